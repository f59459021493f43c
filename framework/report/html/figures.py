"""The report's figures: matplotlib (Agg, no pyplot state) drawings of the residuals and the sphere, as PNG."""

from __future__ import annotations

import base64
import io
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from spherecal.core.models import SPHERE_FRAME
from spherecal.estimation.problem import KIND_PROFILE, KIND_SPHERE_CENTRE
from spherecal.io import files as safeio
from spherecal.report.html.data import (binned_residuals, centre_rows, is_profile, mapped_centres, mapped_points,
                                        plot_sample, profile_points_and_residuals, residual_limit, row_percentiles,
                                        sphere_directions, station_residuals)

#: Figures of the report, by key: saved as ``<stem>_<key>.png``. A dataset without profiles
#: has no ``residuals_per_profile``; one without centre observations no ``residuals_per_centre``.
FIGURE_NAMES = ("residuals_per_profile", "residuals_per_centre", "residuals_per_station", "residual_histogram",
                "residuals_along_line", "residuals_on_sphere", "sphere_3d")

_DPI = 100
_MAX_POINTS_3D_PER_PROFILE = 60
#: At most this many points are drawn in a scatter figure (an evenly spread sample); every
#: statistic printed or drawn as a line uses all the points.
MAX_POINTS_PLOTTED = 20_000
#: At most this many points are drawn in each 3-D view of the sphere (an 8 k-point sphere of
#: about 500 x 500 pixels is already solid colour; each point is projected and depth-sorted).
MAX_POINTS_3D = 8_000


def _station_colours(labels: list[str]) -> dict[str, Any]:
    """A colour for each station, by label, in the order given."""
    from matplotlib import colormaps

    # tab10 without its red (index 3): red marks flagged observations in the figures
    cmap = colormaps["tab10"]
    palette = [cmap(i) for i in range(10) if i != 3]
    return {label: palette[k % len(palette)] for k, label in enumerate(labels)}


def _png(fig: Figure) -> bytes:
    """The figure as PNG, laid out by the margins its maker gave (:func:`_margins`)."""
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    # zlib's fastest level: at level 6 (the default) the encoding takes a tenth of the
    # report's time, for files only 4 % smaller
    fig.savefig(buf, format="png", dpi=_DPI, pil_kwargs={"compress_level": 1})
    return buf.getvalue()


def _margins(fig: Figure, left: float, right: float, bottom: float, top: float, gap: float = 0.0,
             columns: int = 1) -> None:
    """Fixed margins around the subplots and ``gap`` between ``columns`` side-by-side
    ones, inches.

    In place of a layout engine (``tight_layout``), which measures every tick label of
    every axis before the real draw measures them again: a sixth of the report's time on
    1 M points. The margins hold the longest labels the figures get (tick labels up to
    8 characters, such as -0.00075; observation numbers on their side; two-line titles),
    which tests/report/test_html_layout.py checks on data from micrometre to millimetre
    residuals."""
    width, height = fig.get_size_inches()
    axis_width = (width - left - right - (columns - 1) * gap) / columns
    fig.subplots_adjust(left=left / width, right=1.0 - right / width, bottom=bottom / height,
                        top=1.0 - top / height, wspace=gap / axis_width)


def _flagged_mark(ax, k: int, n: int, index: int, label_y: float) -> None:
    """A flagged observation at position k of n: a red band and cross, 'obs <index>
    flagged' (centred on it; near either end of the axis, ending at it or starting at it,
    so that it stays inside the figure)."""
    ax.axvspan(k - 0.45, k + 0.45, color="#c5221f", alpha=0.18)
    ax.plot([k], [0.0], marker="x", color="#c5221f", markersize=10, mew=2.5)
    along = (k + 0.7) / (n + 0.4)  # the position in the axis' width (x from -0.7 to n - 0.3)
    ha = "right" if along > 0.95 else "left" if along < 0.05 else "center"
    ax.annotate(f"obs {index}\nflagged", (k, label_y), ha=ha, va="bottom", fontsize=7, color="#c5221f")


#: Station names longer than this are shortened (with an ellipsis) where a figure writes
#: them; the report's tables give them whole.
MAX_LABEL_CHARS = 14


def _short(label: str) -> str:
    """``label`` as a figure writes it: at most :data:`MAX_LABEL_CHARS` characters."""
    label = str(label)
    return label if len(label) <= MAX_LABEL_CHARS else label[:MAX_LABEL_CHARS - 1] + "\u2026"


