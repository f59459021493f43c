"""The calibration problem in arrays, built from a validated :class:`Dataset`.

Both mounting modes are one problem (docs/conventions.md). The mount frame is the frame
the sensor is fixed in (``flange`` in eye-in-hand, ``base`` in eye-to-hand), the sphere
frame the one the sphere is fixed in (``base`` in eye-in-hand, ``flange`` in
eye-to-hand). With ``A_i = sphere_from_mount_i`` the robot's pose at shot i in those
terms -- ``base_from_flange_i`` in eye-in-hand, ``flange_from_base_i`` in eye-to-hand --
and ``X = mount_from_sensor`` the unknown (``flange_from_sensor`` or
``base_from_sensor``), every profile point p = (0, y, z) satisfies
``|A_i X p - c| = r``, c being the sphere centre in the sphere frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError, InputError, SpherecalError
from spherecal.core.models import Dataset, ObservationFlag, Pose
from spherecal.estimation.robust import median


#: Kinds of shot in :attr:`Problem.kind`.
KIND_PROFILE, KIND_CIRCLE, KIND_SPHERE_CENTRE = 0, 1, 2
KIND_NAMES = {KIND_PROFILE: "profile", KIND_CIRCLE: "circle", KIND_SPHERE_CENTRE: "sphere centre"}


@dataclass
class Problem:
    """Arrays of a dataset, one row per usable profile (see module docstring)."""

    mounting: str
    radius_mm: float
    R0: np.ndarray  # (n, 3, 3) base_from_flange rotations
    t0: np.ndarray  # (n, 3) base_from_flange translations, mm
    R_sphere_from_mount: np.ndarray  # (n, 3, 3) rotations of A_i (module docstring)
    t_sphere_from_mount: np.ndarray  # (n, 3) translations of A_i, mm
    profiles: list[np.ndarray]  # (N_i, 2) points (y, z), mm
    obs_index: np.ndarray  # (n,) observation index of each profile
    station_of: np.ndarray  # (n,) station number of each profile
    station_labels: list[str]
    q_rad: np.ndarray | None = None  # (n, joints) model joint angles of each shot, when known
    # centre observations (docs/estimation.md, "Centre observations"); None: every shot is a profile
    kind: np.ndarray | None = None  # (n,) KIND_PROFILE, KIND_CIRCLE or KIND_SPHERE_CENTRE
    centre_meas: np.ndarray | None = None  # (n, 3) circle (y, z, radius) or sphere centre (x, y, z), mm; NaN for profiles
    centre_cov: np.ndarray | None = None  # (n, 3, 3) its given covariance, mm^2; NaN where not given (estimated)
    # a recording (:mod:`spherecal.core.streams`): each shot's sensor-clock stamp, s; the
    # poses above are the pose stream's at the clock relation of the moment
    t_sensor_s: np.ndarray | None = None

    @property
    def n_profiles(self) -> int:
        """Shots (rows) of the problem, whatever their kind (profiles and centres alike)."""
        return len(self.profiles)

    @property
    def kinds(self) -> np.ndarray:
        """(n,) kind of each shot (all KIND_PROFILE without centre observations)."""
        return self.kind if self.kind is not None else np.zeros(len(self.profiles), dtype=int)

    @property
    def has_centres(self) -> bool:
        return self.kind is not None and bool(np.any(self.kind != KIND_PROFILE))

    def _take(self, keep: np.ndarray, name: str):
        v = getattr(self, name)
        return None if v is None else v[keep]

    def subset(self, keep: np.ndarray) -> "Problem":
        """The same problem restricted to the profiles where ``keep`` is True."""
        keep = np.asarray(keep, dtype=bool)
        labels_used = sorted(set(self.station_of[keep].tolist()))
        remap = {old: new for new, old in enumerate(labels_used)}
        return Problem(
            self.mounting,
            self.radius_mm,
            self.R0[keep],
            self.t0[keep],
            self.R_sphere_from_mount[keep],
            self.t_sphere_from_mount[keep],
            [p for p, k in zip(self.profiles, keep) if k],
            self.obs_index[keep],
            np.array([remap[s] for s in self.station_of[keep]], dtype=int),
            [self.station_labels[i] for i in labels_used],
            None if self.q_rad is None else self.q_rad[keep],
            self._take(keep, "kind"), self._take(keep, "centre_meas"), self._take(keep, "centre_cov"),
            self._take(keep, "t_sensor_s"),
        )

    def with_profiles(self, profiles: list[np.ndarray]) -> "Problem":
        """The same problem with other point sets (e.g. stray points removed)."""
        return replace(self, profiles=profiles)


def sphere_from_mount(mounting: str, R0: np.ndarray, t0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``A_i = sphere_from_mount_i`` (module docstring), rotations (n, 3, 3) and
    translations (n, 3, mm), from the ``base_from_flange`` stacks ``R0``, ``t0``: those
    themselves in eye-in-hand (sphere in ``base``, sensor on the ``flange``), their
    inverse ``flange_from_base`` in eye-to-hand (sphere on the ``flange``, sensor in
    ``base``)."""
    if mounting == "eye_in_hand":
        return R0, t0
    return geo.invert_rt(R0, t0)


