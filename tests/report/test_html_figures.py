"""The report's residual plots that show 0.03 mm (against position along the line,
against depth, on the sphere) and its offline interactive 3-D view; large datasets are
subsampled in what is drawn, never in what is computed."""

import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from spherecal.estimation import solve
from spherecal.report import html as rh
from spherecal.report.html import data as rd, figures as rf
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov


@pytest.fixture(scope="module")
def solution():
    return solve(simulate_dataset(standard_cell("eye_in_hand", seed=5, fov=reference_fov()),
                                  SweepPlan(profiles_per_station=6)))


@pytest.fixture(scope="module")
def report(solution, tmp_path_factory):
    out = tmp_path_factory.mktemp("plots")
    path = rh.write_report(solution, out)
    return path, path.read_text(encoding="utf-8")


def test_the_residuals_along_the_line_and_on_the_sphere_are_in_the_report_and_saved(report):
    path, text = report
    for key in ("residuals_along_line", "residuals_on_sphere"):
        png = path.parent / f"report_{key}.png"
        assert png.read_bytes().startswith(b"\x89PNG\r\n\x1a\n") and png.stat().st_size > 10_000
        assert f'<figure id="fig-{key}"><img' in text
    assert "position along the laser line" in text and "coloured by its residual" in text  # the captions
    assert text.index("fig-residuals_along_line") < text.index("fig-sphere_3d")


def test_binned_residuals_known_answer():
    x = np.array([0.0, 1.0, 2.0, 3.0, 9.0, 10.0])
    r = np.array([0.01, 0.03, -0.02, 0.02, 0.04, 0.0])
    b = rh.binned_residuals(x, r, bins=2)  # bins [0, 5) and [5, 10]
    assert b["centre_mm"].tolist() == [2.5, 7.5]
    assert b["count"].tolist() == [4, 2]
    assert b["mean_mm"] == pytest.approx([0.01, 0.02])
    assert b["rms_mm"] == pytest.approx([np.sqrt((1e-4 + 9e-4 + 4e-4 + 4e-4) / 4), np.sqrt(16e-4 / 2)])
    empty = rh.binned_residuals(np.array([0.0, 10.0]), np.array([0.01, 0.01]), bins=4)
    assert np.isnan(empty["mean_mm"][1]) and empty["count"].tolist() == [1, 0, 0, 1]


def test_plot_sample_spreads_over_all_points_and_keeps_small_sets_whole():
    assert rh.plot_sample(10, 100).tolist() == list(range(10))
    pick = rh.plot_sample(100_000, 1000)
    assert len(pick) == 1000 and pick[0] == 0 and pick[-1] == 99_999
    assert np.all(np.diff(pick) > 0) and np.ptp(np.diff(pick)) <= 1  # evenly spread, no repeats


def _scatter_count(fig) -> list[int]:
    return [len(c.get_offsets()) for ax in fig.axes for c in ax.collections]


def test_subsampling_draws_fewer_points_but_computes_the_same(solution, monkeypatch):
    y, z, res = rh.profile_points_and_residuals(solution)
    assert len(y) == len(z) == len(res) == sum(len(r) for r in solution.refined.residuals)
    assert np.ptp(y) > 30 and np.ptp(z) > 30  # positions along the line and depths of a real sweep
    full = rf._fig_along_line(solution, solution.result)
    monkeypatch.setattr(rf, "MAX_POINTS_PLOTTED", 500)
    small = rf._fig_along_line(solution, solution.result)
    assert _scatter_count(full) == [len(res), len(res)] and _scatter_count(small) == [500, 500]
    for a, b in zip(full.axes, small.axes):  # the per-bin mean and RMS: every point, both times
        assert len(a.lines) == len(b.lines) >= 3
        for la, lb in zip(a.lines, b.lines):
            np.testing.assert_array_equal(la.get_ydata(), lb.get_ydata())
    assert full._suptitle.get_text() == small._suptitle.get_text()
    assert f"all {len(res)} points in the lines" in small._suptitle.get_text()
    # the lines are the binned statistics of all points
    b = rh.binned_residuals(y, res)
    np.testing.assert_array_equal(full.axes[0].lines[0].get_ydata(), b["mean_mm"])
    sphere = rf._fig_on_sphere(solution, solution.result)
    assert _scatter_count(sphere)[0] == 500  # (the colour bar adds its own artists)


