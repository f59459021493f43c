"""Simulated on-the-fly acquisition: continuous sweeps recorded as a pose stream on the
robot's clock and a profile stream on the sensor's (:class:`spherecal.core.streams.Recording`).

The world is harder than the estimator's model, on purpose:

- **Motion** in continuous true time T (s, 0 at the recording's start): at each station
  of a stop-and-go plan (:class:`~spherecal.config.SweepPlan`, planned with the cell's
  true transform as :func:`~spherecal.sim.simulate_dataset` does) straight MoveL sweeps
  with a trapezoidal speed profile (:class:`~spherecal.config.OnTheFlyPlan`), and
  Cartesian moves with reorientation between them. With an arm attached to the cell
  the controller turns the path into joints with its nominal inverse kinematics (at
  knots every few millimetres or a degree along each move, each seeded with the one
  before, joined by cubic splines in the move's path parameter); the flange goes where
  the arm's true geometry puts it and the controller reports its nominal model's pose.
- **Repeatability noise** smooth in time: the true flange moves off that pose by a
  first-order Gauss-Markov process per base axis (translation and rotation, errors in
  the base frame: reported = (exp([eps_r]) R_true, t_true + eps_t), as
  docs/conventions.md states), so the joints and the reported pose always agree.
- **The pose stream** samples every ``period_s`` of the robot's clock; each stamp is off
  the instant its pose was taken by a small jitter; samples are lost one at a time and
  in bursts (their sequence numbers are missing).
- **The profiler** exposes every 1 / ``rate_hz`` of its own clock; each stamp is the
  exposure's middle plus the sensor's constant latency, an undeclared extra latency and
  a jitter. A profile that sees nothing is kept, empty (a profiler delivers a frame per
  exposure; its frame counter runs on), so that profile and frame numbers line up.
- **Two clocks** against true time: robot ``E_r + (1 + rho_r) T``, sensor
  ``E_s + (1 + rho_s) T`` (:class:`~spherecal.config.ClockSettings`).

The truth of the time relation (``recording.provenance``): with ``t_sensor0`` the first
profile's stamp,

    t_robot = t_sensor + true_offset_s + true_drift * (t_sensor - t_sensor0)

is the robot-clock time at which the pose stream holds the pose the profile was measured
at (the exposure's middle), for every profile, up to that profile's stamp jitter. With
linear clocks this is exact, not only to first order in the rates: ``true_drift =
(1 + rho_r) / (1 + rho_s) - 1`` and ``true_offset_s = E_r + (1 + true_drift) (t_sensor0 -
E_s - latency) - t_sensor0``, the latency being the sensor's declared one plus the extra.
``true_offset_without_extra_latency_s`` is the same without the undeclared part.

Everything drawn comes from two seeded generators: the streams' (timing, losses, pose
noise; ``StreamSimSettings.seed``, default the cell's seed) and the cell's own (the
profiles' point noise and strays, as :meth:`SimulatedCell.measure_profile` draws them),
so the same cell, plan and settings give the same recording.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spherecal.config import OnTheFlyPlan, StreamSimSettings, SweepPlan
from spherecal.core import geometry as geo
from spherecal.core.streams import PoseStream, ProfileStream, Recording, SweepInfo
from spherecal.motion.planning import plan_stations, sweep_ends_in_sensor_mm, with_standoff
from spherecal.sim.cell import SimulatedCell
from spherecal.sim.objects import BallBar, Sphere
from spherecal.sim.timeline import (KNOT_DEG, KNOT_MM, MotionTimeline, Segment, _gauss_markov, _grid,  # noqa: F401
                                    _losses, _trapezoid_duration, _with_noise)

__all__ = ["Segment", "StreamTruth", "plan_segments", "simulate_recording", "simulate_recording_with_truth"]

#: The recording's clock names (:attr:`Recording.clocks`): two clocks, so a drift is there to see.
CLOCK_NAMES = {"robot": "spherecal simulated controller", "sensor": "spherecal simulated profiler"}
#: Poses ray-cast at once (bounds the temporary arrays' memory).
CHUNK_PROFILES = 256


def _flange_translation_mm(cell: SimulatedCell, R_bf: np.ndarray, centre_in_sensor_mm: np.ndarray) -> np.ndarray:
    """The flange translation (base, mm) that, with the flange rotation ``R_bf``, puts
    the sphere centre at ``centre_in_sensor_mm`` (..., 3) in the sensor frame (the cell's
    true transform)."""
    X = cell.true_transform
    R_x, t_x = X.rotation_matrix, X.translation
    c = np.asarray(centre_in_sensor_mm, dtype=float)
    if cell.mounting == "eye_in_hand":  # base_from_sensor = base_from_flange X maps c to the sphere centre
        return cell.sphere_centre_mm - c @ (R_bf @ R_x).T - R_bf @ t_x
    return c @ R_x.T + t_x - R_bf @ cell.sphere_centre_mm  # the sphere on the flange, at X c in base


def plan_segments(cell: SimulatedCell, plan: SweepPlan | None = None, otf: OnTheFlyPlan | None = None,
                  lead_in_s: float = 0.2) -> tuple[list[Segment], list[SweepInfo]]:
    """The commanded motion of an on-the-fly recording on ``cell``: its segments in
    true time (a standstill of ``lead_in_s`` first) and its sweeps. ``plan`` gives the
    stations (orientation, and where in the field of view the sphere crosses the laser
    plane: ``station_offsets_mm`` at ``standoff_z_mm``), ``otf`` the sweeps at each."""
    plan = with_standoff(plan or SweepPlan(), cell.fov, cell.sphere_radius_mm)
    otf = otf or OnTheFlyPlan()
    stations = plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm, plan)
    if otf.stations is not None:
        stations = stations[:otf.stations]
    r = cell.sphere_radius_mm
    a = otf.acceleration_mm_s2
    segments: list[Segment] = []
    sweeps: list[SweepInfo] = []
    T = 0.0
    pose: tuple[np.ndarray, np.ndarray] | None = None

    def add(kind, sweep, station, R0, t0, R1, t1, length, speed, duration):
        nonlocal T
        segments.append(Segment(kind, sweep, station, T, duration, R0, np.asarray(t0, float), R1,
                                np.asarray(t1, float), length, speed, a))
        T += duration

    def pause(station, seconds):
        if seconds > 0:
            add("pause", -1, station, pose[0], pose[1], pose[0], pose[1], 0.0, 1.0, seconds)

    for k, (label, poses) in enumerate(stations):
        R_k = poses[0].rotation_matrix
        for d in otf.directions_in_sensor:
            ends = _flange_translation_mm(cell, R_k, sweep_ends_in_sensor_mm(plan, otf, r, k, d))
            flange_dir = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
            for v in otf.speeds_mm_s:
                for start, end, sign in ((ends[0], ends[1], 1.0), (ends[1], ends[0], -1.0)):
                    if pose is None:
                        pose = (R_k, start)
                        pause(label, lead_in_s)
                    move = float(np.linalg.norm(start - pose[1]))
                    turn_deg = geo.rotation_angle_deg(pose[0], R_k)
                    if move > 1e-9 or turn_deg > 1e-9:
                        length = max(move, turn_deg * otf.transit_speed_mm_s / otf.transit_speed_deg_s)
                        add("transit", -1, label, pose[0], pose[1], R_k, start, length, otf.transit_speed_mm_s,
                            _trapezoid_duration(length, otf.transit_speed_mm_s, a))
                        pose = (R_k, start)
                        pause(label, otf.pause_s)
                    length = float(np.linalg.norm(end - start))
                    sweeps.append(SweepInfo(station=label, speed_mm_s=float(v),
                                            direction=tuple(float(c) for c in sign * flange_dir)))
                    add("sweep", len(sweeps) - 1, label, R_k, start, R_k, end, length, float(v),
                        _trapezoid_duration(length, float(v), a))
                    pose = (R_k, end)
                    pause(label, otf.pause_s)
    return segments, sweeps


@dataclass(frozen=True)
class StreamTruth:
    """What the simulator knows and a recording does not say, per profile and per pose
    sample (true time T in s from the recording's start).

    Per profile (m): ``profile_T_s`` the exposure's middle; ``profile_robot_time_s`` the
    robot clock's reading then (where the pose stream holds the pose the profile was
    measured at); ``profile_R``, ``profile_t_mm`` the true base_from_flange then;
    ``profile_reported_R``, ``profile_reported_t_mm`` what the controller would report
    then (its nominal pose; without an arm, the commanded one): the pose stream's
    noise-free value. Per pose sample, lost ones included (n): ``sample_T_s``,
    ``sample_kept``, and ``sample_noise`` (n, 6): the repeatability noise (eps_t mm,
    eps_r rad, base frame) at that instant. ``segments``: the commanded motion."""

    profile_T_s: np.ndarray
    profile_robot_time_s: np.ndarray
    profile_R: np.ndarray
    profile_t_mm: np.ndarray
    profile_reported_R: np.ndarray
    profile_reported_t_mm: np.ndarray
    sample_T_s: np.ndarray
    sample_kept: np.ndarray
    sample_noise: np.ndarray
    segments: list[Segment]


def _frame_from_sensor(cell: SimulatedCell, frame: str, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R (m, 3, 3), t (m, 3)) of ``base_from_sensor`` or ``flange_from_sensor`` (``frame``)
    at true flange poses (R, t): :meth:`SimulatedCell.frame_from_sensor` for many."""
    X = cell.true_transform
    R_x, t_x = X.rotation_matrix, X.translation
    m = len(R)
    fixed = (np.broadcast_to(R_x, (m, 3, 3)), np.broadcast_to(t_x, (m, 3)))
    if frame not in ("base", "flange"):
        raise ValueError(f"frame must be 'base' or 'flange', got {frame!r}")
    if cell.mounting == "eye_in_hand":
        return (R @ R_x, R @ t_x + t) if frame == "base" else fixed
    if frame == "base":
        return fixed
    Rt = np.swapaxes(R, 1, 2)  # flange_from_base X
    return Rt @ R_x, np.einsum("nij,nj->ni", Rt, t_x - t)


