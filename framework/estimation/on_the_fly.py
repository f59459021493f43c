"""Calibration from a recording: a pose stream and a profile stream on two clocks.

The steps (docs/on-the-fly.md):

1. **Which profiles are stations.** Profiles that see the sphere (enough points) keep
   the station of their sweep; a recording that does not say (a ROS 2 bag) has its
   profiles grouped by the flange's orientation once a first clock relation is known.
2. **A robust start for the clock offset, of any size.** The sensor sees the sphere
   appear and disappear only while the robot moves: every offset that maps those
   moments into the pose stream's motion is a candidate (:func:`offset_candidates`,
   seconds to hours wide, on a grid of one pose period). Among the candidates the
   offset at which a subsample's sphere centres follow the robot's moves within each
   station best decides: at the right offset the forth and back passes of a sweep put
   the sphere in one place, at a wrong one they split it by twice the speed times the
   error (:func:`_start_offset`, :func:`_translation_misfit`).
3. **The joint fit** (:mod:`.pipeline`) with the clock relation among the unknowns
   (:mod:`.refine.timing`): offset and drift with the transform, the sphere and the
   robot's error, in one covariance.
4. **What the data say of the time** (:func:`timing_estimate`): the offset's standard
   deviation against what it would be were the transform and sphere known tells whether
   the sweeps separate the offset from the sphere's position.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from spherecal.config import CalibrationOptions
from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError, FitBreakdownError, InputError
from spherecal.core.kinematics import ArmKinematics
from spherecal.core.models import Dataset, ObservationFlag, TimingEstimate
from spherecal.core.streams import Recording, sensor_to_robot_time
from spherecal.estimation.circle import fit_circles
from spherecal.estimation.pipeline import BREAKDOWN_CAUSES, Solution, _solve, with_nominal_comparison
from spherecal.estimation.problem import Problem, orientation_groups, spread_per_station
from spherecal.estimation.refine.linearisation import NoiseAssumptions
from spherecal.estimation.refine.state import RefineState
from spherecal.estimation.refine.timing import TimeEffects, shots_at
from spherecal.estimation.twostep import station_centres

#: Profiles per station the start's search uses (evenly spread over the station).
START_PROFILES_PER_STATION = 48
#: The start's offset is refined down to this step, ms.
START_RESOLUTION_MS = 0.05
#: A pose-stream segment is motion when the flange moves faster than this share of the
#: recording's 95th-percentile speed (and at least MIN_SPEED_MM_S).
MOVING_SHARE = 0.1
MIN_SPEED_MM_S = 1.0
#: The offset is identified when its standard deviation is at most this many times what
#: it would be with the transform and the sphere known (the variance inflation's root).
IDENTIFIED_INFLATION = 30.0
#: ... and at most this, ms.
IDENTIFIED_STD_MS = 1.0
#: Drift is estimated when the recording is long enough to show it: with the offset
#: known to this many ms, a drift of 10 ppm must move the last profile's time by more.
DRIFT_VISIBLE_PPM = 10.0
#: Residuals correlated in time over more than this many profiles (the integrated
#: autocorrelation of :func:`correlation_inflation`) make the fit repeat with the pose
#: noise widened to match.
CORRELATED_SHOTS = 1.5
#: Grouping by orientation (recordings without sweeps): one station's shots turn by less, deg.
STATION_ORIENTATION_TOLERANCE_DEG = 0.5


def solve_recording(
    recording: Recording,
    options: CalibrationOptions | None = None,
    kinematics: ArmKinematics | None = None,
    progress: Callable[[str], None] | None = None,
    offset_ms: float | None = None,
    estimate_drift: bool | None = None,
) -> Solution:
    """Calibrate from ``recording``; see the module docstring. ``offset_ms``: a start for
    the clock offset (in the clocks' own counts), searched within 50 ms of it and refused
    when the recording fits far better elsewhere; ``estimate_drift`` None decides from the
    recording's length and its clocks. The result's ``timing`` holds the clock relation.
    Data so far from the model that the linear algebra breaks down raise
    :class:`~spherecal.core.errors.FitBreakdownError` naming the usual causes."""
    try:
        solution = _solve_recording(recording, options, kinematics, progress, offset_ms, estimate_drift)
    except np.linalg.LinAlgError as exc:
        raise FitBreakdownError(
            f"the fit broke down ({exc}): the recording fits no sphere seen through its poses. Check, most common "
            f"first: {BREAKDOWN_CAUSES}") from None
    return with_nominal_comparison(solution, options.nominal_transform if options is not None else None)


def _solve_recording(recording: Recording, options, kinematics, progress, offset_ms, estimate_drift) -> Solution:
    """:func:`solve_recording` itself."""
    opt = options or CalibrationOptions()
    say = progress or (lambda msg: None)
    recording, epochs = _rebased(recording)
    if offset_ms is not None:
        offset_ms -= 1e3 * (epochs[1] - epochs[0])
    ps, stream = recording.profiles, recording.poses
    seen = ps.counts >= opt.min_points_per_profile
    if not seen.any():
        raise DegenerateDataError(
            f"none of the {ps.n} profiles shows the sphere ({opt.min_points_per_profile} points or more): check the "
            "sweeps pass through it, the sensor's exposure and the profile topic")
    say(f"recording: {stream.n} poses over {stream.t_robot_s[-1] - stream.t_robot_s[0]:.1f} s (robot clock), "
        f"{ps.n} profiles over {ps.t_sensor_s[-1] - ps.t_sensor_s[0]:.1f} s (sensor clock), "
        f"{int(seen.sum())} of them on the sphere")
    q_model = None
    if kinematics is not None and stream.joints_deg is not None:
        q_model = np.array([kinematics.model_joints_rad(q) for q in stream.joints_deg])
    labels, names = _station_labels(recording, seen)
    given_ms = offset_ms
    offset_ms, drift_ppm, start_info = _start_offset(recording, seen, labels, names, opt, say, epochs, given_ms)
    if labels is None:
        labels, names = _labels_by_orientation(recording, seen, offset_ms)
    one_clock = recording.clocks.get("robot") == recording.clocks.get("sensor")
    if estimate_drift is None and one_clock:
        say(f"both streams were stamped by one clock ({recording.clocks.get('robot')}): no drift between the robot's "
            "and the sensor's clocks can be seen; it is held at 0 (the offset is the difference of the two "
            "stamping paths' latencies)")
        drift_ppm, estimate_drift = 0.0, False
    drift = _drift_visible(recording) if estimate_drift is None else estimate_drift
    te = TimeEffects(stream, recording.t_sensor0_s, offset_ms, drift_ppm if drift else 0.0, drift, q_model)
    rows = np.flatnonzero(seen & (labels >= 0))
    problem, flags = _problem(recording, rows, labels, names, te, q_model is not None, epochs)
    for f in flags[:5]:
        say(f"profile {f.index}: {f.reason}")
    if len(flags) > 5:
        say(f"... {len(flags) - 5} more profiles without a pose left out")
    dataset = Dataset(mounting=recording.mounting, sphere_radius_mm=recording.sphere_radius_mm,
                      provenance=recording.provenance)
    joints = problem.q_rad is not None
    detail: dict = {}

    def reweigh(clean: Problem, ref, noise: NoiseAssumptions) -> NoiseAssumptions | None:
        # the robot's repeatability error is smooth in time: profiles taken within its
        # correlation time share it. Weighted as independent, it would pass for station-to-
        # station error (the station model takes it in) and the spread would be too small;
        # weighted as this many times its variance per profile, the profiles of a station
        # weigh what their independent looks weigh
        shots, found = correlation_inflation(clean, ref)
        detail.update(found)
        if shots <= CORRELATED_SHOTS or not ref.converged:  # (a fit of nothing says nothing of time)
            return None
        widen = float(np.sqrt(shots * ref.pose_noise_scale))
        say(f"the residuals are correlated in time over {shots:.1f} profiles: the robot's pose noise is taken "
            f"{np.sqrt(shots):.2f} times larger per profile, and the fit repeated")
        return NoiseAssumptions(noise.point_noise_mm, max(noise.pose_translation_noise_mm, 1e-4) * widen,
                                max(noise.pose_rotation_noise_deg, 1e-5) * widen)

    solution = _solve(dataset, problem, opt, say, kinematics, joints, list(flags), time_effects=te, reweigh=reweigh)
    ref = solution.refined
    timing = timing_estimate(ref, te, start_info["offset_ms"], epochs)
    diag = solution.result.diagnostics.model_copy(update={"refinement": {
        **(solution.result.diagnostics.refinement or {}), "time_correlation": detail}})
    if recording.poses_assumption:
        say(f"pose stream: {recording.poses_assumption}")
        timing = timing.model_copy(update={"poses_assumed": recording.poses_assumption})
    result = solution.result.model_copy(update={
        "timing": timing, "diagnostics": diag,
        "provenance": {**solution.result.provenance, "recording": recording.provenance.get("source", "unknown")},
    })
    final = shots_at(solution.problem, te, np.array([ref.timing["offset_ms"], ref.timing["drift_ppm"]])).problem
    return replace(solution, result=result, problem=final)


def _rebased(recording: Recording) -> tuple[Recording, tuple[float, float]]:
    """``recording`` with each clock counted from a whole second near its start, and those
    seconds (sensor, robot). A clock counting from 1970 resolves 0.24 us at best; the fit's
    steps are finer, and the difference of two such epochs finer still: the fit works in
    these small numbers, the result is said in the clocks' own."""
    s0 = float(np.floor(recording.profiles.t_sensor_s[0]))
    r0 = float(np.floor(recording.poses.t_robot_s[0]))
    ps, st = recording.profiles, recording.poses
    return replace(recording, profiles=replace(ps, t_sensor_s=ps.t_sensor_s - s0),
                   poses=replace(st, t_robot_s=st.t_robot_s - r0)), (s0, r0)


def correlation_inflation(problem: Problem, ref) -> tuple[float, dict]:
    """How many consecutive profiles share the robot's pose noise: the integrated
    autocorrelation time (in profiles) of each profile's mean residual and of its
    circle's shift along y and z (the pose noise as each profile sees it), along each run
    of consecutive profiles, corrected for the white point noise in them, the largest of
    the three; 1 for white noise.

    The fit weighs every profile's pose noise as independent; a robot's repeatability
    error is smooth over tens of milliseconds, so profiles taken at hundreds per second
    share it, and the data hold fewer independent looks than profiles."""
    n = problem.n_profiles
    signals = np.zeros((n, 3))
    C = ref.predicted
    for i, (p, res) in enumerate(zip(problem.profiles, ref.residuals)):
        if len(res) == 0:
            continue
        d = p - C[i, 1:]
        u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        signals[i] = [res.mean(), (res * u[:, 0]).mean(), (res * u[:, 1]).mean()]
    order = np.argsort(problem.t_sensor_s)
    t = problem.t_sensor_s[order]
    period = float(np.median(np.diff(t))) if n > 1 else 1.0
    breaks = np.flatnonzero((np.diff(t) > 3 * period) | (np.diff(problem.station_of[order]) != 0)) + 1
    runs = [r for r in np.split(order, breaks) if len(r) >= 8]
    if not runs:
        return 1.0, {"integrated_autocorrelation_shots": 1.0, "runs": 0}
    max_lag = min(200, max(len(r) for r in runs) // 2)
    taus = []
    for k in range(3):
        num = np.zeros(max_lag + 1)
        for r in runs:
            x = signals[r, k] - signals[r, k].mean()
            for lag in range(min(max_lag, len(x) - 1) + 1):
                num[lag] += float(x[:len(x) - lag] @ x[lag:])
        if num[0] <= 0:
            continue
        rho = num / num[0]
        tau = 1.0
        for lag in range(1, max_lag + 1):
            if rho[lag] < 0.05:
                break
            tau += 2.0 * rho[lag]
        # the white point noise in the signal lowers every lag alike: the smooth part's
        # own correlation is rho / rho_1 (its share of the variance is about rho_1)
        if max_lag >= 1 and rho[1] > 0.1:
            tau = 1.0 + (tau - 1.0) / rho[1]
        taus.append(tau)
    factor = max(taus) if taus else 1.0
    return float(factor), {"integrated_autocorrelation_shots": float(factor), "runs": len(runs)}


def _station_labels(recording: Recording, seen: np.ndarray) -> tuple[np.ndarray | None, list[str]]:
    """Each profile's station number (-1 outside a sweep) and the station names, from
    the recording's sweeps; (None, []) when it has none."""
    ps = recording.profiles
    if ps.sweep is None or not recording.sweeps:
        return None, []
    names: list[str] = []
    of_sweep = []
    for sw in recording.sweeps:
        if sw.station not in names:
            names.append(sw.station)
        of_sweep.append(names.index(sw.station))
    of_sweep = np.array(of_sweep + [-1])
    sweep = np.where((ps.sweep >= 0) & (ps.sweep < len(recording.sweeps)), ps.sweep, -1)
    return of_sweep[sweep], names


def _labels_by_orientation(recording: Recording, seen: np.ndarray, offset_ms: float) -> tuple[np.ndarray, list[str]]:
    """Stations as the groups of profiles that share the flange's orientation."""
    ps = recording.profiles
    at = recording.poses.at(sensor_to_robot_time(ps.t_sensor_s, offset_ms * 1e-3, 0.0, recording.t_sensor0_s))
    labels = np.full(ps.n, -1)
    rows = np.flatnonzero(seen & at.ok)
    for k, members in enumerate(orientation_groups(at.R[rows], STATION_ORIENTATION_TOLERANCE_DEG)):
        labels[rows[members]] = k
    return labels, [f"orientation {k + 1}" for k in range(int(labels.max()) + 1)]


def _problem(recording: Recording, rows: np.ndarray, labels: np.ndarray, names: list[str], te: TimeEffects,
             with_joints: bool, epochs: tuple[float, float] = (0.0, 0.0)) -> tuple[Problem, list[ObservationFlag]]:
    """The problem of profiles ``rows`` with their poses read at ``te``'s start; the
    profiles whose time falls outside the pose stream or in a gap of it left out and
    flagged (never interpolated across; the times said in the clocks' own counts,
    ``epochs`` added back)."""
    ps = recording.profiles
    t_r = te.robot_times(ps.t_sensor_s[rows], te.start())
    ok = recording.poses.at(t_r).ok
    ramp = recording.poses.ramp_at(t_r)
    gaps = recording.poses.gaps()
    flags = []
    s0, r0 = epochs
    for j, t, on_ramp in zip(rows[~ok], t_r[~ok], ramp[~ok]):
        gap = next(((a, b) for a, b in gaps if a < t < b), None)
        where = (f"in a gap of the pose stream ({gap[0] + r0:.3f} to {gap[1] + r0:.3f} s, robot clock)"
                 if gap is not None else "on a speed ramp of a computed pose stream (the acceleration there is "
                 "assumed)" if on_ramp else "outside the pose stream's time span")
        flags.append(ObservationFlag(index=int(j), station=names[labels[j]] if labels[j] >= 0 else "-",
                                     reason=f"sensor time {ps.t_sensor_s[j] + s0:.6f} s maps to robot time "
                                            f"{t + r0:.6f} s, "
                                            f"{where}: no measured pose, left out"))
    rows = rows[ok]
    if not len(rows):
        raise DegenerateDataError("no profile on the sphere falls within the pose stream at the clock offset found")
    used = sorted(set(labels[rows].tolist()))
    remap = {old: new for new, old in enumerate(used)}
    n = len(rows)
    blank = Problem(recording.mounting, recording.sphere_radius_mm, np.tile(np.eye(3), (n, 1, 1)), np.zeros((n, 3)),
                    np.tile(np.eye(3), (n, 1, 1)), np.zeros((n, 3)), [ps.profile(j) for j in rows], rows.copy(),
                    np.array([remap[s] for s in labels[rows]]), [names[k] for k in used],
                    np.zeros((n, 6)) if with_joints else None, t_sensor_s=ps.t_sensor_s[rows])
    return shots_at(blank, te, te.start()).problem, flags


def _drift_visible(recording: Recording) -> bool:
    """Whether the recording is long enough for a drift to show (DRIFT_VISIBLE_PPM)."""
    span = recording.profiles.t_sensor_s[-1] - recording.profiles.t_sensor_s[0]
    return bool(DRIFT_VISIBLE_PPM * 1e-6 * span > 2 * START_RESOLUTION_MS * 1e-3)


def offset_candidates(recording: Recording, seen: np.ndarray) -> list[tuple[float, float]]:
    """Intervals of clock offsets (ms) under which every moment the sensor starts or stops
    seeing the sphere falls where the robot moves, best first (the largest share of such
    moments). Searched over every offset that puts the profiles and the pose stream
    side by side (any difference of epochs), on a grid of one pose period."""
    stream, ps = recording.poses, recording.profiles
    tau = stream.t_robot_s
    speed = np.linalg.norm(np.diff(stream.t_mm, axis=0), axis=1) / np.diff(tau)
    threshold = max(MOVING_SHARE * float(np.percentile(speed, 95)), MIN_SPEED_MM_S)
    moving = speed > threshold
    change = np.flatnonzero(seen[1:] != seen[:-1])
    if not len(change):
        raise DegenerateDataError(
            "the sensor sees the sphere in every profile or in none: the sweeps must carry the laser line onto the "
            "sphere and off it, so that the moments it appears tell the clock offset")
    t_events = 0.5 * (ps.t_sensor_s[change] + ps.t_sensor_s[change + 1])
    t_seen = ps.t_sensor_s[seen]
    step = stream.period_s
    lo, hi = tau[0] - t_seen[-1], tau[-1] - t_seen[0]
    n_grid = int((hi - lo) / step) + 1
    if n_grid > 2_000_000:
        step = (hi - lo) / 2_000_000
        n_grid = 2_000_001
    offsets = lo + step * np.arange(n_grid)
    score = np.zeros(n_grid)
    chunk = max(1, 4_000_000 // max(len(t_events), 1))
    for a in range(0, n_grid, chunk):
        off = offsets[a:a + chunk, None]
        k = np.searchsorted(tau, t_events[None, :] + off) - 1
        inside = (k >= 0) & (k < len(moving))
        hits = np.where(inside, moving[np.clip(k, 0, len(moving) - 1)], False)
        # share of the events in motion, and of the profiles on the sphere inside the stream
        covered = (np.searchsorted(tau, t_seen[0] + off[:, 0]) > 0) & (t_seen[-1] + off[:, 0] < tau[-1])
        score[a:a + chunk] = hits.mean(axis=1) * (0.5 + 0.5 * covered)
    best = score.max()
    top = score >= best - 1e-12
    edges = np.flatnonzero(np.diff(np.concatenate([[0], top.astype(int), [0]])))
    runs = [(offsets[s] * 1e3 - step * 1e3, offsets[e - 1] * 1e3 + step * 1e3) for s, e in zip(edges[::2], edges[1::2])]
    return runs


def _start_offset(recording: Recording, seen: np.ndarray, labels, names, opt, say,
                  epochs: tuple[float, float] = (0.0, 0.0), given_ms: float | None = None) -> tuple[float, float, dict]:
    """The offset (ms) and drift (ppm) the fit starts from and how they were found: the
    candidates (:func:`offset_candidates`), the offset at which a subsample's sphere
    centres follow the robot's moves best (:func:`_translation_misfit`), then each
    station's own best offset, whose trend over the recording is the drift. A ``given_ms``
    (the user's, in the rebased counts) is searched around instead, and refused, naming
    it, when the recording fits far better elsewhere."""
    runs = offset_candidates(recording, seen)
    if given_ms is not None:
        runs = [(given_ms - 50.0, given_ms + 50.0)] + runs
    if labels is None:
        mid = 0.5 * (runs[0][0] + runs[0][1])
        labels, names = _labels_by_orientation(recording, seen, mid)
    rows = spread_per_station(np.flatnonzero(seen & (labels >= 0)), labels, START_PROFILES_PER_STATION)
    ps = recording.profiles
    fits_list = fit_circles([ps.profile(j) for j in rows], outlier_k=opt.point_outlier_k)
    radius = recording.sphere_radius_mm
    largest = float(np.percentile([f.radius for f in fits_list if f.n_inliers >= opt.min_points_per_profile] or [0.0], 98))
    if 0 < largest < 0.6 * radius:
        raise InputError(
            f"the sphere's radius is given as {radius:g} mm, but the largest circles the profiles show are "
            f"{largest:.2f} mm: sweeps through the sphere reach its radius. The diameter given as the radius? "
            f"(--sphere-radius-mm, or the recording's sphere_radius_mm)")
    good = np.array([f.radius < radius and f.n_inliers >= opt.min_points_per_profile for f in fits_list])
    rows = rows[good]
    fits = {i: f for i, f in enumerate(f for f, g in zip(fits_list, good) if g)}
    te0 = TimeEffects(recording.poses, recording.t_sensor0_s, 0.0, 0.0, False)

    def cost(offset_ms: float, drift_ppm: float = 0.0, station: int | None = None) -> float:
        te = replace(te0, offset_ms=offset_ms, drift_ppm=drift_ppm)
        use = np.arange(len(rows)) if station is None else np.flatnonzero(labels[rows] == station)
        ok = recording.poses.at(te.robot_times(ps.t_sensor_s[rows[use]], te.start())).ok
        if ok.mean() < 0.9:
            return np.inf
        keep = use[ok]
        problem, _ = _problem(recording, rows[keep], labels, names, te, False)
        return _translation_misfit(problem, {j: fits[int(i)] for j, i in enumerate(keep)})

    say(f"searching the clock offset: {len(runs)} candidate interval(s), "
        f"{runs[0][1] - runs[0][0]:.0f} ms wide; {len(rows)} profiles' sphere centres against the robot's moves at "
        "each trial offset")
    trials: list[tuple[float, float]] = []
    for lo, hi in runs[:40]:
        for x in np.linspace(lo, hi, max(3, min(41, int((hi - lo) / 2.0) + 1))):
            trials.append((cost(float(x)), float(x)))
    trials.sort()
    if given_ms is not None:
        near = [t for t in trials if abs(t[1] - given_ms) <= 50.0]
        shift_ms = 1e3 * (epochs[1] - epochs[0])
        if not near or not np.isfinite(min(near)[0]) or min(near)[0] > 3.0 * trials[0][0] + 0.01:
            at_given = min(near)[0] if near else np.inf
            there = (f"the recording's sphere centres lie {at_given:.3g} mm RMS from the robot's moves"
                     if np.isfinite(at_given) else "the profiles fall outside the pose stream or fit no sphere")
            raise InputError(
                f"--clock-offset-ms {given_ms + shift_ms:.3f}: within 50 ms of it {there}; at about "
                f"{trials[0][1] + shift_ms:.1f} ms they lie {trials[0][0]:.3g} mm from them: the offset given is "
                "wrong. Leave it out to have it searched")
        trials = near
    if not np.isfinite(trials[0][0]):
        raise DegenerateDataError(
            "no clock offset makes the recording's sphere centres follow the robot's moves: check the mounting, the "
            "sphere's radius and the topics")
    best_cost, best = trials[0]
    width = max(max((hi - lo) / 40 for lo, hi in runs[:1]), 2.0)
    best, best_cost = _zoom(cost, best, best_cost, width)
    # each station's own offset: their trend over the recording is the drift's start
    t_mid, offs = [], []
    for k in np.unique(labels[rows]):
        members = rows[labels[rows] == k]
        c0 = cost(best, 0.0, int(k))
        if np.isfinite(c0):
            o, _ = _zoom(lambda x: cost(x, 0.0, int(k)), best, c0, 1.0)
            t_mid.append(float(np.mean(ps.t_sensor_s[members])) - recording.t_sensor0_s)
            offs.append(o)
    drift_ppm, offset0 = 0.0, best
    if len(offs) >= 2 and np.ptp(t_mid) > 0:
        slope, intercept = np.polyfit(t_mid, offs, 1)
        drift_ppm, offset0 = float(slope * 1e3), float(intercept)  # ms per s = 1e3 ppm
    say(f"clock start: offset {offset0 + 1e3 * (epochs[1] - epochs[0]):.2f} ms (robot clock minus sensor clock), drift "
        f"{drift_ppm:.0f} ppm, the sphere centres {best_cost:.4f} mm RMS from the robot's moves")
    return offset0, drift_ppm, {"offset_ms": offset0, "drift_ppm": drift_ppm, "candidates": len(runs),
                                "rms_mm": best_cost}


def _zoom(cost, best: float, best_cost: float, width: float) -> tuple[float, float]:
    """``best`` refined by grids of nine, each a quarter as wide, to START_RESOLUTION_MS."""
    while width > START_RESOLUTION_MS:
        for x in best + width * np.linspace(-1, 1, 9):
            c = cost(float(x))
            if c < best_cost:
                best_cost, best = c, float(x)
        width /= 4
    return best, best_cost


def _translation_misfit(problem: Problem, fits: dict) -> float:
    """RMS (mm) of the sphere centres seen in each station against the robot's moves
    within it, each station with its own best rotation and side of the laser plane (the
    two-step's first step, station by station: cheap, and at a wrong offset the passes of
    a sweep disagree by the speed times the error)."""
    sq, n = 0.0, 0
    for k in range(len(problem.station_labels)):
        st = station_centres(problem, fits, k)
        if st.rank < 2 or not st.candidates:
            continue
        best = np.inf
        for cand in st.candidates:
            A = cand - cand.mean(axis=0)
            R = geo.proper_procrustes(A.T, st.d.T)
            best = min(best, float(np.sum((A @ R.T - st.d) ** 2)))
        sq += best
        n += len(st.d)
    return float(np.sqrt(sq / n)) if n else np.inf


def timing_estimate(ref, te: TimeEffects, start_offset_ms: float,
                    epochs: tuple[float, float] = (0.0, 0.0)) -> TimingEstimate:
    """The result's clock relation with its identifiability (module docstring, step 4),
    in the clocks' own counts (``epochs``: the seconds :func:`_rebased` took off each)."""
    tm = ref.timing
    shift_ms = 1e3 * (epochs[1] - epochs[0])
    cov = np.asarray(tm["covariance"], dtype=float)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = float(cov[0, 1] / (sd[0] * sd[1])) if sd[0] > 0 and sd[1] > 0 else 0.0
    known = ref.diagnostics.get("offset_std_ms_known_geometry")
    inflation = float(sd[0] / known) if known else float("nan")
    identifiable = bool(sd[0] <= IDENTIFIED_STD_MS and (not np.isfinite(inflation) or inflation <= IDENTIFIED_INFLATION))
    if identifiable:
        text = (f"the sweeps separate the clock offset from the sphere's position: {tm['offset_ms'] + shift_ms:.3f} "
                f"+/- {sd[0]:.3f} ms")
    else:
        text = (f"the clock offset is not separated from the sphere's position (+/- {sd[0]:.3g} ms"
                + (f", {inflation:.0f} times what the same data give with the geometry known" if np.isfinite(inflation)
                   else "") + "): a constant offset moves every profile along its sweep, which a shifted sphere "
                "explains as well. Add sweeps in the opposite direction (forth and back) and at a second speed")
    return TimingEstimate(
        offset_ms=tm["offset_ms"] + shift_ms, offset_std_ms=float(sd[0]), drift_ppm=tm["drift_ppm"],
        drift_std_ppm=float(sd[1]), drift_estimated=bool(tm["drift_estimated"]), t_sensor0_s=te.t_sensor0_s + epochs[0],
        offset_drift_correlation=corr, identifiable=identifiable, identifiability=text,
        start_offset_ms=start_offset_ms + shift_ms)


def timing_with_geometry_known(recording: Recording, solution: Solution, R, t, centre) -> tuple[float, float]:
    """The clock relation (offset ms in the clocks' own counts, drift ppm) fitted with the
    transform (``R``, ``t``) and the sphere's ``centre`` held at given values, on the
    profiles ``solution`` used, at its noise model: the floor any estimator of the time
    reaches on these data when the geometry is known (a benchmark's oracle, with the
    simulated truth)."""
    rec, epochs = _rebased(recording)
    tm = solution.result.timing
    start_ms = tm.offset_ms - 1e3 * (epochs[1] - epochs[0])
    problem = solution.problem
    te = TimeEffects(rec.poses, rec.t_sensor0_s, start_ms, tm.drift_ppm, tm.drift_estimated)
    base = replace(problem, t_sensor_s=rec.profiles.t_sensor_s[problem.obs_index])
    noise = NoiseAssumptions(float(solution.result.diagnostics.noise["point_noise_mm"]),
                             float(solution.result.diagnostics.noise["pose_translation_noise_mm"]),
                             float(solution.result.diagnostics.noise["pose_rotation_noise_deg"]))
    fit = RefineState(base, R, t, centre, noise, False, None, None, te)
    n0 = fit.n_par - fit.n_time
    for _ in range(20):
        lin = fit.linearise(1.0)
        cols = fit.design(lin)[0][:, :, n0:]
        step = np.linalg.solve(lin.red.gram(cols, cols), lin.red.rhs(cols))
        tau = fit.tau.copy()
        tau[:fit.n_time] += step
        fit.set_tau(tau)
        if np.abs(step).max() < 1e-9:
            break
    return float(fit.tau[0] + 1e3 * (epochs[1] - epochs[0])), float(fit.tau[1])