def test_residuals_on_the_sphere_are_at_each_points_direction(solution):
    az, el, res = rh.sphere_directions(solution)
    pts = np.concatenate(rh.mapped_points(solution)) - solution.refined.centre
    d = pts / np.linalg.norm(pts, axis=1)[:, None]
    back = np.column_stack([np.cos(np.radians(el)) * np.cos(np.radians(az)),
                            np.cos(np.radians(el)) * np.sin(np.radians(az)), np.sin(np.radians(el))])
    np.testing.assert_allclose(back, d, atol=1e-12)
    assert len(res) == len(az) and np.all(np.abs(el) <= 90)


def test_the_interactive_view_is_inline_and_offline(report, solution):
    _, text = report
    section = text[text.index('<section class="interactive">'):]
    section = section[:section.index("</section>")]
    data = json.loads(re.search(r'<script type="application/json" id="view3d-data">(.*?)</script>', section,
                                re.S).group(1))
    n = len(data["residuals"])
    assert n == min(rd.MAX_POINTS_INTERACTIVE, data["total"]) and len(data["points"]) == 3 * n
    p = np.reshape(data["points"], (-1, 3))
    assert np.all(np.abs(np.linalg.norm(p, axis=1) - data["radius_mm"]) < 0.5)  # on the fitted sphere
    # nothing is fetched: no URL, no external script or stylesheet anywhere in the report
    assert not re.search(r"https?://", text) and "<script src" not in text and "<link" not in text
    print_css = text[text.index("@media print {"):text.index("</style>")]
    assert ".interactive { display: none; }" in print_css  # print shows the static PNGs instead


def test_the_interactive_colour_limit_comes_from_every_point(solution):
    a = rh.interactive_points(solution, limit=200)
    b = rh.interactive_points(solution, limit=10**7)
    assert len(a["residuals"]) == 200 and len(b["residuals"]) == b["total"] == a["total"]
    assert a["limit_mm"] == b["limit_mm"] and a["radius_mm"] == b["radius_mm"]


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium not installed (apt-get install chromium)")
def test_the_interactive_view_draws_in_a_browser_without_network(report):
    path, text = report
    proc = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom",
                           "--proxy-server=127.0.0.1:9", "--proxy-bypass-list=<-loopback>", path.as_uri()],
                          capture_output=True, text=True, timeout=180)
    canvas = re.search(r'<canvas id="view3d-canvas"[^>]*>', proc.stdout)
    assert canvas, proc.stderr[-2000:]
    n = len(json.loads(re.search(r'id="view3d-data">(.*?)</script>', text, re.S).group(1))["residuals"])
    assert f'data-drawn="{n}"' in canvas.group(0)