def _sphere_centres_in_sensor(cell: SimulatedCell, R: np.ndarray, t: np.ndarray, sphere: Sphere | None = None) -> \
        np.ndarray:
    """A sphere's centre (default the reference sphere's) in the sensor frame (m, 3) at
    true flange poses (R, t)."""
    sphere = sphere or cell.reference_sphere
    Rf, tf = _frame_from_sensor(cell, sphere.frame, R, t)
    return np.einsum("nji,nj->ni", Rf, sphere.centre_mm - tf)


def _spheres_of(obj) -> list[Sphere]:
    """The spheres an object is made of (a sphere, a ball bar's two), or none."""
    return [obj] if isinstance(obj, Sphere) else [obj.sphere_a, obj.sphere_b] if isinstance(obj, BallBar) else []


def _may_reach(obj, Rf: np.ndarray, tf: np.ndarray, apex_z_mm: float, far_z_mm: float) -> np.ndarray:
    """Which poses' laser fans may meet ``obj`` within the measuring range (k,): all of
    them for an object that gives no bounding sphere; else those whose laser plane cuts
    the sphere, with part of it below the fan's apex and above the far end of the range.
    A hit beyond the far end would be dropped, and would hide nothing nearer: skipping
    it changes no profile. ``Rf``, ``tf``: frame_from_sensor of the object's frame."""
    bounds = getattr(obj, "bounding_sphere_mm", None)
    if bounds is None:
        return np.ones(len(Rf), dtype=bool)
    centre, radius = bounds()
    c = np.einsum("kji,kj->ki", Rf, np.asarray(centre, dtype=float) - tf)  # in the sensor frame
    return (np.abs(c[:, 0]) < radius) & (c[:, 2] - radius < apex_z_mm) & (c[:, 2] + radius > far_z_mm)