#: Most observation indices written under a per-observation figure (every k-th beyond,
#: turned on their side).
MAX_TICK_LABELS = 40
#: The bottom margin of a per-observation figure, inches: indices level, on their side.
_INDEX_AXIS_BOTTOM = {False: 0.6, True: 0.9}


def _station_axis(ax, entries: list[tuple], label_y: float) -> None:
    """The x axis of per-observation figures (entries: (station, index, ...)): dashed
    lines between stations, each station's label centred above its entries at
    ``label_y``, the observation indices as ticks (at most :data:`MAX_TICK_LABELS`,
    evenly spread, when there are more)."""
    stations = [e[0] for e in entries]
    n = len(stations)
    ticks = plot_sample(n, MAX_TICK_LABELS)
    ax.set_xticks(ticks, [str(entries[k][1]) for k in ticks], fontsize=7, rotation=90 if n > MAX_TICK_LABELS else 0)
    ax.set_xlim(-0.7, n - 0.3)
    ax.set_xlabel("observation index (grouped by station)")
    for k in range(1, n):
        if stations[k] != stations[k - 1]:
            ax.axvline(k - 0.5, color="#9aa0a6", lw=0.8, ls="--")
    starts = [0] + [k for k in range(1, n) if stations[k] != stations[k - 1]] + [n]
    for a, b in zip(starts[:-1], starts[1:]):
        ax.text((a + b - 1) / 2, label_y, _short(stations[a]), ha="center", va="center", fontsize=9,
                fontweight="bold")


def _fig_per_profile(solution, result, colours) -> Figure:
    prob, ref = solution.problem, solution.refined
    entries = [(prob.station_labels[prob.station_of[i]], int(prob.obs_index[i]), ref.residuals[i], None)
               for i in range(prob.n_profiles) if prob.kinds[i] == KIND_PROFILE]
    entries += [(f.station, f.index, None, f.reason) for f in result.flagged if is_profile(solution, f.index)]
    order = list(prob.station_labels) + sorted({f.station for f in result.flagged} - set(prob.station_labels))
    entries.sort(key=lambda e: (order.index(e[0]), e[1]))
    n = len(entries)
    fig = Figure(figsize=(min(16.0, max(7.5, 6.0 + 0.16 * n)), 4.2))
    ax = fig.add_subplot()
    used = [(k, e) for k, e in enumerate(entries) if e[2] is not None]
    _boxes(ax, [k for k, _ in used], [e[2] for _, e in used], [colours.get(e[0], "grey") for _, e in used])
    lim = max(float(np.max(np.abs(np.concatenate([e[2] for _, e in used])))), 1e-3)
    ax.set_ylim(-1.15 * lim, 1.3 * lim)
    for k, e in enumerate(entries):
        if e[2] is None:
            _flagged_mark(ax, k, n, e[1], -1.05 * lim)
    _station_axis(ax, entries, 1.22 * lim)
    ax.axhline(0, color="black", lw=0.6)
    ax.set_ylabel("in-plane residual (mm)")
    shape = ("dark band: quartiles, light band: 1-99 %, line: median" if len(used) > MAX_BOXES
             else "box: quartiles, whiskers: 1-99 %")
    ax.set_title(f"Residuals per profile ({shape}; red: flagged and left out)", fontsize=10)
    _margins(fig, 1.1, 0.2, _INDEX_AXIS_BOTTOM[n > MAX_TICK_LABELS], 0.35)
    return fig


def _boxes(ax, positions, samples, colours, width: float = 0.6) -> None:
    """Box plots of ``samples`` at ``positions`` (box: quartiles, whiskers: 1-99 %, a
    black median), drawn as three collections (one artist per box takes seconds); beyond
    :data:`MAX_BOXES`, as bands (:func:`_bands`). The statistics are every point's."""
    from matplotlib.collections import LineCollection, PolyCollection

    if not len(positions):
        return
    q = row_percentiles(samples, [1, 25, 50, 75, 99])  # (n, 5), every point
    x = np.asarray(positions, dtype=float)
    if len(x) > MAX_BOXES:
        _bands(ax, x, q, colours)
        return
    h = width / 2
    boxes = np.stack([np.column_stack([x - h, q[:, 1]]), np.column_stack([x + h, q[:, 1]]),
                      np.column_stack([x + h, q[:, 3]]), np.column_stack([x - h, q[:, 3]])], axis=1)
    ax.add_collection(PolyCollection(boxes, facecolors=colours, edgecolors="black", linewidths=0.6, alpha=0.75))
    whiskers = [((xi, lo), (xi, b)) for xi, lo, b in zip(x, q[:, 0], q[:, 1])]
    whiskers += [((xi, t), (xi, hi)) for xi, t, hi in zip(x, q[:, 3], q[:, 4])]
    caps = [((xi - h / 2, v), (xi + h / 2, v)) for xi, v in zip(np.r_[x, x], np.r_[q[:, 0], q[:, 4]])]
    ax.add_collection(LineCollection(whiskers + caps, colors="black", linewidths=0.6))
    ax.add_collection(LineCollection([((xi - h, m), (xi + h, m)) for xi, m in zip(x, q[:, 2])], colors="black",
                                     linewidths=1.0))
    ax.autoscale_view()