def test_the_3d_and_per_profile_figures_draw_a_bounded_number_of_artists(solution, monkeypatch):
    """However many profiles: one scatter per station in each 3-D view, at most
    MAX_POINTS_PLOTTED points in all; the per-profile boxes are three collections, their
    statistics from every point; at most MAX_TICK_LABELS observation indices."""
    prob = solution.problem
    monkeypatch.setattr(rf, "MAX_POINTS_PLOTTED", 300)
    monkeypatch.setattr(rf, "MAX_TICK_LABELS", 7)
    sphere = rf._fig_sphere(solution, solution.result, rf._station_colours(list(prob.station_labels)))
    for ax in sphere.axes:
        counts = [len(c._offsets3d[0]) for c in ax.collections if hasattr(c, "_offsets3d")]
        counts = [n for n in counts if n > 1]  # (the centre's '+' is one point)
        assert len(counts) == len(prob.station_labels) and sum(counts) <= 300
    per_profile = rf._fig_per_profile(solution, solution.result, rf._station_colours(list(prob.station_labels)))
    ax = per_profile.axes[0]
    assert len(ax.collections) == 3  # boxes, whiskers with caps, medians
    boxes = ax.collections[0].get_paths()
    assert len(boxes) == prob.n_profiles
    # box i spans the quartiles of profile i's residuals: all its points
    order = sorted(range(prob.n_profiles), key=lambda i: (prob.station_of[i], prob.obs_index[i]))
    for k, i in enumerate(order):
        ys = boxes[k].vertices[:, 1]
        q1, q3 = np.percentile(solution.refined.residuals[i], [25, 75])
        assert np.isclose(ys.min(), q1) and np.isclose(ys.max(), q3)
    assert len([t for t in ax.get_xticklabels() if t.get_text()]) <= 7


def test_beyond_max_boxes_the_per_profile_figure_draws_bands_of_the_same_statistics(solution, monkeypatch):
    """More profiles than MAX_BOXES: a band per station (1-99 %, quartiles) and a median
    line, not one box each; the bands are drawn from each profile's percentiles of every
    point."""
    prob = solution.problem
    monkeypatch.setattr(rf, "MAX_BOXES", 5)
    drawn = []
    bands = rf._bands
    monkeypatch.setattr(rf, "_bands", lambda ax, x, q, colours: (drawn.append((x, q)), bands(ax, x, q, colours)))
    fig = rf._fig_per_profile(solution, solution.result, rf._station_colours(list(prob.station_labels)))
    ax = fig.axes[0]
    assert len(ax.collections) == 2 * len(prob.station_labels)  # two bands a station, no box a profile
    assert len(ax.lines) >= len(prob.station_labels)  # the medians (and the zero line)
    assert "dark band: quartiles" in ax.get_title()
    (x, q), = drawn
    order = sorted(range(prob.n_profiles), key=lambda i: (prob.station_of[i], prob.obs_index[i]))
    np.testing.assert_array_equal(x, np.arange(prob.n_profiles))
    for k, i in enumerate(order):
        np.testing.assert_allclose(q[k], np.percentile(solution.refined.residuals[i], [1, 25, 50, 75, 99]))
    ys = np.concatenate([c.get_paths()[0].vertices[:, 1] for c in ax.collections])
    assert ys.min() == pytest.approx(q[:, 0].min()) and ys.max() == pytest.approx(q[:, 4].max())


def test_row_percentiles_are_numpys_for_every_row():
    rng = np.random.default_rng(3)
    samples = ([rng.normal(size=int(rng.integers(1, 700))) for _ in range(300)]
               + [np.array([2.5]), np.ones(4), rng.integers(0, 3, 41).astype(float), np.arange(20_000.0),
                  np.array([1.0, np.nan, 2.0, 3.0])])
    qs = [0, 1, 25, 50, 75, 99, 100]
    np.testing.assert_array_equal(rh.row_percentiles(samples, qs), np.array([np.percentile(v, qs) for v in samples]))


def test_mapped_points_are_each_shots_transform_of_its_points(solution):
    prob, ref = solution.problem, solution.refined
    mapped = rh.mapped_points(solution)
    assert [len(m) for m in mapped] == [len(p) for p in prob.profiles]
    for i in (0, prob.n_profiles // 2, prob.n_profiles - 1):
        p_s = np.column_stack([np.zeros(len(prob.profiles[i])), prob.profiles[i]])
        expected = (p_s @ ref.R.T + ref.t) @ prob.R_sphere_from_mount[i].T + prob.t_sphere_from_mount[i]
        np.testing.assert_allclose(mapped[i], expected, rtol=0, atol=1e-9)