def build_problem(
    dataset: Dataset,
    flange_pose_from_joints: Callable[[np.ndarray], Pose] | None = None,
    model_joints_rad: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Problem:
    """Arrays from a dataset, with the checks that need the whole dataset.

    With ``model_joints_rad`` (the robot's conversion of controller joints, deg, to its
    chain's model angles, rad) and joint readings on every observation, the problem
    carries each shot's joints (:attr:`Problem.q_rad`) for the kinematic robot error
    model.

    Raises :class:`InputError` for lengths that look like metres or an observation
    without a usable pose; :class:`DegenerateDataError` for an empty dataset. Whether
    each station keeps one orientation is checked by :func:`screen_station_orientations`."""
    obs = dataset.observations
    if not obs:
        raise DegenerateDataError("the dataset has no observations: acquire some profiles first")
    R0, t0 = [], []
    for o in obs:
        pose = o.base_from_flange
        if pose is None:
            if flange_pose_from_joints is None:
                raise InputError(
                    f"observation {o.index} (station {o.station}) has joint readings but no flange pose, "
                    "and no forward kinematics was given: calibrate with the robot plugin's model "
                    "(spherecal solve --robot TYPE; `spherecal plugins` lists the robot types)"
                )
            try:
                pose = flange_pose_from_joints(np.asarray(o.joints_deg, dtype=float))
            except SpherecalError as exc:
                raise InputError(f"observation {o.index} (station {o.station}): joints_deg: {exc}") from None
        R0.append(pose.quaternion_wxyz)
        t0.append(pose.translation)
    R0 = geo.matrix_from_quat_wxyz(np.array(R0, dtype=float).reshape(-1, 4))  # (all at once: one call, not n)
    t0 = np.array(t0)
    profiles = [o.profile.points_mm if o.profile is not None else np.zeros((0, 2)) for o in obs]
    _check_units(dataset, t0, profiles)
    kind = centre_meas = centre_cov = None
    if any(o.profile is None for o in obs):
        kind, centre_meas, centre_cov = centre_arrays(obs)

    labels: list[str] = []
    station_of = np.empty(len(obs), dtype=int)
    for i, o in enumerate(obs):
        if o.station not in labels:
            labels.append(o.station)
        station_of[i] = labels.index(o.station)
    R_sm, t_sm = sphere_from_mount(dataset.mounting, R0, t0)
    q_rad = None
    if model_joints_rad is not None and all(o.joints_deg is not None for o in obs):
        q_rad = np.array([model_joints_rad(np.asarray(o.joints_deg, dtype=float)) for o in obs])
    return Problem(
        dataset.mounting, dataset.sphere_radius_mm, R0, t0, R_sm, t_sm, profiles,
        np.array([o.index for o in obs]), station_of, labels, q_rad, kind, centre_meas, centre_cov,
    )


def centre_arrays(observations) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kind (n,), measurement (n, 3) and given covariance (n, 3, 3) of each observation
    (see :class:`Problem`): a circle's standard deviations become a diagonal covariance
    of (y, z, radius); NaN where nothing is given (the fit estimates it: a circle may give
    one of its two standard deviations, see :func:`fill_unknown`)."""
    n = len(observations)
    kind = np.zeros(n, dtype=int)
    meas = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    for i, o in enumerate(observations):
        if o.circle is not None:
            kind[i] = KIND_CIRCLE
            meas[i] = [*o.circle.centre_yz_mm, o.circle.radius_mm]
            sd = [o.circle.centre_std_mm] * 2 + [o.circle.radius_std_mm]
            if any(v is not None for v in sd):
                cov[i] = np.diag([np.nan if v is None else v * v for v in sd])
        elif o.sphere_centre_mm is not None:
            kind[i] = KIND_SPHERE_CENTRE
            meas[i] = o.sphere_centre_mm
            if o.sphere_centre_covariance_mm2 is not None:
                cov[i] = np.array(o.sphere_centre_covariance_mm2, dtype=float)
    return kind, meas, cov


def unknown_variances(cov: np.ndarray) -> np.ndarray:
    """Which diagonal entries of given centre covariances (..., 3, 3) are not given (NaN)."""
    return np.isnan(np.diagonal(cov, axis1=-2, axis2=-1))


def fill_unknown(cov: np.ndarray, variance) -> np.ndarray:
    """Given centre covariances (..., 3, 3) with the variances not given (NaN diagonal
    entries) set to ``variance`` (mm^2, scalar or per matrix) and NaN off-diagonal terms
    (those of a component not given) to 0."""
    cov = np.asarray(cov, dtype=float)
    out = np.where(np.isnan(cov), 0.0, cov)
    diag = unknown_variances(cov)
    v = np.broadcast_to(np.asarray(variance, dtype=float)[..., None], diag.shape)
    idx = np.arange(3)
    out[..., idx, idx] = np.where(diag, v, out[..., idx, idx])
    return out


# --- one orientation per station ------------------------------------------------------------
#: Floor of the derived station rotation tolerance, deg.
STATION_ROTATION_FLOOR_DEG = 0.02
#: The derived tolerance is this many times the typical angle (s sqrt(3)) of one shot's
#: orientation reading from the station's mean, s being the per-axis read noise.
STATION_ROTATION_K = 4.0
#: The scatter the stations show may raise the derived tolerance up to this, deg: beyond
#: it the pure-translation start degrades (0.1 deg is 0.35 mm at 200 mm), so a robot whose
#: readings scatter more must be told so (pose_rotation_noise_deg or the tolerance).
STATION_ROTATION_SEEN_CAP_DEG = 0.1
#: The scatter the stations show is taken over pairs of shots within this angle of their
#: group's mean orientation (deg): ten times the cap, so that shots that turned a few
#: tenths of a degree still count, and stations labelled with orientations degrees apart
#: do not pass for read noise.
NOISE_PAIRS_WITHIN_DEG = 10 * STATION_ROTATION_SEEN_CAP_DEG
#: Median of the chi distribution with 3 degrees of freedom (sqrt of chi^2_3's median).
_CHI3_MEDIAN = 1.5382


def derived_station_rotation_tolerance_deg(rotation_noise_deg: float) -> float:
    """``max(floor, k s sqrt(3))``: with per-axis orientation read noise s (deg), the
    angle between one shot and its station's mean is about s sqrt(3) (chi with 3 degrees
    of freedom); k = 4 leaves a shot of pure jitter beyond the tolerance with a
    probability far below 1e-6."""
    return max(STATION_ROTATION_FLOOR_DEG, STATION_ROTATION_K * float(rotation_noise_deg) * np.sqrt(3.0))


@dataclass
class OrientationScreening:
    """What :func:`screen_station_orientations` did: the problem without the turned
    shots (split stations relabelled), their flags, and a summary for the result."""

    problem: Problem
    flags: list[ObservationFlag]
    diagnostics: dict
    notes: list[str]


def chordal_mean(Rs: np.ndarray) -> np.ndarray:
    """The rotation closest (Frobenius) to the mean of the matrices ``Rs`` (n, 3, 3)."""
    U, _, Vt = np.linalg.svd(np.mean(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def _angles_deg(R: np.ndarray, Rs: np.ndarray) -> np.ndarray:
    """Angle (deg) between R and each of Rs (n, 3, 3)."""
    c = (np.einsum("ij,nij->n", R, Rs) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _pairwise_angles_deg(Rs: np.ndarray) -> np.ndarray:
    """Angle (deg) between every two of Rs (n, 3, 3): (n, n), one matrix product."""
    flat = Rs.reshape(len(Rs), 9)
    c = (flat @ flat.T - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _clusters(Rs: np.ndarray, tolerance_deg: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Groups of shots whose orientations lie within ``tolerance_deg`` of their group's
    chordal mean, largest first: ``[(positions, mean rotation), ...]``."""
    n = len(Rs)
    if n:
        mean = chordal_mean(Rs)
        if np.all(_angles_deg(mean, Rs) <= tolerance_deg / 2):
            # every two within the tolerance of each other (the angle is a metric): one
            # group, as the search below would find, without its n x n table (thousands of
            # profiles of a recording's station)
            return [(np.arange(n), mean)]
    D = _pairwise_angles_deg(Rs)
    remaining = np.ones(n, dtype=bool)
    groups = []
    while remaining.any():
        rem = np.flatnonzero(remaining)
        sub = D[np.ix_(rem, rem)]
        counts = (sub <= tolerance_deg).sum(axis=1)
        best = counts == counts.max()
        seed = rem[np.flatnonzero(best)[np.argmin(median(sub[best], axis=1))]]
        members = rem[D[seed, rem] <= tolerance_deg]
        mean = Rs[seed]
        for _ in range(5):
            mean = chordal_mean(Rs[members])
            new = rem[_angles_deg(mean, Rs[rem]) <= tolerance_deg]
            if len(new) == 0 or np.array_equal(new, members):
                break
            members = new
        groups.append((members, mean))
        remaining[members] = False
    groups.sort(key=lambda g: -len(g[0]))
    return groups


