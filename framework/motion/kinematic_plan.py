"""Station planning for kinematic calibration, and the check that a plan identifies the
arm's geometry before anything moves.

Brand-free: the arm is reached only through :class:`~spherecal.core.kinematics.ArmKinematics`
(its chain, its joint convention and its inverse kinematics, which refuses poses out of
reach or beyond a joint limit), the workspace through the configuration's box.

**The planner.** A station is a short pure-translation sweep over the sphere
(:func:`spherecal.motion.planning.plan_stations`) at one orientation: the sensor (eye-in-hand)
or the flange (eye-to-hand) turned from the reference orientation by a tilt of the view
axis (up to ``max_tilt_deg``, in every direction) and a turn about it (up to
``max_turn_deg``). The candidates are ``candidates`` such orientations, spread evenly
over the tilt cone (a Fibonacci spiral) with turns drawn from ``seed``; each is kept if
every flange position lies in the workspace box, the arm reaches its middle shot within
the joint limits and no joint swings far along it (a singularity). From them the planner picks ``stations`` greedily,
starting with the reference orientation: each step adds the candidate that most raises
``log det(I + S / s^2)``, ``S`` the information on the geometric parameters (each
scaled by its prior spread, the transform and the sphere projected out, as the estimator
and the plan check see them) and ``s`` :data:`DESIGN_CENTRE_NOISE_MM`: a Bayesian
D-optimal design, which spreads the stations over the joints that the parameters need
(shoulder, elbow and wrist). The chosen stations are visited nearest orientation first,
every target is checked for reach in that order (the joints the robot takes, the
controller choosing the solution nearest its current joints), and the plan goes through
the same checks as every plan. Deterministic for a given configuration and seed.

**The check** (:func:`check_plan_identifies_kinematics`) reports the parameters a plan
identifies (per joint) and the condition number before anything moves, and refuses a plan
that identifies too few or too poorly, naming the parameters not seen or seen too weakly,
the joints the stations do not spread, and the stations to add (found by the same greedy
search, continuing from the plan as it is, and checked as the plan they make).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spherecal.config import AcquisitionConfig, CalibrationOptions, KinematicPlanSettings, SphereConfig, TransformConfig
from spherecal.core import geometry as geo
from spherecal.core.errors import ConfigError, InputError, SpherecalError
from spherecal.estimation.options import kinematic_effects
from spherecal.estimation.refine import design_identifiability, plan_design
from spherecal.core.kinematics import (ERROR_PARAMETERS_PER_JOINT, error_parameter_names, flange_error_jacobian,
                                      joints_from_home)
from spherecal.core.models import MountingMode, Pose
from spherecal.motion.planning import SweepPlan, station_flange_poses, with_standoff

#: With identify_kinematics a plan must identify at least this many geometric parameters
#: per joint on average: a revolute arm seen through one sphere has 3 per joint
#: identifiable at best with spherecal's 6-per-joint parametrisation (docs/estimation.md,
#: "Kinematic calibration").
IDENTIFIABLE_PER_JOINT = 3
#: ... and their identification must not be worse conditioned than this (the prior-scaled
#: sphere-centre Jacobian, transform and sphere projected out). Measured: 20 hand-written
#: stations with tilts spread up to 50 deg, 149 (identified parameters determined to 0.4 of
#: their prior spread, median; fresh poses then agree to 0.02 mm); the 4-station default
#: plan 2,212 (2.5 times their prior spread, median; fresh poses 0.18 mm apart); the
#: planner's 20 stations 88-111 eye-in-hand, 316 eye-to-hand.
MAX_IDENTIFICATION_CONDITION = 1e3
#: The stations suggested for a refused plan stop once it would pass with this margin.
SUGGESTION_CONDITION = 0.5 * MAX_IDENTIFICATION_CONDITION
#: At most this many stations are suggested.
MAX_SUGGESTED_STATIONS = 24
#: A joint the suggested stations move over this many times its span in the plan, and at
#: least this much further (deg), is named as one the plan's stations lack (at most three,
#: those spread most).
MIN_SPREAD_GAIN = 2.0
MIN_SPREAD_GAIN_DEG = 10.0
#: Assumed standard deviation (mm, per axis) of one profile's sphere centre in the
#: design criterion (robot pose noise and the circle fit): it weighs the data against the
#: prior spread, so that the greedy search spends stations on the parameters known worst.
DESIGN_CENTRE_NOISE_MM = 0.05
#: A candidate station whose sweep turns some joint by more than this (deg) passes near a
#: singularity (of the wrist, most often) and is left out: a real controller slows down or
#: stops there, and the design's linearisation fails.
MAX_SWEEP_JOINT_TRAVEL_DEG = 10.0


def uses_planner(acq: AcquisitionConfig | None, calibration: CalibrationOptions) -> bool:
    """True when the stations come from the kinematic planner: an
    ``[acquisition.kinematic_plan]`` section, or ``identify_kinematics`` with no
    ``acquisition.sweep.tilts_deg`` given (automatic acquisition only)."""
    if acq is None or acq.mode == "manual":
        return False
    return acq.kinematic_plan is not None or (
        calibration.identify_kinematics and "tilts_deg" not in acq.sweep.model_fields_set)


def candidate_tilts_deg(settings: KinematicPlanSettings, mounting: MountingMode) -> np.ndarray:
    """``(candidates, 3)`` rotation vectors (deg) from the reference orientation, the first
    the reference itself: a tilt of the view axis (z) about a horizontal direction (a
    Fibonacci spiral over the cone up to the mode's max tilt, even in area), after a turn
    about the view axis (uniform up to the max turn, drawn from ``seed``)."""
    max_tilt, max_turn = settings.limits_deg(mounting)
    n = settings.candidates
    rng = np.random.default_rng(settings.seed)
    turns = rng.uniform(-max_turn, max_turn, n)
    golden = np.pi * (3.0 - np.sqrt(5.0))
    out = np.zeros((n, 3))
    for k in range(1, n):
        tilt = np.radians(max_tilt) * np.sqrt(k / (n - 1))
        phi = k * golden
        R = geo.matrix_from_rotvec(tilt * np.array([np.cos(phi), np.sin(phi), 0.0])) @ geo.matrix_from_rotvec(
            [0.0, 0.0, np.radians(turns[k])])
        out[k] = np.degrees(geo.rotvec_from_matrix(R))
    return out


@dataclass
class _Candidates:
    """Candidate stations: tilts (C, 3) deg, field-of-view offsets (C, 2) mm, flange
    rotations (C, n, 3, 3) and translations (C, n, 3) mm, joints at the middle shot (C,
    n_joints) deg, controller convention, and the design rows of each (C, 3 n, 9) and
    (C, 3 n, 6 n_joints), prior-scaled."""

    tilts_deg: np.ndarray
    offsets_mm: np.ndarray
    R: np.ndarray
    t: np.ndarray
    joints_deg: np.ndarray
    Jg: np.ndarray
    Jk: np.ndarray

    def __len__(self) -> int:
        return len(self.tilts_deg)

    def poses(self, i: int) -> list[Pose]:
        return [Pose.from_rt(r, p) for r, p in zip(self.R[i], self.t[i])]


@dataclass
class _Context:
    """What planning and the check share: the cell as configured and the arm."""

    mounting: MountingMode
    X: Pose
    centre: np.ndarray
    radius_mm: float
    sweep: SweepPlan
    R_ref: np.ndarray
    workspace: object
    arm: object
    prior_sd: np.ndarray
    settings: KinematicPlanSettings

    @classmethod
    def of(cls, acq: AcquisitionConfig, calibration: CalibrationOptions, mounting: MountingMode,
           nominal: TransformConfig, sphere: SphereConfig, arm) -> "_Context":
        sweep = with_standoff(acq.sweep, None)  # as app.cell.for_sensor fitted it to the sensor (else: which setting)
        return cls(mounting, nominal.pose(), np.asarray(acq.sphere_centre_mm, float),
                   sphere.radius_mm, sweep, geo.matrix_from_quat_wxyz(acq.reference_flange_quaternion_wxyz),
                   acq.workspace, arm, kinematic_effects(calibration, arm.chain).prior_sd,
                   acq.kinematic_plan or KinematicPlanSettings())

    def rows(self, R0: np.ndarray, t0: np.ndarray, joints_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Design rows (prior-scaled) of shots at flange poses (R0, t0) with joints (deg)."""
        q = np.array([self.arm.model_joints_rad(j) for j in joints_deg])
        Jg, Jk = plan_design(self.mounting, R0, t0, q, self.X, self.centre, self.arm.chain)
        return Jg, Jk * self.prior_sd

    def candidates(self, seed_joints_deg) -> tuple[_Candidates, int]:
        """The candidates (module docstring) whose flange positions all lie in the
        workspace, whose middle shot the arm reaches from ``seed_joints_deg`` and whose
        sweep stays clear of singularities (:data:`MAX_SWEEP_JOINT_TRAVEL_DEG`), and how
        many were tried. The other shots' joints come from Newton steps on the chain from
        the middle shot's; every shot of the chosen stations is checked by the plugin's
        inverse kinematics later."""
        tilts = candidate_tilts_deg(self.settings, self.mounting)
        offsets = np.array([self.sweep.station_offsets_mm[k % len(self.sweep.station_offsets_mm)]
                            for k in range(len(tilts))], dtype=float)
        R, t = station_flange_poses(self.mounting, self.X, self.centre, self.radius_mm, self.sweep, tilts, offsets,
                                    self.R_ref)
        lo, hi = np.asarray(self.workspace.min_mm), np.asarray(self.workspace.max_mm)
        keep = np.all((t >= lo) & (t <= hi), axis=(1, 2))
        mid = t.shape[1] // 2
        joints = np.full((len(tilts), self.arm.chain.n_joints), np.nan)
        for k in np.flatnonzero(keep):
            try:
                joints[k] = self.arm.joints_from_flange_pose(Pose.from_rt(R[k, mid], t[k, mid]), seed_joints_deg)
            except SpherecalError:
                keep[k] = False
        n, n_kin = t.shape[1], len(self.prior_sd)
        if not keep.any():
            return _Candidates(np.zeros((0, 3)), np.zeros((0, 2)), R[:0], t[:0], joints[:0], np.zeros((0, 3 * n, 9)),
                               np.zeros((0, 3 * n, n_kin))), len(tilts)
        q_mid = np.array([self.arm.model_joints_rad(j) for j in joints[keep]]).reshape(int(keep.sum()), -1)
        q = _sweep_joints_rad(self.arm.chain, q_mid, R[keep], t[keep])
        # near a singularity a short sweep swings some joints far: such a station is left out
        smooth = np.degrees(np.max(q.max(axis=1) - q.min(axis=1), axis=1)) <= MAX_SWEEP_JOINT_TRAVEL_DEG
        keep[np.flatnonzero(keep)[~smooth]] = False
        q = q[smooth]
        C = int(keep.sum())
        Jg, Jk = plan_design(self.mounting, R[keep].reshape(-1, 3, 3), t[keep].reshape(-1, 3), q.reshape(C * n, -1),
                             self.X, self.centre, self.arm.chain)
        Jk = Jk * self.prior_sd
        return _Candidates(tilts[keep], offsets[keep], R[keep], t[keep], joints[keep], Jg.reshape(C, 3 * n, -1),
                           Jk.reshape(C, 3 * n, -1)), len(tilts)


def _sweep_joints_rad(chain, q_mid: np.ndarray, R: np.ndarray, t: np.ndarray, iterations: int = 3) -> np.ndarray:
    """Model joints (rad) of every shot of short sweeps, (C, n, joints): Newton steps on
    ``chain`` from each sweep's middle-shot joints ``q_mid`` (C, joints) to the flange
    poses ``R`` (C, n, 3, 3), ``t`` (C, n, 3) mm, all shots at once (the joint columns of
    :func:`~spherecal.core.kinematics.flange_error_jacobian` are the arm's Jacobian)."""
    C, n = t.shape[:2]
    Q = np.repeat(q_mid[:, None, :], n, axis=1).reshape(C * n, -1)
    Rt, tt = R.reshape(-1, 3, 3), t.reshape(-1, 3)
    for _ in range(iterations):
        T = chain.flange_matrices(Q)
        e = np.concatenate([geo.rotvec_from_matrix(Rt @ np.swapaxes(T[:, :3, :3], 1, 2)), tt - T[:, :3, 3]], axis=1)
        J = flange_error_jacobian(chain, Q)[:, :, ::len(ERROR_PARAMETERS_PER_JOINT)]  # the zero-offset columns
        Q = Q + np.einsum("kij,kj->ki", np.linalg.pinv(J), e)
    return Q.reshape(C, n, -1)


def _greedy(base_rows: list, cands: _Candidates, count: int, stop=None, exclude=()) -> list[int]:
    """Indices of up to ``count`` candidates added one at a time to the design of
    ``base_rows`` (a list of (J_geo, J_kin) row blocks), each the one that most raises
    ``log det(I + S / s^2)``: S the information on the (prior-scaled) geometric
    parameters with the transform and sphere projected out, s
    :data:`DESIGN_CENTRE_NOISE_MM`. Computed for every candidate at once with the
    determinant lemma, ``log det(I + S/s^2) = log det(M) - log det(M_gg)`` with ``M`` the
    information of all parameters (a unit prior on the geometric ones, a vanishing one on
    the transform and sphere). ``stop(chosen)`` ends the search when it returns True;
    ``exclude``: indices never taken."""
    n_g, n_k = cands.Jg.shape[2], cands.Jk.shape[2]
    rows = [np.hstack(r) for r in base_rows]
    J = np.concatenate([cands.Jg, cands.Jk], axis=2) / DESIGN_CENTRE_NOISE_MM  # (C, m, n_g + n_k)
    M = sum((r.T @ r for r in rows), np.zeros((n_g + n_k, n_g + n_k))) / DESIGN_CENTRE_NOISE_MM**2
    eps = 1e-9 * max(np.trace(M[:n_g, :n_g]), 1.0) / n_g  # a vanishing prior on the transform and sphere
    M += np.diag([eps] * n_g + [1.0] * n_k)
    taken = np.zeros(len(cands), dtype=bool)
    taken[list(exclude)] = True
    chosen: list[int] = []
    eye = np.eye(J.shape[1])
    for _ in range(count):
        if taken.all():
            break
        G = J @ np.linalg.inv(M)  # (C, m, p)
        full = np.linalg.slogdet(eye + np.einsum("cmp,cnp->cmn", G, J))[1]
        Gg = J[:, :, :n_g] @ np.linalg.inv(M[:n_g, :n_g])
        nuisance = np.linalg.slogdet(eye + np.einsum("cmp,cnp->cmn", Gg, J[:, :, :n_g]))[1]
        gain = np.where(taken, -np.inf, full - nuisance)
        best = int(np.argmax(gain))
        chosen.append(best)
        taken[best] = True
        M += J[best].T @ J[best]
        if stop is not None and stop(chosen):
            break
    return chosen


def _visiting_order(R_first: np.ndarray) -> list[int]:
    """The first station, then always the nearest remaining orientation (flange
    rotations ``R_first`` (K, 3, 3))."""
    order, left = [0], list(range(1, len(R_first)))
    while left:
        last = R_first[order[-1]]
        nxt = min(left, key=lambda i: geo.rotation_angle_deg(last, R_first[i]))
        order.append(nxt)
        left.remove(nxt)
    return order


@dataclass
class KinematicPlan:
    """The planner's result: ``sweep`` (the configuration's, with the chosen stations'
    tilts and field-of-view offsets in visiting order) and what it found."""

    sweep: SweepPlan
    tried: int  # candidate orientations
    reachable: int  # of them, reachable and in the workspace
    limits_deg: tuple[float, float]  # max tilt, max turn

    def summary(self) -> str:
        tilts = ", ".join("[" + ", ".join(f"{v:.1f}" for v in t) + "]" for t in self.sweep.tilts_deg)
        return (f"kinematic plan: {len(self.sweep.tilts_deg)} stations chosen from {self.reachable} reachable "
                f"candidate orientations (of {self.tried}; tilts up to {self.limits_deg[0]:g} deg, turns up to "
                f"{self.limits_deg[1]:g} deg) for the arm's geometric parameters; tilts_deg = [{tilts}]")


def plan_kinematic_stations(acq: AcquisitionConfig, calibration: CalibrationOptions, mounting: MountingMode,
                            nominal: TransformConfig, sphere: SphereConfig, arm, *,
                            robot_type: str | None = None) -> KinematicPlan:
    """The stations of the kinematic planner (module docstring) for the acquisition
    ``acq`` (its ``kinematic_plan`` settings, sweep, workspace and rough sphere centre),
    with the arm's kinematics ``arm`` and the prior spread of its geometric error from
    ``calibration``; ``robot_type`` names the robot in the message when ``arm`` is None.
    Raises :class:`InputError` when too few candidate orientations are reachable."""

    if arm is None:
        raise ConfigError("the kinematic planner needs a robot type whose plugin describes its arm "
                          f"(robot.type = {robot_type!r} does not): list the stations in "
                          "acquisition.sweep.tilts_deg")
    ctx = _Context.of(acq, calibration, mounting, nominal, sphere, arm)
    n = ctx.settings.stations
    limits = ctx.settings.limits_deg(mounting)
    R, t = station_flange_poses(mounting, ctx.X, ctx.centre, ctx.radius_mm, ctx.sweep, [(0.0, 0.0, 0.0)],
                                [(0.0, 0.0)], ctx.R_ref)
    mid = R.shape[1] // 2
    try:
        seed = joints_from_home(arm, Pose.from_rt(R[0, mid], t[0, mid]))
    except SpherecalError as exc:
        raise InputError(f"the kinematic planner: the reference station (acquisition.sphere_centre_mm seen at "
                         f"acquisition.reference_flange_quaternion_wxyz) is out of reach: {exc}; nothing was "
                         "moved") from None
    cands, tried = ctx.candidates(seed)
    if not len(cands) or np.any(cands.tilts_deg[0]):
        raise InputError("the kinematic planner: the reference station (acquisition.sphere_centre_mm seen at "
                         "acquisition.reference_flange_quaternion_wxyz) leaves acquisition.workspace: choose a "
                         "reference orientation whose sweep lies in it; nothing was moved")
    excluded = {0}
    while True:
        if len(cands) - len(excluded) < n - 1:
            raise InputError(
                f"the kinematic planner: only {len(cands) - len(excluded) + 1} of {tried} candidate orientations "
                f"(tilts up to {limits[0]:g} deg, turns up to {limits[1]:g} deg) are reachable with every flange "
                f"position in acquisition.workspace, and {n} stations were asked for: widen acquisition.workspace, "
                "move the sphere (acquisition.sphere_centre_mm) nearer the middle of the arm's reach, or ask for "
                "fewer stations (acquisition.kinematic_plan.stations); nothing was moved")
        picked = [0] + _greedy([(cands.Jg[0], cands.Jk[0])], cands, n - 1, exclude=excluded)
        picked = [picked[i] for i in _visiting_order(cands.R[picked, 0])]
        # every target, in the order the robot takes them, from the reference's joints
        joints, bad = seed, None
        for i in picked:
            sweep = _station_joints(arm, cands.poses(i), joints)
            if sweep is None:
                bad = i
                break
            joints = sweep[-1]
        if bad is None:
            break
        if bad == 0:
            raise InputError("the kinematic planner: the reference station is out of reach from the planned "
                             "stations; choose another acquisition.reference_flange_quaternion_wxyz; nothing was moved")
        excluded.add(bad)
    sweep = ctx.sweep.model_copy(update={
        "tilts_deg": [tuple(float(v) for v in cands.tilts_deg[i]) for i in picked],
        "station_offsets_mm": [tuple(float(v) for v in cands.offsets_mm[i]) for i in picked]})
    return KinematicPlan(SweepPlan.model_validate(sweep.model_dump()), tried, len(cands), limits)


# --- the check -----------------------------------------------------------------------------


def _joint_spans_deg(joints_deg: np.ndarray) -> np.ndarray:
    return joints_deg.max(axis=0) - joints_deg.min(axis=0) if len(joints_deg) else np.zeros(joints_deg.shape[1])


def _weak_parameters(info: dict, limit: float) -> list[int]:
    """Indices (of all parameters) dominating the directions whose singular value is
    below ``sv_max / limit``: what makes the condition number exceed ``limit``."""
    sv, V = info["singular_values"], info["directions"]
    ids = np.flatnonzero(info["identifiable"])
    out: list[int] = []
    for s, v in zip(sv, V):
        if s < sv[0] / limit:
            big = np.flatnonzero(np.abs(v) >= 0.5 * np.abs(v).max())
            out.extend(int(ids[k]) for k in big if int(ids[k]) not in out)
    return out


def _and(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _sequential_joints(arm, poses, seed=None) -> np.ndarray:
    """Joints (deg) of flange poses taken in order, each solved from the last (as the
    controller chooses them), the first from ``seed`` (None: from the arm's home,
    :func:`~spherecal.core.kinematics.joints_from_home`); raises the plugin's error for
    one out of reach."""
    out = []
    for p in poses:
        seed = joints_from_home(arm, p) if seed is None else arm.joints_from_flange_pose(p, seed)
        out.append(seed)
    return np.array(out)


def _station_joints(arm, poses: list[Pose], seed) -> np.ndarray | None:
    """The joints (deg) of one station's shots in order from ``seed``, or None when one is
    out of reach or a joint swings more than :data:`MAX_SWEEP_JOINT_TRAVEL_DEG` along the
    sweep (a singularity)."""
    try:
        joints = _sequential_joints(arm, poses, seed)
    except SpherecalError:
        return None
    return joints if np.max(np.ptp(joints, axis=0)) <= MAX_SWEEP_JOINT_TRAVEL_DEG else None


def _identification(ctx: _Context, R0, t0, joints_deg) -> tuple[tuple[np.ndarray, np.ndarray], dict]:
    rows = ctx.rows(R0, t0, joints_deg)
    return rows, design_identifiability(*rows, np.ones(len(ctx.prior_sd)))


def _passes(info: dict, n_joints: int, max_condition: float) -> bool:
    return int(info["identifiable"].sum()) >= IDENTIFIABLE_PER_JOINT * n_joints and \
        info["condition_number"] <= max_condition


def check_plan_identifies_kinematics(targets, acq: AcquisitionConfig, calibration: CalibrationOptions,
                                     mounting: MountingMode, nominal: TransformConfig, sphere: SphereConfig, arm,
                                     planned: KinematicPlan | None = None, *, start_joints_deg=None,
                                     robot_type: str | None = None) -> str:
    """Before anything moves, with ``identify_kinematics``: the parameters the plan would
    identify (per joint) and the condition number of their identification. Raises
    :class:`InputError` (nothing moved) when the plan identifies fewer than
    ``IDENTIFIABLE_PER_JOINT`` per joint on average or has a condition number above
    ``MAX_IDENTIFICATION_CONDITION``, saying what is not seen or seen too weakly, which
    joints the stations do not spread and which stations to add (to
    ``acquisition.sweep.tilts_deg``; with ``planned``, the planner's plan, how many more
    to ask the planner for); returns a one-line summary otherwise. The joints of the
    targets are those the arm takes reaching them in order from ``start_joints_deg``
    (controller convention; default: the arm's home, before the robot is connected; the
    arm's joints where it stands, once it is). The sections and ``robot_type`` are as
    for :func:`plan_kinematic_stations`."""
    if arm is None:
        raise ConfigError("calibration.identify_kinematics needs a robot type whose plugin describes its arm "
                          f"(robot.type = {robot_type!r} does not); nothing was moved")
    ctx = _Context.of(acq, calibration, mounting, nominal, sphere, arm)
    joints = _sequential_joints(arm, [t.pose for t in targets], start_joints_deg)
    rows, info = _identification(ctx, np.array([t.pose.rotation_matrix for t in targets]),
                                 np.array([t.pose.translation for t in targets]), joints)
    n_joints = arm.chain.n_joints
    per_joint = info["identifiable"].reshape(n_joints, len(ERROR_PARAMETERS_PER_JOINT)).sum(axis=1)
    n_id, need, cond = int(per_joint.sum()), IDENTIFIABLE_PER_JOINT * n_joints, info["condition_number"]
    stations = len({t.station for t in targets})
    summary = (f"kinematic identification: the plan ({stations} stations) identifies {n_id} of {len(per_joint) * 6} "
               f"geometric parameters (per joint: {', '.join(str(int(v)) for v in per_joint)}), condition number "
               f"{cond:.0f}")
    if _passes(info, n_joints, MAX_IDENTIFICATION_CONDITION):
        return summary
    if n_id < need:
        why = f"it must identify at least {need} to calibrate the arm"
    else:
        why = (f"too poorly: the condition number must stay under {MAX_IDENTIFICATION_CONDITION:.0f}, or the "
               "identified parameters are known worse than before the calibration")
    raise InputError(f"{summary}: {why}. {_what_to_add(ctx, targets, rows, joints, info, planned)}; nothing was moved")


def _what_to_add(ctx: _Context, targets, rows, joints: np.ndarray, info: dict, planned: KinematicPlan | None) -> str:
    """The advice of a refused plan: what is not seen or seen too weakly, the joints the
    stations do not spread, and the stations that make the plan pass: the greedy search of
    the planner continued from the plan, each suggestion checked as the plan it makes
    (every target reached in order, the identification computed from its joints)."""
    names = error_parameter_names(ctx.arm.chain)
    n_joints = ctx.arm.chain.n_joints
    by_station: dict[str, list[int]] = {}
    for k, t in enumerate(targets):
        by_station.setdefault(t.station, []).extend(range(3 * k, 3 * k + 3))
    base = [(rows[0][ks], rows[1][ks]) for ks in by_station.values()]
    cands, _ = ctx.candidates(joints[-1])
    ones = np.ones(len(names))

    def approximate(added) -> dict:
        return design_identifiability(np.vstack([rows[0], *cands.Jg[added]]), np.vstack([rows[1], *cands.Jk[added]]),
                                      ones)

    def exact(added):
        """The plan with the stations ``added`` appended to acquisition.sweep.tilts_deg:
        (identification, joints), or the index of an added candidate it cannot take."""
        tilts = list(ctx.sweep.tilts_deg) + [tuple(cands.tilts_deg[k]) for k in added]
        sweep = ctx.sweep.model_copy(update={"tilts_deg": tilts})
        offsets = [sweep.station_offsets_mm[k % len(sweep.station_offsets_mm)] for k in range(len(tilts))]
        R, t = station_flange_poses(ctx.mounting, ctx.X, ctx.centre, ctx.radius_mm, sweep, tilts, offsets, ctx.R_ref)
        n_old, n = len(ctx.sweep.tilts_deg), R.shape[1]
        joints_all, seed = [], None
        for k in range(len(tilts)):
            poses = [Pose.from_rt(r, p) for r, p in zip(R[k], t[k])]
            if k < n_old:  # the plan's own stations: as they are
                sweep_joints = _sequential_joints(ctx.arm, poses, seed)
            else:
                sweep_joints = _station_joints(ctx.arm, poses, seed)
                if sweep_joints is None or not all(ctx.workspace.contains(p) for p in t[k]):
                    return added[k - n_old]
            seed = sweep_joints[-1]
            joints_all.append(sweep_joints)
        joints_all = np.vstack(joints_all)
        return _identification(ctx, R.reshape(-1, 3, 3), t.reshape(-1, 3), joints_all)[1], joints_all

    # grow the suggestion until the plan it makes passes with a margin; a candidate that the
    # grown plan cannot take (out of reach from where the robot is then) is left out and the
    # search redone
    excluded: set[int] = set()
    result = None
    for _ in range(MAX_SUGGESTED_STATIONS):
        bad = None

        def stop(chosen) -> bool:
            nonlocal bad, result
            if not _passes(approximate(chosen), n_joints, SUGGESTION_CONDITION):
                return False
            if planned is not None:  # the planner will check its own plan again
                result = approximate(chosen), np.vstack([joints, cands.joints_deg[chosen]])
                return True
            got = exact(chosen)
            if isinstance(got, (int, np.integer)):
                bad = int(got)
                return True
            result = got
            return _passes(got[0], n_joints, MAX_IDENTIFICATION_CONDITION)

        result = None
        count = min(MAX_SUGGESTED_STATIONS, len(cands) - len(excluded))
        added = _greedy(base, cands, count, stop, exclude=excluded) if count > 0 else []
        if bad is None:
            break
        excluded.add(bad)
    reachable = approximate(list(range(len(cands))))["identifiable"]  # what any reachable plan can see
    unseen = [k for k in range(len(names)) if reachable[k] and not info["identifiable"][k]]
    weak = [k for k in _weak_parameters(info, MAX_IDENTIFICATION_CONDITION) if k not in unseen]
    parts = [f"not seen: {', '.join(names[k] for k in unseen)}"] if unseen else []
    parts += [f"seen too weakly: {', '.join(names[k] for k in weak)}"] if weak else []
    text = "; ".join(parts) if parts else "too few parameters are seen"
    if result is None or not _passes(result[0], n_joints, MAX_IDENTIFICATION_CONDITION):
        max_tilt, max_turn = ctx.settings.limits_deg(ctx.mounting)
        return (f"{text}. No reachable station within tilts of {max_tilt:g} deg and turns of {max_turn:g} deg "
                "makes the plan pass: allow larger ones ([acquisition.kinematic_plan] max_tilt_deg, max_turn_deg), "
                "widen acquisition.workspace or move the sphere nearer the middle of the arm's reach")
    after, joints_after = result
    spans, new_spans = _joint_spans_deg(joints), _joint_spans_deg(joints_after)
    # the joints the added stations spread most: what the plan's stations lack
    grown = [int(j) for j in np.argsort(spans / np.maximum(new_spans, 1e-9))
             if new_spans[j] >= max(MIN_SPREAD_GAIN * spans[j], spans[j] + MIN_SPREAD_GAIN_DEG)][:3]
    tilts = ", ".join("[" + ", ".join(f"{v:.1f}" for v in cands.tilts_deg[k]) + "]" for k in added)
    if grown:
        j0 = grown[0]
        text += (f". The stations are too alike: between them joint {j0 + 1} moves over {spans[j0]:.0f} deg only"
                 + "".join(f", joint {j + 1} over {spans[j]:.0f} deg" for j in grown[1:])
                 + ". Add stations that move " + ("it" if len(grown) == 1 else "them") + " further: ")
    else:
        text += ". Add stations: "
    took = (" take " + _and([f"joint {j + 1} over {new_spans[j]:.0f} deg" for j in grown]) + " and") if grown else ""
    figures = f"{int(after['identifiable'].sum())} parameters, condition number {after['condition_number']:.0f}"
    if planned is not None:
        more = len(planned.sweep.tilts_deg) + len(added)
        return (f"{text}ask the planner for {more} (acquisition.kinematic_plan.stations = {more}): its {len(added)} "
                f"more{took} make it {figures} (tilts {tilts})")
    return (f"{text}these {len(added)} (append them to acquisition.sweep.tilts_deg){took} make it {figures}: "
            f"{tilts}. Or leave acquisition.sweep.tilts_deg out and let the kinematic planner choose every station "
            "([acquisition.kinematic_plan], docs/configuration.md)")