#: More boxes than this in one figure (a box then narrower than a few pixels) are drawn as
#: bands: the same statistics, every point's, as an area per run of one colour.
MAX_BOXES = 400


def _bands(ax, x, q, colours) -> None:
    """What :func:`_boxes` draws, for very many positions: per run of positions of one
    colour (a station), the 1-99 % band (light), the quartiles' band and the median as a
    line, each point of them a position's statistics (``q`` (n, 5))."""
    colours = list(colours)
    runs = [0] + [k for k in range(1, len(x)) if colours[k] != colours[k - 1] or x[k] != x[k - 1] + 1] + [len(x)]
    for a, b in zip(runs[:-1], runs[1:]):
        xs = np.repeat(x[a:b], 2) + np.tile([-0.5, 0.5], b - a)  # each position as a step of width 1
        band = {j: np.repeat(q[a:b, j], 2) for j in range(5)}
        ax.fill_between(xs, band[0], band[4], color=colours[a], alpha=0.3, lw=0)
        ax.fill_between(xs, band[1], band[3], color=colours[a], alpha=0.75, lw=0)
        ax.plot(xs, band[2], color="black", lw=0.3, alpha=0.6)
    ax.autoscale_view()


def _fig_per_centre(solution, result, colours) -> Figure:
    """The length of each centre observation's residual (mm), grouped by station; the
    flagged ones marked in red."""
    prob, ref = solution.problem, solution.refined
    entries = [(prob.station_labels[prob.station_of[i]], int(prob.obs_index[i]),
                float(np.linalg.norm(ref.centre_residuals[i]))) for i in centre_rows(solution)]
    entries += [(f.station, f.index, None) for f in result.flagged if not is_profile(solution, f.index)]
    order = list(prob.station_labels) + sorted({e[0] for e in entries} - set(prob.station_labels))
    entries.sort(key=lambda e: (order.index(e[0]), e[1]))
    n = len(entries)
    fig = Figure(figsize=(min(16.0, max(7.5, 6.0 + 0.16 * n)), 4.0))
    ax = fig.add_subplot()
    top = max([e[2] for e in entries if e[2] is not None] + [1e-3])
    for k, (label, index, length) in enumerate(entries):
        if length is None:
            _flagged_mark(ax, k, n, index, 0.55 * top)
        else:
            ax.bar([k], [length], width=0.7, color=colours.get(label, "grey"), alpha=0.8)
    _station_axis(ax, entries, 1.12 * top)
    ax.set_ylim(0, 1.22 * top)
    ax.set_ylabel("centre residual, length (mm)")
    ax.set_title("Residual of every centre observation used (red: flagged and left out)", fontsize=10)
    _margins(fig, 1.1, 0.2, _INDEX_AXIS_BOTTOM[n > MAX_TICK_LABELS], 0.35)
    return fig


def _fig_per_station(solution, result, colours) -> Figure:
    prob, ref = solution.problem, solution.refined
    labels = list(prob.station_labels)
    data = [station_residuals(solution, np.flatnonzero(prob.station_of == k)) for k in range(len(labels))]
    fig = Figure(figsize=(max(5.0, 1.2 * len(labels) + 2.5), 3.8))
    ax = fig.add_subplot()
    _boxes(ax, range(len(labels)), data, [colours[label] for label in labels])
    top = max(float(np.percentile(np.abs(d), 99)) for d in data)
    for k, label in enumerate(labels):
        rms = result.residuals.per_station_rms_mm.get(label, float(np.sqrt(np.mean(data[k] ** 2))))
        ax.text(k, 1.12 * top, f"RMS {rms:.4f}", ha="center", fontsize=8)
    ax.set_ylim(-1.25 * top, 1.3 * top)
    ax.axhline(0, color="black", lw=0.6)
    ax.set_xticks(range(len(labels)), [_short(label) for label in labels])
    ax.set_xlabel("station")
    ax.set_ylabel("residual (mm)")
    ax.set_title("Residuals per station", fontsize=10)
    _margins(fig, 1.1, 0.2, 0.6, 0.35)
    return fig


