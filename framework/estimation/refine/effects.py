"""The robot's systematic error as random effects: station offsets and the arm's geometric error."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.kinematics import SerialChain, chain_with_errors, flange_corrections
from spherecal.estimation.problem import Problem, sphere_from_mount
from spherecal.estimation.refine.linearisation import _Reduced


@dataclass(frozen=True)
class StationEffects:
    """Systematic robot error shared by the shots of a station (a random effect).

    Station k's flange poses are off by one small pose error ``delta_k = (omega_k,
    tau_k)``, rotation (rad, base axes, about the flange) and translation (mm, base), on
    top of the per-shot pose noise: ``R0 <- exp(omega_k) R0``, ``t0 <- t0 + tau_k``.
    Prior: ``delta_k = delta_common + delta'_k``. ``delta'_k`` is independent per
    station with per-axis standard deviations ``(rotation_deg, translation_mm)``,
    estimated from the data by REML unless given: the station-to-station inconsistency
    is its evidence. ``delta_common`` is shared by every station, per-axis standard
    deviations ``(common_rotation_deg, common_translation_mm)``: the robot's error over
    the calibration region, which one sphere location cannot measure (it moves the
    sphere centre or the transform as a whole), so it enters as prior uncertainty only,
    from the robot's stated accuracy."""

    enabled: bool = True
    rotation_deg: float | None = None
    translation_mm: float | None = None
    common_rotation_deg: float = 0.0
    common_translation_mm: float = 0.0
    #: not ``enabled`` (no station offsets: rows that share no orientation), the robot's
    #: common error still considered in the covariance
    common_only: bool = False


@dataclass(frozen=True)
class KinematicEffects:
    """Systematic robot error as the arm's geometric error (needs each shot's joints).

    The flange pose of shot i is off by ``K(q_i) kappa``: ``kappa`` (6 per joint, see
    :mod:`spherecal.core.kinematics`) are the arm's joint zero offsets, joint origin
    displacements and axis tilts, ``K`` their first-order effect on the flange pose at the
    shot's joints, applied exactly through the chain. Unlike a per-station offset, this
    ties the error of every shot to every other through the arm's geometry, including its
    change along a sweep.

    ``prior_sd`` (rad and mm, per parameter) is the spread of an uncalibrated arm, a
    floor: the fit may widen it by a factor estimated from the data (REML) unless
    ``estimate_scale`` is False. With ``identify`` the parameters the data determine (the identifiability test
    of :func:`.design.identifiable_kinematic_parameters`) are estimated without prior (kinematic
    calibration); the others keep their prior, unscaled, and only widen the covariance.

    With ``select_by_evidence`` (the ``auto`` robot error model) the data decide: when
    they show no geometric error of the arm (the REML likelihood ratio of the prior's
    scale free against zero, :func:`.reml._kinematic_evidence`, below
    :data:`.reml.KINEMATIC_EVIDENCE_LR`), the fit is the pose-noise-only one, efficient on an
    exact or calibrated arm, and the parameters the data barely see are *considered*:
    not estimated, their prior spread propagated into the covariance.
    ``consider_columns`` (set by that choice) selects that mode directly."""

    chain: SerialChain
    prior_sd: np.ndarray
    estimate_scale: bool = True
    identify: bool = False
    select_by_evidence: bool = False
    consider_columns: tuple[int, ...] | None = None


def _apply_station_offsets(problem: Problem, delta: np.ndarray) -> Problem:
    """``problem`` with station k's flange poses moved by ``delta[k]`` (see StationEffects)."""
    if not np.any(delta):
        return problem
    d = delta[problem.station_of]
    R0 = geo.matrix_from_rotvec(d[:, :3]) @ problem.R0
    t0 = problem.t0 + d[:, 3:]
    R_sm, t_sm = sphere_from_mount(problem.mounting, R0, t0)
    return replace(problem, R0=R0, t0=t0, R_sphere_from_mount=R_sm, t_sphere_from_mount=t_sm)