def _cast_fan(cell: SimulatedCell, R: np.ndarray, t: np.ndarray, point_noise_mm: float = 0.0) -> \
        tuple[np.ndarray, np.ndarray]:
    """Fan hits at many true flange poses (R (m, 3, 3), t (m, 3)): points (N, 2) and
    per-profile starts (m + 1,). What :meth:`SimulatedCell.cast_fan` does pose by pose,
    for a chunk of poses at a time: the nearest surface along each ray over all the
    scene's objects, spheres cut in the laser plane (a circle met in 2-D), other objects
    through their ``intersect``, hits outside the measuring range dropped. With
    ``point_noise_mm`` the cell's generator adds Gaussian noise to y and z of every
    point. In a scene of spheres alone, only the poses whose laser plane cuts one are cast."""
    apex, d = cell.fan_rays()
    (a_y, a_z), d_yz = apex[1:], d[:, 1:]
    near, far = cell.fov.z_near_mm, cell.fov.z_far_mm
    m, n_col = len(R), len(d)
    counts = np.zeros(m, dtype=np.int64)
    spheres = [[(sph, _sphere_centres_in_sensor(cell, R, t, sph)) for sph in _spheres_of(obj)] for obj in cell.objects]
    if all(spheres):  # spheres alone: a pose sees something only where its laser plane cuts one
        cut = np.flatnonzero(np.any([np.abs(c[:, 0]) < sph.radius_mm for per in spheres for sph, c in per], axis=0))
    else:
        cut = np.arange(m)
    # room for every column of every pose cast: pages never written take no memory, and the
    # array is cut to the points found at the end (in place), so the points exist once
    out = np.empty((len(cut) * n_col, 2))
    n = 0
    for lo in range(0, len(cut), CHUNK_PROFILES):
        rows = cut[lo:lo + CHUNK_PROFILES]
        dist = np.full((len(rows), n_col), np.inf)
        for obj, per in zip(cell.objects, spheres):
            for sph, centres in per:
                c = centres[rows]
                w = apex[1:] - c[:, 1:]  # (k, 2)
                b = w @ d_yz.T  # (k, n_columns)
                disc = b * b
                disc -= (np.einsum("kj,kj->k", w, w) - (sph.radius_mm ** 2 - c[:, 0] ** 2))[:, None]
                hit = disc > 0
                np.sqrt(np.maximum(disc, 0.0, out=disc), out=disc)
                s = np.negative(b, out=b)
                s -= disc  # the nearer root
                hit &= s > 0
                np.minimum(dist, np.where(hit, s, np.inf), out=dist)
            if not per:  # any other object: its own ray intersection, the rays in its frame
                Rf, tf = _frame_from_sensor(cell, obj.frame, R[rows], t[rows])
                reach = _may_reach(obj, Rf, tf, apex[2], far)
                if not reach.any():
                    continue
                Rf, tf = Rf[reach], tf[reach]
                origins = np.einsum("kij,j->ki", Rf, apex) + tf
                dirs = np.einsum("kij,cj->kci", Rf, d)
                s = obj.intersect(np.repeat(origins, n_col, axis=0), dirs.reshape(-1, 3))
                dist[reach] = np.minimum(dist[reach], np.asarray(s, dtype=float).reshape(len(Rf), n_col))
        hit = np.isfinite(dist)
        dist[~hit] = 0.0
        z = a_z + dist * d_yz[:, 1]
        hit &= (z <= near) & (z >= far)
        y = np.multiply(dist, d_yz[:, 0], out=dist)
        y += a_y
        counts[rows] = hit.sum(axis=1)
        k = int(counts[rows].sum())
        chunk = out[n:n + k]
        chunk[:, 0], chunk[:, 1] = y[hit], z[hit]  # row-major: pose by pose, in column order
        if point_noise_mm > 0:
            chunk += cell.rng.normal(0.0, point_noise_mm, chunk.shape)
        n += k
    chunk = None  # no view of ``out`` outlives its cut
    out.resize((n, 2), refcheck=False)
    return out, np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