def _fig_histogram(solution, result) -> Figure:
    res = station_residuals(solution, np.arange(solution.problem.n_profiles))
    rms = result.residuals.rms_mm
    point = float((result.diagnostics.noise or {}).get("point_noise_mm", 0.0) or 0.0)
    fig = Figure(figsize=(6.5, 3.8))
    ax = fig.add_subplot()
    lim = max(float(np.max(np.abs(res))), 4 * rms)
    ax.hist(res, bins=60, range=(-lim, lim), density=True, color="#8ab4f8", edgecolor="white", lw=0.3,
            label=f"{res.size} residuals")
    x = np.linspace(-lim, lim, 400)
    ax.plot(x, np.exp(-0.5 * (x / rms) ** 2) / (rms * np.sqrt(2 * np.pi)), color="#1a73e8", lw=1.6,
            label=f"normal, sd = residual RMS {rms:.4f} mm")
    if point > 0:
        ax.plot(x, np.exp(-0.5 * (x / point) ** 2) / (point * np.sqrt(2 * np.pi)), color="#5f6368", lw=1.2,
                ls="--", label=f"normal, sd = point noise {point:.4f} mm")
    ax.set_xlabel("residual (mm)")
    ax.set_ylabel("density (1/mm)")
    ax.set_title("Histogram of the residuals with the expected normal curves", fontsize=10)
    ax.legend(fontsize=8)
    _margins(fig, 0.9, 0.2, 0.6, 0.35)  # (densities: shorter tick labels than residuals)
    return fig