def _common_error_design(problem: Problem, Jd: np.ndarray) -> np.ndarray:
    """Per-shot derivatives (n, 3, 6) of the predicted sphere centres with respect to the
    robot's common error (rotation rad, translation mm, base axes): the part of the
    robot's error that the transform absorbs, which one sphere location cannot tell apart
    from it. ``Jd``: their derivatives with respect to a flange pose error (omega about
    the flange, tau; see :class:`StationEffects`).

    In eye-to-hand it is an error of the arm's motion as seen from the base, a rotation of
    the work region about its centre p and a shift: shot i's flange turns by ``omega``
    and moves by ``omega x (t_i - p) + tau``. It turns every sweep's direction too, so
    it is not a station offset: a common offset of the stations' offsets would leave the
    transform's rotation out. In eye-in-hand it is the flange's own error, which the
    transform on the flange takes whole: ``omega`` and ``tau`` common to
    every shot (base axes), station by station."""
    n = problem.n_profiles
    M = np.zeros((n, 6, 6))
    M[:, :3, :3] = np.eye(3)
    M[:, 3:, 3:] = np.eye(3)
    if problem.mounting == "eye_to_hand":
        M[:, 3:, :3] = -geo.skew(problem.t0 - problem.t0.mean(axis=0))  # omega x d = -[d]x omega
    return Jd @ M


def _apply_kinematic_errors(problem: Problem, chain: SerialChain, kappa: np.ndarray) -> Problem:
    """``problem`` with each reported flange pose corrected by what the geometric errors
    ``kappa`` change at its joints: ``R0 <- R_k R_n^T R0``, ``t0 <- t0 + t_k - t_n`` (k:
    the chain with errors, n: the nominal chain). Exact for poses the nominal model reports."""
    if not np.any(kappa):
        return problem
    dR, dt = flange_corrections(chain, chain_with_errors(chain, kappa), problem.q_rad)
    R0 = dR @ problem.R0
    t0 = problem.t0 + dt
    R_sm, t_sm = sphere_from_mount(problem.mounting, R0, t0)
    return replace(problem, R0=R0, t0=t0, R_sphere_from_mount=R_sm, t_sphere_from_mount=t_sm)


def _effect_blocks(red: _Reduced, At, As, Ak, z, station_shots):
    """Normal-equation blocks of ``y = J_t b + [J_s | J_k] d + e`` with y = -res + J z
    (``z`` (n, 4) per shot, or None): per-shot fixed-effect columns ``At`` (n, 4, p),
    station-offset columns ``As`` (n, 4, 6) (each shot against its own station's six,
    ``station_shots[k]`` the shots of station k) and dense kinematic columns ``Ak``
    (n, 4, q); either may be None. Returns (A_tt, A_td, A_dd, b_t, b_d, yy)."""
    K = len(station_shots) if As is not None else 0
    q = Ak.shape[2] if Ak is not None else 0
    p = At.shape[2]
    A_td = np.zeros((p, 6 * K + q))
    A_dd = np.zeros((6 * K + q, 6 * K + q))
    b_d = np.zeros(6 * K + q)
    for k, rows in enumerate(station_shots[:K]):
        Xs = As[rows]
        sl = slice(6 * k, 6 * k + 6)
        A_td[:, sl] = red.gram(At[rows], Xs, rows)
        A_dd[sl, sl] = red.gram(Xs, Xs, rows)
        b_d[sl] = red.rhs(Xs, z, rows)
        if q:
            A_dd[sl, 6 * K:] = red.gram(Xs, Ak[rows], rows)
            A_dd[6 * K:, sl] = A_dd[sl, 6 * K:].T
    if q:
        A_td[:, 6 * K:] = red.gram(At, Ak)
        A_dd[6 * K:, 6 * K:] = red.gram(Ak, Ak)
        b_d[6 * K:] = red.rhs(Ak, z)
    return red.gram(At, At), A_td, A_dd, red.rhs(At, z), b_d, red.quad(z)
