"""The calibration problem in arrays, built from a validated :class:`Dataset`.

Both mounting modes are one problem (docs/conventions.md): with ``A_i`` the transform
from base to the sphere frame at shot i -- ``base_from_flange_i`` in eye-in-hand,
``flange_from_base_i`` in eye-to-hand -- and ``X`` the unknown (``flange_from_sensor``
or ``base_from_sensor``), every profile point p = (0, y, z) satisfies
``|A_i X p - c| = r``, c being the sphere centre in the sphere frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .. import geometry as geo
from ..errors import DegenerateDataError, InputError
from ..models import Dataset, Pose


@dataclass
class Problem:
    """Arrays of a dataset, one row per usable profile (see module docstring)."""

    mounting: str
    radius_mm: float
    R0: np.ndarray  # (n, 3, 3) base_from_flange rotations
    t0: np.ndarray  # (n, 3) base_from_flange translations, mm
    R_A: np.ndarray  # (n, 3, 3) sphere_frame_from_base... see A_i above
    t_A: np.ndarray  # (n, 3)
    profiles: list[np.ndarray]  # (N_i, 2) points (y, z), mm
    obs_index: np.ndarray  # (n,) observation index of each profile
    station_of: np.ndarray  # (n,) station number of each profile
    station_labels: list[str]

    @property
    def n_profiles(self) -> int:
        return len(self.profiles)

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
            self.R_A[keep],
            self.t_A[keep],
            [p for p, k in zip(self.profiles, keep) if k],
            self.obs_index[keep],
            np.array([remap[s] for s in self.station_of[keep]], dtype=int),
            [self.station_labels[i] for i in labels_used],
        )

    def with_profiles(self, profiles: list[np.ndarray]) -> "Problem":
        """The same problem with other point sets (e.g. stray points removed)."""
        return Problem(
            self.mounting, self.radius_mm, self.R0, self.t0, self.R_A, self.t_A, profiles,
            self.obs_index, self.station_of, self.station_labels,
        )


def sphere_frame_from_base(mounting: str, R0: np.ndarray, t0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``A_i`` of the module docstring from ``base_from_flange`` stacks."""
    if mounting == "eye_in_hand":
        return R0, t0
    return geo.invert_rt(R0, t0)


def build_problem(
    dataset: Dataset,
    flange_pose_from_joints: Callable[[np.ndarray], Pose] | None = None,
    station_rotation_tolerance_deg: float = 0.05,
) -> Problem:
    """Arrays from a dataset, with the checks that need the whole dataset.

    Raises :class:`InputError` for lengths that look like metres, a station whose
    observations do not share one orientation, or an observation without a usable pose;
    :class:`DegenerateDataError` for an empty dataset."""
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
                    "and no forward kinematics was given: calibrate with the robot plugin's model"
                )
            pose = flange_pose_from_joints(np.asarray(o.joints_deg, dtype=float))
        R0.append(pose.rotation_matrix)
        t0.append(pose.translation)
    R0 = np.array(R0)
    t0 = np.array(t0)
    profiles = [o.profile.points_mm for o in obs]
    _check_units(dataset, t0, profiles)

    labels: list[str] = []
    station_of = np.empty(len(obs), dtype=int)
    first_of: dict[str, int] = {}
    for i, o in enumerate(obs):
        if o.station not in first_of:
            first_of[o.station] = i
            labels.append(o.station)
        station_of[i] = labels.index(o.station)
        j = first_of[o.station]
        angle = geo.rotation_angle_deg(R0[j], R0[i])
        if angle > station_rotation_tolerance_deg:
            raise InputError(
                f"station {o.station!r} mixes orientations: observation {o.index} is rotated "
                f"{angle:.3f} deg from observation {obs[j].index} (tolerance "
                f"{station_rotation_tolerance_deg} deg); within a station the robot may only "
                "translate: give each orientation its own station label"
            )
    R_A, t_A = sphere_frame_from_base(dataset.mounting, R0, t0)
    return Problem(
        dataset.mounting, dataset.sphere_radius_mm, R0, t0, R_A, t_A, profiles,
        np.array([o.index for o in obs]), station_of, labels,
    )


def _check_units(dataset: Dataset, t0: np.ndarray, profiles: list[np.ndarray]) -> None:
    r = dataset.sphere_radius_mm
    extent = max(float(np.abs(p).max()) for p in profiles)
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
