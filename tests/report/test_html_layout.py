"""The report's figures are laid out with fixed margins (no layout engine: one takes a
sixth of the report's time on 1 M points): every label, title, legend and annotation
must still lie inside its figure, whatever the data put on the axes: tiny and large
residuals, flagged observations, bands beyond MAX_BOXES, centre observations, both
mountings."""

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.text import Text

from spherecal.estimation import solve
from spherecal.estimation.centres import circles_from_profiles
from spherecal.core.models import Pose
from spherecal.report import html as rh
from spherecal.report.html import figures as rf
from spherecal.sim import NoiseModel, SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

PLAN = SweepPlan(profiles_per_station=6)


def _figures(solution, tmp_path, monkeypatch) -> dict:
    """Every figure of the report on ``solution``, drawn as the report draws it."""
    drawn = {}
    png = rf._png

    def keep(fig):
        drawn[fig.axes[0].get_title() or fig.get_suptitle()] = fig
        return png(fig)

    monkeypatch.setattr(rf, "_png", keep)
    rh.write_report(solution, tmp_path)
    return drawn


def _outside(fig, monkeypatch) -> list[str]:
    """The texts drawn on ``fig`` that reach beyond its edges (more than a pixel)."""
    drawn = []
    draw = Text.draw

    def record(text, renderer):
        drawn.append(text)
        return draw(text, renderer)

    with monkeypatch.context() as m:
        m.setattr(Text, "draw", record)
        renderer = FigureCanvasAgg(fig).get_renderer()
        fig.draw(renderer)  # as the PNG has it: only the ticks in view are drawn
    width, height = fig.bbox.width, fig.bbox.height
    out = []
    for text in drawn:
        if not text.get_visible() or not text.get_text().strip():
            continue
        box = text.get_window_extent(renderer)
        if box.x0 < -1 or box.y0 < -1 or box.x1 > width + 1 or box.y1 > height + 1:
            out.append(f"{text.get_text()!r} at x {box.x0:.0f}..{box.x1:.0f} of {width:.0f}, "
                       f"y {box.y0:.0f}..{box.y1:.0f} of {height:.0f}")
    assert len(drawn) > 10  # (the texts were seen)
    return out


def _check(solution, tmp_path, monkeypatch, expected: int):
    figures = _figures(solution, tmp_path, monkeypatch)
    assert len(figures) == expected, list(figures)
    bad = {title[:40]: where for title, fig in figures.items() if (where := _outside(fig, monkeypatch))}
    assert not bad, bad


def _dataset(mounting, seed, noise=None):
    return simulate_dataset(standard_cell(mounting, seed=seed, noise=noise or NoiseModel(), fov=reference_fov()),
                            PLAN)


@pytest.mark.slow
@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_nothing_is_cut_off_on_ordinary_data(mounting, tmp_path, monkeypatch):
    _check(solve(_dataset(mounting, 5)), tmp_path, monkeypatch, expected=6)


@pytest.mark.slow
def test_nothing_is_cut_off_with_micrometre_residuals(tmp_path, monkeypatch):
    """Residuals of a few micrometres: the longest tick labels (-0.0025 and the like)."""
    noise = NoiseModel(point_noise_mm=0.001, pose_translation_noise_mm=0.0005)
    _check(solve(_dataset("eye_in_hand", 6, noise)), tmp_path, monkeypatch, expected=6)


@pytest.mark.slow
def test_nothing_is_cut_off_with_millimetre_residuals_and_flags(tmp_path, monkeypatch):
    """Large residuals, stray points and a pose read 3 mm off (flagged, annotated)."""
    ds = _dataset("eye_in_hand", 3, NoiseModel(point_noise_mm=0.3, stray_profile_fraction=0.3, strays_per_profile=8))
    obs = list(ds.observations)
    o = obs[8]
    obs[8] = o.model_copy(update={"base_from_flange": Pose.from_rt(o.base_from_flange.rotation_matrix,
                                                                   o.base_from_flange.translation + [0, 3.0, 0])})
    solution = solve(ds.model_copy(update={"observations": obs}))
    assert solution.result.flagged  # the annotation is drawn
    _check(solution, tmp_path, monkeypatch, expected=6)


@pytest.mark.slow
def test_nothing_is_cut_off_with_bands_and_rotated_indices(tmp_path, monkeypatch):
    """Beyond MAX_BOXES (bands) and beyond 40 profiles (observation numbers turned on
    their side)."""
    monkeypatch.setattr(rf, "MAX_BOXES", 5)
    solution = solve(simulate_dataset(standard_cell("eye_in_hand", seed=7, fov=reference_fov()),
                                      SweepPlan(profiles_per_station=12)))
    assert solution.problem.n_profiles > 40
    _check(solution, tmp_path, monkeypatch, expected=6)


@pytest.mark.slow
def test_nothing_is_cut_off_with_centre_observations(tmp_path, monkeypatch):
    """Profiles and circles mixed: the per-centre figure as well."""
    profiles = _dataset("eye_to_hand", 2)
    circles = {o.index: o for o in circles_from_profiles(profiles).observations}
    mixed = [circles.get(o.index) if o.station in ("S2", "S4") else o for o in profiles.observations]
    solution = solve(profiles.model_copy(update={"observations": [o for o in mixed if o is not None]}))
    _check(solution, tmp_path, monkeypatch, expected=7)


@pytest.mark.slow
def test_nothing_is_cut_off_with_long_station_names_and_a_flagged_last_observation(tmp_path, monkeypatch):
    """Station names of 40 characters (a dataset may carry them; the figures shorten
    them, the tables do not) and six-digit observation numbers with the last one
    flagged (its label ends at it instead of running off the figure)."""
    ds = _dataset("eye_in_hand", 3)
    obs = [o.model_copy(update={"station": f"{o.station}-tilted-30-deg-about-x-then-y-rev-b",
                                "index": 100_000 + o.index}) for o in ds.observations]
    last = max(range(len(obs)), key=lambda i: (obs[i].station, obs[i].index))
    o = obs[last]
    obs[last] = o.model_copy(update={"base_from_flange": Pose.from_rt(o.base_from_flange.rotation_matrix,
                                                                      o.base_from_flange.translation + [0, 3.0, 0])})
    solution = solve(ds.model_copy(update={"observations": obs}))
    assert [f.index for f in solution.result.flagged] == [obs[last].index]
    assert len(solution.problem.station_labels[0]) > rf.MAX_LABEL_CHARS
    _check(solution, tmp_path, monkeypatch, expected=6)
    html = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert solution.problem.station_labels[0] in html  # whole in the report's tables


@pytest.mark.slow
def test_nothing_is_cut_off_with_two_profiles_among_circles(tmp_path, monkeypatch):
    """Two profiles, the rest circles: the per-profile figure at its narrowest keeps its
    title inside."""
    profiles = _dataset("eye_to_hand", 2)
    circles = {o.index: o for o in circles_from_profiles(profiles).observations}
    keep = {profiles.observations[0].index, profiles.observations[1].index}
    mixed = [o if o.index in keep else circles.get(o.index) for o in profiles.observations]
    solution = solve(profiles.model_copy(update={"observations": [o for o in mixed if o is not None]}))
    assert solution.result.residuals.n_profiles_used == 2
    _check(solution, tmp_path, monkeypatch, expected=7)
