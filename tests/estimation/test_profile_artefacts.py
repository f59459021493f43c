"""The sensor's artefacts named where they are the cause: simulated profiles clipped at
the edge of the field of view (values held at the limit, or the arc cut by it) or
quantised on a coarse grid are recognised against the simulator's truth, clean profiles
are not, and a solve names the clipping in place of "a pose read at the wrong moment or a
mis-paired shot", in the flag and in the advice."""

from __future__ import annotations

import re

import numpy as np
import pytest

from spherecal.core.models import Profile
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.profile_artefacts import grid_step_mm, profile_artefact
from spherecal.report.assess import advice
from spherecal.sim import NoiseModel, SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

FOV = reference_fov()


@pytest.fixture(scope="module")
def dataset():
    cell = standard_cell("eye_in_hand", seed=3, fov=FOV, noise=NoiseModel(point_noise_mm=0.001))
    return simulate_dataset(cell, SweepPlan())


def _points(ds, i) -> np.ndarray:
    return np.asarray(ds.observations[i].profile.points_mm, dtype=float)


def _with_profiles(ds, change, fov=None):
    obs = []
    for o in ds.observations:
        p = change(np.asarray(o.profile.points_mm, dtype=float))
        obs.append(o.model_copy(update={"profile": Profile.from_points(p if len(p) else o.profile.points_mm[:1])}))
    provenance = ds.provenance if fov is None else {**ds.provenance, "fov": fov.model_dump()}
    return ds.model_copy(update={"observations": obs, "provenance": provenance})


def test_profiles_are_named_clipped_where_the_line_truly_cut_them(dataset):
    """Against the same cell with a line wide enough to see every arc whole: the profiles
    named as cut at the line's edge are those the wider line sees more of; no other
    profile, nor any of the wider line's, is named."""
    wide_fov = FOV.model_copy(update={"width_near_mm": 90.0, "width_far_mm": 120.0})
    wide = simulate_dataset(standard_cell("eye_in_hand", seed=3, fov=wide_fov,
                                          noise=NoiseModel(point_noise_mm=0.001)), SweepPlan())
    named = {i for i in range(len(dataset.observations)) if profile_artefact(_points(dataset, i), FOV)}
    assert named and all("the edge of the laser line" in profile_artefact(_points(dataset, i), FOV) for i in named)
    spans = [(np.ptp(_points(dataset, i)[:, 0]), np.ptp(_points(wide, i)[:, 0])) for i in range(len(wide.observations))]
    assert all(w > n + 5.0 for i, (n, w) in enumerate(spans) if i in named)
    assert all(profile_artefact(_points(wide, i), wide_fov) is None for i in range(len(wide.observations)))


def test_values_held_at_a_limit_are_named_with_the_limit_and_the_count(dataset):
    p = _points(dataset, 0)
    limit = float(p[:, 1].min() + 0.3 * np.ptp(p[:, 1]))
    held = p.copy()
    held[:, 1] = np.maximum(held[:, 1], limit)  # a sensor that reports the far limit for what lies beyond
    beyond = int((p[:, 1] < limit).sum())
    said = profile_artefact(held)
    assert said.startswith("the profile is clipped at the edge of the sensor's field of view: "
                           f"{beyond} of {len(p)} points pile at z = {limit:.3f} mm")
    wide = p.copy()
    wide[:, 0] = np.clip(wide[:, 0], -5.0, 5.0)  # held at the line's edge
    assert re.search(r"points pile at y = -?5\.000 mm", profile_artefact(wide))


def test_an_arc_cut_by_the_declared_field_of_view_is_named(dataset):
    p = _points(dataset, 0)
    z_far = float(p[:, 1].max() - 1.5)  # the range ends 1.5 mm below the sphere's top: most of the arc is lost
    fov = FOV.model_copy(update={"z_far_mm": z_far, "standoff_z_mm": None})
    kept = p[p[:, 1] >= z_far]
    assert f"its arc ends at z = " in profile_artefact(kept, fov) and f"(z_far_mm = {z_far:g})" in \
        profile_artefact(kept, fov)
    assert profile_artefact(kept) is None  # without the field of view, a short arc is only a short arc
    assert profile_artefact(p, fov.model_copy(update={"z_far_mm": FOV.z_far_mm})) is None


@pytest.mark.parametrize("step", [0.05, 0.02, 0.1])
def test_coarse_quantisation_is_named_with_its_step(dataset, step):
    p = _points(dataset, 5)
    q = p.copy()
    q[:, 1] = np.round(q[:, 1] / step) * step
    assert grid_step_mm(q[:, 1]) == pytest.approx(step, rel=1e-3)
    assert f"coarsely quantised: its z values lie on a {step:.4g} mm grid" in profile_artefact(q)
    assert grid_step_mm(p[:, 1]) is None
    # float32 storage is no grid
    assert grid_step_mm(p[:, 1].astype(np.float32).astype(float)) is None


def test_a_solve_names_the_clipping_instead_of_a_pose_read_at_the_wrong_moment(dataset):
    """The far end of the range 35 mm below the sensor: one profile keeps a sliver of its
    arc, whose centre lies 1.7 mm off; it was put down to the robot."""
    fov = FOV.model_copy(update={"z_far_mm": -35.0, "standoff_z_mm": None})
    cut = _with_profiles(dataset, lambda p: p[p[:, 1] >= -35.0], fov)
    result = solve(cut, CalibrationOptions()).result
    flag = next(f for f in result.flagged if f.reason.startswith("inconsistent"))
    assert re.search(r"the profile is clipped at the edge of the sensor's field of view: its arc ends at z = "
                     r"-3[45]\.\d{3} mm, the far end of the sensor's measuring range \(z_far_mm = -35\)", flag.reason)
    assert "(more likely than a pose read at the wrong moment or a mis-paired shot)" in flag.reason
    text = next(a.text for a in advice(result) if a.key == "flagged")
    assert f"Observation(s) {flag.index} (station {flag.station}): likely profiles clipped at the edge" in text


def test_a_solve_that_fails_on_held_values_says_so(dataset):
    from spherecal.core.errors import DegenerateDataError

    held = _with_profiles(dataset, lambda p: np.column_stack([p[:, 0], np.maximum(p[:, 1], -35.0)]))
    with pytest.raises(DegenerateDataError, match=r"profiles show the sensor's doing, not the robot's \(observation "
                                                  r"\d+: the profile is clipped .* pile at z = -35.000 mm"):
        solve(held, CalibrationOptions())