def _measure(cell: SimulatedCell, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Noisy profiles at true flange poses (R (m, 3, 3), t (m, 3)): points (N, 2) and
    starts (m + 1,), with the cell's noise model and generator (point noise on every
    point; stray points on a share of the profiles that see something, as
    :meth:`SimulatedCell.measure_profile` adds them)."""
    n = cell.noise
    pts, start = _cast_fan(cell, R, t, n.point_noise_mm)
    if n.strays_per_profile and n.stray_profile_fraction > 0:
        counts = np.diff(start)
        stray = (cell.rng.random(len(counts)) < n.stray_profile_fraction) & (counts > 0)
        if stray.any():
            profiles = [pts[start[j]:start[j + 1]] for j in range(len(counts))]
            for j in np.flatnonzero(stray):
                profiles[j] = np.vstack([profiles[j], cell._strays(profiles[j])])
            counts = np.array([len(p) for p in profiles])
            pts = np.concatenate(profiles)
            start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return pts, start


def simulate_recording(cell: SimulatedCell, plan: OnTheFlyPlan | None = None, settings: StreamSimSettings | None = None,
                       stations: SweepPlan | None = None) -> Recording:
    """An on-the-fly recording of ``cell``: sweeps ``plan`` (default
    :class:`~spherecal.config.OnTheFlyPlan`; :meth:`OnTheFlyPlan.quick` for a short one) at
    the stations of ``stations`` (a stop-and-go plan, default
    :class:`~spherecal.config.SweepPlan`), streamed as ``settings`` say (default
    :class:`~spherecal.config.StreamSimSettings`). The truth goes into ``provenance``
    (module docstring)."""
    return simulate_recording_with_truth(cell, plan, settings, stations)[0]


def simulate_recording_with_truth(cell: SimulatedCell, plan: OnTheFlyPlan | None = None,
                                  settings: StreamSimSettings | None = None,
                                  stations: SweepPlan | None = None) -> tuple[Recording, StreamTruth]:
    """:func:`simulate_recording` and what the simulator knows beyond it (:class:`StreamTruth`)."""
    plan = plan or OnTheFlyPlan()
    settings = settings or StreamSimSettings()
    stations = with_standoff(stations or SweepPlan(), cell.fov, cell.sphere_radius_mm)
    segments, sweeps = plan_segments(cell, stations, plan, settings.lead_in_s)
    motion = MotionTimeline.of_segments(segments, cell.arm)
    duration = segments[-1].T1_s
    rng = np.random.default_rng([settings.seed if settings.seed is not None else (cell.seed or 0), 0x57EA])
    ps, ss, clk = settings.pose, settings.sensor, settings.clocks
    rho_r, rho_s = clk.robot_rate_error_ppm * 1e-6, clk.sensor_rate_error_ppm * 1e-6

    # the two clocks' ticks: pose samples on the robot's, exposures on the sensor's
    robot_clock, sample_T, sample_jitter = _grid(rng, ps.period_s, rho_r, duration, ps.stamp_jitter_s)
    sensor_clock, expo_T, expo_jitter = _grid(rng, 1.0 / ss.rate_hz, rho_s, duration, ss.stamp_jitter_s)
    sample_kept = _losses(rng, len(sample_T), ps.drop_rate, ps.burst_rate_per_s, ps.burst_length, duration)
    if sample_kept.sum() < 2:
        raise ValueError(f"simulate_recording: {int(sample_kept.sum())} pose samples left after the losses; "
                         "lower pose.drop_rate or pose.burst_rate_per_s")
    frame_kept = rng.random(len(expo_T)) >= ss.frame_drop_rate
    if not frame_kept.any():
        raise ValueError("simulate_recording: every profile lost; lower sensor.frame_drop_rate")

    # the repeatability noise, one process sampled at every pose sample and exposure
    all_T = np.concatenate([sample_T, expo_T[frame_kept]])
    order = np.argsort(all_T, kind="stable")
    sd = np.array([ps.translation_noise_mm] * 3 + [np.radians(ps.rotation_noise_deg)] * 3)
    noise = np.empty((len(all_T), 6))
    noise[order] = _gauss_markov(rng, all_T[order], sd, ps.noise_correlation_s)
    sample_noise, expo_noise = noise[:len(sample_T)], noise[len(sample_T):]

    # the pose stream: what the controller reports at its kept samples
    Tk = sample_T[sample_kept]
    R_c, t_c, q, sample_sweep = motion.at(Tk)
    if cell.arm is not None:
        M = cell.arm.nominal_flange_matrices(q)
        R_c, t_c = np.ascontiguousarray(M[:, :3, :3]), np.ascontiguousarray(M[:, :3, 3])
    poses = PoseStream(
        t_robot_s=clk.robot_epoch_s + robot_clock[sample_kept] + sample_jitter[sample_kept],
        R=R_c, t_mm=t_c, joints_deg=q if (q is not None and ps.joints) else None,
        seq=ps.first_seq + np.flatnonzero(sample_kept).astype(np.int64), sweep=sample_sweep)

    # the profiles: measured at the true pose at each kept exposure
    Tj = expo_T[frame_kept]
    R_rep, t_rep, qj, profile_sweep = motion.at(Tj)
    if cell.arm is not None:
        M = cell.arm.nominal_flange_matrices(qj)
        R_rep, t_rep = np.ascontiguousarray(M[:, :3, :3]), np.ascontiguousarray(M[:, :3, 3])
        A = cell.arm.true_flange_matrices(qj)
        R_true, t_true = _with_noise(A[:, :3, :3], A[:, :3, 3], expo_noise)
    else:
        R_true, t_true = _with_noise(R_rep, t_rep, expo_noise)
    pts, start = _measure(cell, R_true, t_true)
    latency = ss.latency_s + ss.extra_latency_s
    t_sensor = clk.sensor_epoch_s + sensor_clock[frame_kept] + latency + expo_jitter[frame_kept]
    profiles = ProfileStream(t_sensor_s=t_sensor, points_yz_mm=pts, start=start,
                             frame=ss.first_frame + np.flatnonzero(frame_kept).astype(np.int64), sweep=profile_sweep)

    # the truth of the time relation (module docstring): exact for linear clocks
    k = (1.0 + rho_r) / (1.0 + rho_s)
    s0 = float(t_sensor[0])

    def offset(lat):
        return (clk.robot_epoch_s - s0) + k * ((s0 - clk.sensor_epoch_s) - lat)

    robot_time = clk.robot_epoch_s + (1.0 + rho_r) * Tj
    provenance = {
        "source": "spherecal simulator (on the fly)",
        "true_transform_name": cell.transform_name,
        "true_transform": cell.true_transform.model_dump(),
        "true_sphere_centre_mm": cell.sphere_centre_mm.tolist(),
        "noise": cell.noise.model_dump(),
        "fov": cell.fov.model_dump(),
        "plan": stations.model_dump(),
        "on_the_fly_plan": plan.model_dump(),
        "stream_settings": settings.model_dump(),
        "time_definition": "t_robot = t_sensor + true_offset_s + true_drift * (t_sensor - t_sensor0_s): the robot-clock "
                           "time at which the pose stream holds the pose of the profile stamped t_sensor (its "
                           "exposure's middle), up to the profile's stamp jitter; t_sensor0_s the first profile's stamp",
        "true_offset_s": float(offset(latency)),
        "true_drift": float(k - 1.0),
        "true_drift_ppm": float((k - 1.0) * 1e6),
        "t_sensor0_s": s0,
        "true_offset_without_extra_latency_s": float(offset(ss.latency_s)),
        "duration_s": float(duration),
        "pose_samples": {"taken": int(len(sample_T)), "kept": int(sample_kept.sum())},
        "profiles": {"exposed": int(len(expo_T)), "kept": int(frame_kept.sum()),
                     "seeing_something": int(np.count_nonzero(np.diff(start)))},
    }
    if cell.arm is not None:
        err_t = np.linalg.norm(A[:, :3, 3] - t_rep, axis=1)
        err_r = np.degrees(np.linalg.norm(geo.rotvec_from_matrix(A[:, :3, :3] @ np.swapaxes(R_rep, 1, 2)), axis=1))
        provenance.update({"robot_error": cell.arm.error.model_dump(),
                           "flange_error_mm_range": [float(err_t.min()), float(err_t.max())],
                           "flange_error_deg_range": [float(err_r.min()), float(err_r.max())]})
    recording = Recording(mounting=cell.mounting, sphere_radius_mm=cell.sphere_radius_mm, poses=poses,
                          profiles=profiles, sweeps=sweeps, provenance=provenance, clocks=dict(CLOCK_NAMES))
    truth = StreamTruth(profile_T_s=Tj, profile_robot_time_s=robot_time, profile_R=R_true, profile_t_mm=t_true,
                        profile_reported_R=R_rep, profile_reported_t_mm=t_rep, sample_T_s=sample_T,
                        sample_kept=sample_kept, sample_noise=sample_noise, segments=segments)
    return recording, truth