def _fig_sphere(solution, result, colours, pts: list[np.ndarray] | None = None) -> Figure:
    prob, ref = solution.problem, solution.refined
    pts = mapped_points(solution) if pts is None else pts
    c, r = np.asarray(ref.centre, dtype=float), float(ref.radius)
    frame = SPHERE_FRAME[result.mounting]
    # at most _MAX_POINTS_3D_PER_PROFILE of each profile, and MAX_POINTS_3D (MAX_POINTS_PLOTTED if fewer) in all
    per_profile = [p[::max(1, len(p) // _MAX_POINTS_3D_PER_PROFILE)] for p in pts]
    every = np.concatenate(per_profile) if per_profile else np.zeros((0, 3))
    station = np.repeat(np.asarray(prob.station_of[:len(pts)]), [len(p) for p in per_profile])
    pick = plot_sample(len(every), min(MAX_POINTS_PLOTTED, MAX_POINTS_3D))
    drawn = {}
    for k, label in enumerate(prob.station_labels):
        mine = pick[station[pick] == k]
        if len(mine):
            drawn[label] = every[mine]
    fig = Figure(figsize=(11, 5.2))
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 25), np.linspace(0, np.pi, 13))
    sx, sy, sz = c[0] + r * np.cos(u) * np.sin(v), c[1] + r * np.sin(u) * np.sin(v), c[2] + r * np.cos(v)
    for j, (elev, azim) in enumerate([(25, -60), (60, 30)]):
        ax = fig.add_subplot(1, 2, j + 1, projection="3d")
        ax.plot_wireframe(sx, sy, sz, color="#9aa0a6", lw=0.4, alpha=0.6)
        ax.scatter([c[0]], [c[1]], [c[2]], color="black", s=20, marker="+")
        seen = set()
        for label, q in drawn.items():  # one scatter per station (one per profile takes seconds)
            ax.scatter(q[:, 0], q[:, 1], q[:, 2], s=1.5, color=colours[label], depthshade=False,
                       label=f"station {_short(label)}")
            seen.add(label)
        for i, (kind, q) in mapped_centres(solution).items():
            label = prob.station_labels[prob.station_of[i]]
            if kind == KIND_SPHERE_CENTRE:
                ax.scatter(q[:, 0], q[:, 1], q[:, 2], s=18, marker="x", color=colours[label], depthshade=False,
                           label=None if label in seen else f"station {_short(label)}")
            else:
                ax.plot(q[:, 0], q[:, 1], q[:, 2], lw=0.8, color=colours[label],
                        label=None if label in seen else f"station {_short(label)}")
            seen.add(label)
        for setter, k in ((ax.set_xlim, 0), (ax.set_ylim, 1), (ax.set_zlim, 2)):
            setter(c[k] - 1.15 * r, c[k] + 1.15 * r)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=elev, azim=azim)
        ax.set_xlabel(f"{frame} x (mm)", fontsize=8)
        ax.set_ylabel(f"{frame} y (mm)", fontsize=8)
        ax.set_zlabel(f"{frame} z (mm)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.locator_params(nbins=5)  # (the default's 8-9 labels an axis ran into each other)
        if j == 0:
            ax.legend(fontsize=8, markerscale=5, loc="upper left")
    what = "every profile" if (prob.kinds == KIND_PROFILE).any() else "every observation"
    fig.suptitle(f"Fitted sphere (r = {r:.3f} mm) and {what} mapped into the {frame} frame "
                 f"through A_i X", fontsize=10)
    _margins(fig, 0.15, 0.15, 0.28, 0.45, gap=0.2, columns=2)
    return fig


def _fig_along_line(solution, result) -> Figure:
    """Residual against the position along the laser line and against depth: every
    point's residual (a sample of them drawn when there are many) and, from all of them,
    the mean and RMS per bin."""
    y, z, res = profile_points_and_residuals(solution)
    pick = plot_sample(res.size, MAX_POINTS_PLOTTED)
    lim = residual_limit(res)
    outside = int(np.count_nonzero(np.abs(res) > lim))
    fig = Figure(figsize=(11, 4.0))
    for j, (x, name) in enumerate([(y, "position along the laser line, sensor y (mm)"),
                                   (z, "depth, distance from the sensor, sensor z (mm)")]):
        ax = fig.add_subplot(1, 2, j + 1)
        ax.scatter(x[pick], np.clip(res[pick], -lim, lim), s=1.0, color="#8ab4f8", alpha=0.5, lw=0, rasterized=True,
                   label=f"residuals ({pick.size} of {res.size} drawn)")
        b = binned_residuals(x, res)
        ax.plot(b["centre_mm"], b["mean_mm"], color="#1a73e8", lw=1.8, marker="o", ms=3, label="mean per bin")
        ax.plot(b["centre_mm"], b["rms_mm"], color="#c5221f", lw=1.2, ls="--", label="RMS per bin")
        ax.plot(b["centre_mm"], -b["rms_mm"], color="#c5221f", lw=1.2, ls="--")
        ax.axhline(0, color="black", lw=0.6)
        ax.set_ylim(-lim, lim)
        ax.set_xlabel(name)
        ax.set_ylabel("residual (mm)")
        if j == 0:
            legend = ax.legend(fontsize=7, loc="upper right")
            legend.legend_handles[0].set_sizes([12.0])
    # (two lines: on one, the title is wider than the figure)
    fig.suptitle("Residuals against position along the line and against depth\n(all "
                 f"{res.size} points in the lines; residual RMS {result.residuals.rms_mm:.4f} mm"
                 + (f"; {outside} beyond +/-{lim:.3f} mm drawn at the edge" if outside else "") + ")", fontsize=10)
    _margins(fig, 1.1, 0.2, 0.6, 0.75, gap=1.1, columns=2)
    return fig


def _fig_on_sphere(solution, result, pts: list[np.ndarray] | None = None) -> Figure:
    """The residuals mapped on the sphere: each point at its direction from the fitted
    centre (azimuth, elevation in the sphere frame), coloured by its residual."""
    az, el, res = sphere_directions(solution, pts)
    pick = plot_sample(res.size, MAX_POINTS_PLOTTED)
    lim = residual_limit(res)
    frame = SPHERE_FRAME[result.mounting]
    fig = Figure(figsize=(11, 4.6))
    ax = fig.add_subplot()
    sc = ax.scatter(az[pick], el[pick], c=np.clip(res[pick], -lim, lim), cmap="RdBu_r", vmin=-lim, vmax=lim, s=2.0,
                    lw=0, rasterized=True)
    _margins(fig, 0.9, 0.2, 0.6, 0.35)  # (before the colour bar, which takes its room from the axes)
    fig.colorbar(sc, ax=ax, label="residual (mm)", shrink=0.9)
    ax.set_xlim(-180, 180)
    ax.set_ylim(-90, 90)
    ax.set_xticks(range(-180, 181, 45))
    ax.set_yticks(range(-90, 91, 30))
    ax.grid(color="#dadce0", lw=0.5)
    ax.set_xlabel(f"azimuth about {frame} z, from {frame} x (deg)")
    ax.set_ylabel(f"elevation from the {frame} x-y plane (deg)")
    ax.set_title(f"Residuals mapped on the sphere ({pick.size} of {res.size} points drawn; colour limits "
                 f"+/-{lim:.3f} mm)", fontsize=10)
    return fig


#: The caption under each figure in the report, by key.
CAPTIONS = {
    "residuals_per_profile": "Residuals of every profile used, grouped by station; flagged observations "
                             "(left out of the solution) are marked in red.",
    "residuals_per_centre": "The residual of every centre observation used (its length, mm), grouped by "
                            "station; flagged observations are marked in red.",
    "residuals_per_station": "Residuals per station. A station clearly wider than the others deserves a look.",
    "residual_histogram": "All residuals. Solid: a normal curve with the residual RMS; dashed: with the sensor "
                          "point noise alone (the gap is the robot's pose noise). Heavy tails mean strays.",
    "residuals_along_line": "Residuals against the position along the laser line and against depth (distance "
                            "from the sensor). The lines (mean and RMS per bin) use every point; the dots are "
                            "a sample when there are many. A slope or a curve is a systematic error of the "
                            "sensor (scale, tilt of the line) or of the sphere radius, not noise.",
    "residuals_on_sphere": "Every point at its direction from the fitted centre, coloured by its residual. "
                           "Noise looks like salt and pepper; a patch or a band of one colour is a bias "
                           "(a dirty or damaged area of the sphere, a reflection, a wrong radius).",
    "sphere_3d": "The fitted sphere (wireframe) and the profile points mapped into the sphere frame through "
                 "A_i X, coloured by station: they should lie on the sphere.",
}
#: The captions that differ for data without profiles (centre observations only), by key.
CENTRE_CAPTIONS = {
    "sphere_3d": "The fitted sphere (wireframe) and the centre observations mapped into the sphere frame through "
                 "A_i X, coloured by station: a sphere centre (x) should fall on the fitted centre (+), a circle "
                 "should lie on the sphere.",
}


def _drawers(solution, result, pts: list[np.ndarray]) -> dict[str, Any]:
    """What draws each figure the data has, by key in the report's order: no per-profile,
    along-the-line or on-the-sphere figure without profiles, no per-centre figure without
    centre observations. ``pts``: the :func:`mapped_points` of ``solution``."""
    labels = list(solution.problem.station_labels)
    colours = _station_colours(labels + sorted({f.station for f in result.flagged} - set(labels)))
    drawers = {
        "residuals_per_profile": lambda: _fig_per_profile(solution, result, colours),
        "residuals_per_centre": lambda: _fig_per_centre(solution, result, colours),
        "residuals_per_station": lambda: _fig_per_station(solution, result, colours),
        "residual_histogram": lambda: _fig_histogram(solution, result),
        "residuals_along_line": lambda: _fig_along_line(solution, result),
        "residuals_on_sphere": lambda: _fig_on_sphere(solution, result, pts),
        "sphere_3d": lambda: _fig_sphere(solution, result, colours, pts),
    }
    if not (solution.problem.kinds == KIND_PROFILE).any():
        del drawers["residuals_per_profile"], drawers["residuals_along_line"], drawers["residuals_on_sphere"]
    if not len(centre_rows(solution)):
        del drawers["residuals_per_centre"]
    return drawers


def draw_figures(solution, result, out: Path, stem: str, pts: list[np.ndarray]) -> dict[str, tuple[str, str]]:
    """Draw the figures the data has (of :data:`FIGURE_NAMES`), save each as
    ``<stem>_<key>.png`` in ``out`` and return them by key as (the PNG in base64, its
    caption). ``pts``: the :func:`mapped_points` of ``solution``."""
    figures = {}
    captions = CAPTIONS if (solution.problem.kinds == KIND_PROFILE).any() else {**CAPTIONS, **CENTRE_CAPTIONS}
    for key, draw in _drawers(solution, result, pts).items():
        with matplotlib.rc_context({"text.parse_math": False}):  # labels are data: '$x$' is not mathtext
            png = _png(draw())
        safeio.write_bytes(out / f"{stem}_{key}.png", png)
        figures[key] = (base64.b64encode(png).decode("ascii"), captions[key])
    return figures