def orientation_groups(Rs: np.ndarray, tolerance_deg: float) -> list[np.ndarray]:
    """Positions of ``Rs`` (n, 3, 3) grouped by orientation: each group within
    ``tolerance_deg`` of its chordal mean, largest first."""
    return [members for members, _ in _clusters(Rs, tolerance_deg)]


def screen_station_orientations(
    problem: Problem,
    tolerance_deg: float | None = None,
    rotation_noise_deg: float = 0.0,
    estimate_noise: bool = True,
    min_profiles_per_station: int = 4,
) -> OrientationScreening:
    """Within a station the robot may only translate. Each shot's orientation is
    compared with its station's robust mean orientation (the chordal mean of the largest
    group of shots within the tolerance of each other). Shots beyond the tolerance are
    left out and flagged with their angle, unless they form a group of their own with at
    least ``min_profiles_per_station`` shots: that group becomes a station of its own,
    labelled ``<station>/b`` (``/c``, ...). Nothing is refused here.

    ``tolerance_deg`` None derives it (:func:`derived_station_rotation_tolerance_deg`)
    from the per-axis orientation read noise ``rotation_noise_deg``; with
    ``estimate_noise`` the scatter the stations show (median pairwise angle within
    stations, which a minority of turned shots hardly moves) may raise it, up to
    :data:`STATION_ROTATION_SEEN_CAP_DEG`."""
    R0 = problem.R0
    pair_angles = []
    for k in range(len(problem.station_labels)):
        idx = np.flatnonzero(problem.station_of == k)
        # pairs of one orientation only: shots degrees apart under one label are a
        # labelling error (split or flagged below), not read noise
        for members in orientation_groups(R0[idx], NOISE_PAIRS_WITHIN_DEG) if len(idx) > 1 else ():
            if len(members) > 1:
                D = _pairwise_angles_deg(R0[idx[members]])
                pair_angles.append(D[np.triu_indices(len(members), 1)])
    pairs = np.concatenate(pair_angles) if pair_angles else np.zeros(0)
    noise_seen = float(median(pairs) / (np.sqrt(2.0) * _CHI3_MEDIAN)) if len(pairs) >= 10 else 0.0
    derived = tolerance_deg is None
    if derived:
        tolerance_deg = derived_station_rotation_tolerance_deg(rotation_noise_deg)
        if estimate_noise:
            tolerance_deg = max(tolerance_deg, min(derived_station_rotation_tolerance_deg(noise_seen),
                                                   STATION_ROTATION_SEEN_CAP_DEG))

    keep = np.ones(problem.n_profiles, dtype=bool)
    station_of = problem.station_of.copy()
    labels: list[str] = []
    new_of_old: dict[int, int] = {}
    flags: list[ObservationFlag] = []
    notes: list[str] = []
    split: dict[str, list[str]] = {}
    spread: dict[str, float] = {}
    for k, label in enumerate(problem.station_labels):
        idx = np.flatnonzero(problem.station_of == k)
        groups = _clusters(R0[idx], tolerance_deg)
        main_members, main_mean = groups[0]
        labels.append(label)
        new_of_old[k] = len(labels) - 1
        station_of[idx[main_members]] = len(labels) - 1
        spread[label] = float(_angles_deg(main_mean, R0[idx[main_members]]).max())
        for members, mean in groups[1:]:
            turn = geo.rotation_angle_deg(main_mean, mean)
            if len(members) >= min_profiles_per_station:
                new_label = f"{label}/{chr(ord('a') + len(split.get(label, [label])))}"
                split.setdefault(label, [label]).append(new_label)
                labels.append(new_label)
                station_of[idx[members]] = len(labels) - 1
                spread[new_label] = float(_angles_deg(mean, R0[idx[members]]).max())
                notes.append(
                    f"station {label}: observations {', '.join(str(problem.obs_index[i]) for i in idx[members])} "
                    f"are turned {turn:.3f} deg from the station's other shots (tolerance {tolerance_deg:.3f} deg); "
                    f"solved as a station of their own, {new_label}"
                )
                continue
            angles = _angles_deg(main_mean, R0[idx[members]])
            for i, a in zip(idx[members], angles):
                keep[i] = False
                flags.append(ObservationFlag(
                    index=int(problem.obs_index[i]), station=label,
                    reason=f"turned {a:.3f} deg from the orientation of its station "
                           f"(tolerance {tolerance_deg:.3f} deg): "
                           "within a station the robot may only translate",
                ))
    shaped = replace(problem, station_of=station_of, station_labels=labels)
    scattered = _scattered_stations(problem, keep)
    diagnostics = {
        "tolerance_deg": float(tolerance_deg),
        "tolerance_derived": derived,
        "rotation_noise_seen_deg": noise_seen,
        "max_angle_to_station_mean_deg": spread,
        "split_stations": split,
        "turned_observations": sorted(f.index for f in flags),
        "notes": notes,
        **({"scattered_stations": scattered} if scattered else {}),
    }
    return OrientationScreening(shaped.subset(keep) if not keep.all() else shaped, flags, diagnostics, notes)


