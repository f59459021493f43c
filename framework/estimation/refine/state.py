"""The state the refinement's steps share: the problem's fixed setup and the current estimate."""

from __future__ import annotations

import numpy as np

from spherecal.core.kinematics import chain_with_errors, flange_error_jacobian
from spherecal.estimation.problem import Problem, unknown_variances
from spherecal.estimation.refine.design import _centre_design, identifiable_kinematic_parameters
from spherecal.estimation.refine.effects import (
    KinematicEffects, StationEffects, _apply_kinematic_errors, _apply_station_offsets,
)
from spherecal.estimation.refine.linearisation import (
    NoiseAssumptions, _centre_variance, _Linearisation, _linearise, _Points, _pose_cov,
)
from spherecal.estimation.refine.timing import TimeEffects, shots_at, time_design


class RefineState:
    """One refinement's problem, settings and current estimate, read and moved by its steps.

    Fixed over the fit: the problem and its stacked points (``pts``), the assumed noise
    (``sigma`` mm, ``pose_cov`` of the pose noise at scale 1), the random effects in use
    (``se``: :class:`StationEffects`, ``ke``: :class:`KinematicEffects`, either None), the
    stations' shots, the kinematic parameters' prior and identifiability and which of
    them are identified (``id_cols``, fixed effects), random (``rand_cols``) or only
    considered (``consider_cols``).

    Moved by the fit: the transform (``R``, ``t``), the sphere (``c``, ``r``), the station
    offsets ``delta`` (K, 6) and kinematic errors ``kappa``, the random effects' scales
    (``s_hat``: station rotation rad and translation mm; ``lam``: the kinematic prior's
    factor), the pose-noise scale, the centre observations' variance ``s2_centre`` and
    the covariance they are whitened with within a pass (``centre_cov_frozen``).

    A recording's clock relation (``te``: :class:`.timing.TimeEffects`) moves with them:
    ``tau`` = (offset_ms, drift_ppm); ``problem`` is then ``base_problem`` with its poses
    re-read from the pose stream at ``tau`` (:meth:`set_tau`), ``twist`` the flange's
    velocity at each shot."""

    def __init__(self, problem: Problem, R, t, centre, noise: NoiseAssumptions, fit_radius: bool,
                 station_effects: StationEffects | None, kinematic_effects: KinematicEffects | None,
                 time_effects: TimeEffects | None = None):
        self.progress = None  # refine() sets what tells the user, on long fits, that it still runs
        self.base_problem = self.problem = problem
        self.te = time_effects if time_effects is not None and problem.t_sensor_s is not None else None
        self.n_time = 0 if self.te is None else self.te.n_parameters
        self.tau = np.zeros(2) if self.te is None else self.te.start()
        self.twist = None
        if self.te is not None:
            self.set_tau(self.tau)
        self.R = np.array(R, dtype=float)
        self.t = np.array(t, dtype=float)
        self.c = np.array(centre, dtype=float)
        self.r = float(problem.radius_mm)
        self.pts = _Points(problem)
        self.sigma = max(noise.point_noise_mm, 1e-7)
        self.pose_cov = _pose_cov(noise)
        self.fit_radius = fit_radius
        self.n_geo = 10 if fit_radius else 9
        K = self.K = len(problem.station_labels)
        self.se = station_effects if station_effects is not None and station_effects.enabled and K >= 2 else None
        # the robot's common error considered without station offsets (StationEffects.common_only)
        self.common_only = (station_effects if station_effects is not None and station_effects.common_only
                            and not station_effects.enabled else None)
        self.ke = kinematic_effects if kinematic_effects is not None and problem.q_rad is not None else None
        self.delta = np.zeros((K, 6))
        self.station_shots = [np.flatnonzero(problem.station_of == k) for k in range(K)]
        self.n_shots = problem.n_profiles
        self.m_centres = len(self.pts.centre_shots)
        self._start_centre_variance()
        se = self.se
        self.fixed = (None if se is None else
                      (None if se.rotation_deg is None else np.radians(se.rotation_deg),
                       se.translation_mm))
        self.s_start = np.array([np.radians(0.01), 0.1])  # start of the station-effect scales
        self.s_hat = self.s_start.copy()
        self._set_kinematic_parameters()
        self.n_kin_fitted = len(self.id_cols) + len(self.rand_cols)
        self.lam = 1.0
        self.n_par = self.n_geo + len(self.id_cols) + self.n_time
        self.scale = 1.0
        # the centre observations' covariance depends on the parameters (the pose noise seen
        # through the transform and, for a circle, through where the plane cuts the sphere).
        # Within a pass of Gauss-Newton it is held at its value at the pass's start (iteratively
        # reweighted least squares), so that the cost the line search compares is the one the
        # step minimises; each pass re-evaluates it until a pass no longer moves the solution.
        # (Re-evaluated at every step, the step aims at the reweighted solution while the
        # line search judges by a cost with moving weights: where that covariance dominates,
        # as for exact centres with the centre noise at its floor, the two disagree by about
        # 1e-4 standard deviations and the steps crawl there, halved, for ever.)
        self.centre_cov_frozen = None
        # the prior's scale: the stated spread is a floor, the data may widen it (REML)
        ke = self.ke
        self.estimate_lam = (ke is not None and ke.estimate_scale and not ke.identify
                             and bool(np.any(self.kin_identifiable[self.rand_cols])))
        self.any_random = se is not None or len(self.rand_cols) > 0
        self.free = [i for i in range(2) if se is not None and self.fixed[i] is None]
        self.starts_agreed = False  # the REML search's two starts ended at the same scales
        self.iterations = 0
        self.converged = False
        self.s2_profiles = 1.0

    def _start_centre_variance(self) -> None:
        """Centre observations given without a covariance: one variance per axis, estimated
        from their residuals (a variance component, like the pose noise's scale); its start."""
        problem, pts, m_centres = self.problem, self.pts, self.m_centres
        self.estimate_centre = bool(m_centres) and bool(
            unknown_variances(problem.centre_cov[pts.centre_shots]).any())
        self.s2_centre = None
        if m_centres:
            self.s2_centre = 1.0 if self.estimate_centre else None
            if self.estimate_centre:
                start = _linearise(problem, pts, self.R, self.t, self.c, self.r, self.fit_radius, self.pose_cov,
                                   self.sigma, 1.0)
                self.s2_centre = _centre_variance(start.centre_parts, 3 * m_centres - 9 * m_centres / self.n_shots,
                                                  1.0)

    def _set_kinematic_parameters(self) -> None:
        """The kinematic parameters: identified (fixed effects, in the parameter vector),
        random, or considered, with their prior and identifiability at the start."""
        ke = self.ke
        n_kin = self.n_kin = 0 if ke is None else 6 * ke.chain.n_joints
        self.kappa = np.zeros(n_kin)
        self.kin_prior = np.zeros(n_kin) if ke is None else np.asarray(ke.prior_sd, dtype=float)
        self.kin_identifiable = np.zeros(n_kin, dtype=bool)
        self.kin_share = np.zeros(n_kin)
        if ke is not None:
            Jc_geo, Jc_kin = _centre_design(self.problem, self.R, self.t, self.c, ke.chain, self.fit_radius)
            self.kin_identifiable, self.kin_share = identifiable_kinematic_parameters(Jc_geo, Jc_kin, self.kin_prior)
        self.id_cols = (np.flatnonzero(self.kin_identifiable) if ke is not None and ke.identify
                        else np.array([], dtype=int))
        rand_cols = np.flatnonzero(~np.isin(np.arange(n_kin), self.id_cols))  # (np.setdiff1d imports numpy.ma)
        self.rand_cols = rand_cols[self.kin_prior[rand_cols] > 0]
        self.consider_cols = np.array([], dtype=int)
        if ke is not None and ke.consider_columns is not None:
            self.consider_cols = np.asarray(ke.consider_columns, dtype=int)
            self.rand_cols = np.array([], dtype=int)

    def set_tau(self, tau) -> None:
        """Move the clock relation to ``tau`` and re-read the shots' poses at it."""
        self.tau = np.array(tau, dtype=float)
        timed = shots_at(self.base_problem, self.te, self.tau)
        self.problem, self.twist = timed.problem, timed.twist

    def current(self) -> Problem:
        """The problem with its flange poses moved by the current robot errors."""
        p = self.problem
        if self.ke is not None:
            p = _apply_kinematic_errors(p, self.ke.chain, self.kappa)
        return _apply_station_offsets(p, self.delta)

    def linearise(self, scale: float) -> _Linearisation:
        """The linearisation at the current estimate, the pose noise at ``scale``."""
        return _linearise(self.current(), self.pts, self.R, self.t, self.c, self.r, self.fit_radius,
                          scale * self.pose_cov, self.sigma, self.s2_centre, centre_cov_frozen=self.centre_cov_frozen)

    def kin_columns(self, lin: _Linearisation) -> np.ndarray:
        """Per-shot d res / d kappa (n, 4, n_kin)."""
        return lin.columns(lin.Jd @ flange_error_jacobian(chain_with_errors(self.ke.chain, self.kappa),
                                                          self.problem.q_rad))

    def prior_sd(self, sv, lam) -> np.ndarray:
        """Prior spread of each random effect (station offsets (6 K,): s_rot, s_rot, s_rot,
        s_trans, ... per station; then the random kinematic parameters): the diagonal of
        the prior's square root L (L L^T = I (x) diag(s_rot^2 I3, s_trans^2 I3) for the
        stations; the common part is a consider parameter, in the covariance only), for
        station scales ``sv`` and the kinematic prior's factor ``lam``."""
        return np.concatenate([np.tile(np.repeat(sv, 3), self.K) if self.se is not None else [],
                               lam * self.kin_prior[self.rand_cols]])

    def sqrt_prior(self, sv, lam) -> np.ndarray:
        return np.diag(self.prior_sd(sv, lam))

    def design(self, lin: _Linearisation):
        """Per-shot fixed-effect columns, station columns, random kinematic columns."""
        At = lin.columns(lin.Jc, self.fit_radius)
        As = lin.columns(lin.Jd) if self.se is not None else None
        Ak = None
        if self.ke is not None:
            Kk = self.kin_columns(lin)
            if len(self.id_cols):
                At = np.concatenate([At, Kk[:, :, self.id_cols]], axis=2)
            Ak = Kk[:, :, self.rand_cols] if len(self.rand_cols) else None
        if self.te is not None:
            At = np.concatenate([At, lin.columns(lin.Jd @ time_design(self.problem, self.te, self.twist))], axis=2)
        return At, As, Ak

    def shift(self, As, Ak) -> np.ndarray:
        """J z of the random effects now, per shot (n, 4)."""
        z = np.zeros((self.n_shots, 4))
        if As is not None:
            z += np.einsum("nap,np->na", As, self.delta[self.problem.station_of])
        if Ak is not None:
            z += Ak @ self.kappa[self.rand_cols]
        return z

    def random_effects(self) -> np.ndarray:
        """The random effects now: the station offsets, then the random kinematic parameters."""
        return np.concatenate([self.delta.ravel() if self.se is not None else [], self.kappa[self.rand_cols]])

    def snapshot(self) -> tuple:
        """The estimate now, (R, t, c, r, delta, kappa, tau), to step from."""
        return self.R, self.t, self.c, self.r, self.delta.copy(), self.kappa.copy(), self.tau.copy()

    def penalised_cost(self, lin: _Linearisation, sv, lam) -> float:
        """The MAP objective: whitened residuals plus the random effects against their prior."""
        cost = lin.red.cost()
        if self.any_random:
            d = self.random_effects()
            sd = self.prior_sd(sv, lam)
            cost += float(np.sum(np.where(sd > 0, d / np.where(sd > 0, sd, 1.0), 0.0) ** 2))
        return cost