#: Orientations farther apart than this (deg) within one station are not a robot that
#: turned a little during its sweep or noisy orientation readings (tenths of a degree)
#: but shots of several stations under one label (stations differ by 10-45 deg).
SEVERAL_STATIONS_DEG = 5.0


def _scattered_stations(problem: Problem, keep: np.ndarray) -> dict[str, dict]:
    """The stations whose shots the orientation screening mostly left out as turned (no
    orientation holds most of them) and whose orientations lie more than
    :data:`SEVERAL_STATIONS_DEG` apart: shots of several stations under one label. For
    each: its shots, how many orientations they are at, and the largest angle between two
    of them (deg)."""
    out = {}
    for k, label in enumerate(problem.station_labels):
        idx = np.flatnonzero(problem.station_of == k)
        if len(idx) < 2 or 2 * np.count_nonzero(keep[idx]) > len(idx):
            continue
        widest = float(_pairwise_angles_deg(problem.R0[idx]).max())
        if widest > SEVERAL_STATIONS_DEG:
            out[label] = {"observations": len(idx), "widest_deg": widest,
                          "orientations": len(orientation_groups(problem.R0[idx], NOISE_PAIRS_WITHIN_DEG))}
    return out


def several_stations_under_one_label(scattered: dict[str, dict]) -> str:
    """What :func:`_scattered_stations` found, as the cause of a refusal: the stations,
    why their observations were left out, and what to do."""
    parts = [f"station {label}: its {v['observations']} observations are at {v['orientations']} different "
             f"orientations (up to {v['widest_deg']:.1f} deg apart), so no orientation holds most of them and the "
             "others were left out as turned" for label, v in scattered.items()]
    return ("; ".join(parts) + ". Within a station the robot may only translate: label each orientation a station "
            "of its own (each with shots at different positions of a pure-translation sweep)")


def spread_per_station(rows: np.ndarray, station_of: np.ndarray, at_most: int) -> np.ndarray:
    """At most ``at_most`` of ``rows`` (positions of a problem's shots) per station,
    evenly spread over each station's (in order), sorted: a start's subsample of the
    thousands of profiles of a recording."""
    out = [np.zeros(0, dtype=int)]
    for k in np.unique(station_of[rows]):
        members = rows[station_of[rows] == k]
        take = np.unique(np.linspace(0, len(members) - 1, min(len(members), at_most)).astype(int))
        out.append(members[take])
    return np.sort(np.concatenate(out))


def _check_units(dataset: Dataset, t0: np.ndarray, profiles: list[np.ndarray]) -> None:
    r = dataset.sphere_radius_mm
    extent = max((float(np.abs(p).max()) for p in profiles if len(p)), default=np.inf)
    if extent < 0.05 * r and extent < 1.0:
        raise InputError(
            f"profile points span at most {extent:.4g} from the sensor origin while the sphere radius is "
            f"{r} mm: the profiles look like metres; give them in millimetres"
        )
    reach = float(np.linalg.norm(t0, axis=1).max())
    if reach < 5.0:
        raise InputError(
            f"flange positions are all within {reach:.4g} of the base origin: the poses look like metres; "
            "give base_from_flange translations in millimetres"
        )
