"""A self-contained HTML report of a calibration.

:func:`write_report` writes one HTML file that opens offline: the CSS is inlined and
the figures (PNG, drawn with matplotlib's Agg renderer, no pyplot state touched) are
embedded as base64 data URIs; the same PNGs are saved next to the HTML file. The report
shows, top to bottom: the verdict, the transform with its direction and uncertainties,
what to do when something is off, residual plots, a 3-D view of the sphere with the
mapped points, the uncertainty, station and flagged-observation tables, an optional
validation table and the estimator's details. See docs/results.md for a tour.
"""

from __future__ import annotations

import base64
import html
import io
import json
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from importlib import resources
from pathlib import Path
from string import Template
from typing import Any

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from spherecal import __version__
from spherecal.core import geometry as geo
from spherecal.core.errors import InputError
from spherecal.estimation.blocks import BLOCK_POINTS, profile_blocks
from spherecal.estimation.problem import KIND_PROFILE, KIND_SPHERE_CENTRE
from spherecal.io.exporters import ExportNote
from spherecal.core.mapping import map_profile_list
from spherecal.core.models import SPHERE_FRAME, CalibrationResult
from spherecal.report import export
from spherecal.io import files as safeio
from spherecal.report.assess import POINT_DISTANCE_MM, Thresholds, Verdict, advice, expected_rms_mm, inconsistent_stations, verdict

__all__ = ["write_report", "mapped_points", "FIGURE_NAMES"]

#: Figures of the report, by key: saved as ``<stem>_<key>.png``. A dataset without profiles
#: has no ``residuals_per_profile``; one without centre observations no ``residuals_per_centre``.
FIGURE_NAMES = ("residuals_per_profile", "residuals_per_centre", "residuals_per_station", "residual_histogram",
                "residuals_along_line", "residuals_on_sphere", "sphere_3d")

_DPI = 100
_MAX_POINTS_3D_PER_PROFILE = 60
#: At most this many points are drawn in a scatter figure, and this many in the
#: interactive view; every statistic printed or drawn as a line uses all the points.
MAX_POINTS_PLOTTED = 20_000
MAX_POINTS_INTERACTIVE = 4_000
#: ... and at most this many in each 3-D view of the sphere (an 8 k-point sphere of about
#: 500 x 500 pixels is already solid colour; each point is projected and depth-sorted).
MAX_POINTS_3D = 8_000
#: Bins of the residual statistics against position along the line and against depth.
RESIDUAL_BINS = 16


# --- helpers ----------------------------------------------------------------------------------------
def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _n(value: float | None, decimals: int = 4) -> str:
    if value is None:
        return "&ndash;"
    return export.fixed(value, decimals)


def _station_colours(labels: list[str]) -> dict[str, Any]:
    from matplotlib import colormaps

    # tab10 without its red (index 3): red marks flagged observations in the figures
    cmap = colormaps["tab10"]
    palette = [cmap(i) for i in range(10) if i != 3]
    return {label: palette[k % len(palette)] for k, label in enumerate(labels)}


def _png(fig: Figure) -> bytes:
    """The figure as PNG, laid out by the margins its maker gave (:func:`_margins`)."""
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    # zlib's fastest level: the encoding took a tenth of the report at level 6 (the
    # default), for files 4 % smaller
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
    which tests/core/test_report_layout.py checks on data from micrometre to millimetre
    residuals."""
    width, height = fig.get_size_inches()
    axis_width = (width - left - right - (columns - 1) * gap) / columns
    fig.subplots_adjust(left=left / width, right=1.0 - right / width, bottom=bottom / height,
                        top=1.0 - top / height, wspace=gap / axis_width)


def mapped_points(solution) -> list[np.ndarray]:
    """Each used profile's points mapped into the sphere frame through ``A_i X``:
    ``p = R_A_i (R p_sensor + t) + t_A_i`` with p_sensor = (0, y, z); ``A_i`` is
    ``base_from_flange_i`` (eye-in-hand) or ``flange_from_base_i`` (eye-to-hand). mm.
    (:func:`spherecal.core.mapping.map_profile_list`, the scan's mapping.)"""
    prob, ref = solution.problem, solution.refined
    R_A, t_A = prob.R_sphere_from_mount, prob.t_sphere_from_mount
    points, _ = map_profile_list(R_A @ ref.R, R_A @ np.asarray(ref.t, dtype=float) + t_A, prob.profiles)
    return np.split(points, np.cumsum([len(p) for p in prob.profiles])[:-1])


def mapped_centres(solution) -> dict[int, tuple[int, np.ndarray]]:
    """Each used centre observation mapped into the sphere frame through ``A_i X``, by
    position in the problem: a sphere centre as one point (1, 3) (it should fall on the
    fitted centre); a circle as points along it (it should lie on the fitted sphere). mm."""
    prob, ref = solution.problem, solution.refined
    out = {}
    theta = np.linspace(0.0, 2 * np.pi, 49)
    for i in _centre_rows(solution):
        v = prob.centre_meas[i]
        if prob.kinds[i] == KIND_SPHERE_CENTRE:
            p_s = v[None, :]
        else:  # the circle lies in the laser plane x = 0
            p_s = np.column_stack([np.zeros_like(theta), v[0] + v[2] * np.cos(theta), v[1] + v[2] * np.sin(theta)])
        p_sphere = (p_s @ ref.R.T + ref.t) @ prob.R_sphere_from_mount[i].T + prob.t_sphere_from_mount[i]
        out[int(i)] = (int(prob.kinds[i]), p_sphere)
    return out


# --- figures ----------------------------------------------------------------------------------------
def _is_profile(solution, index: int) -> bool:
    """Whether observation ``index`` of the dataset is a profile (the solution keeps the
    kinds of every observation, used or flagged)."""
    return solution.extras.get("kinds", {}).get(int(index), "profile") == "profile"


def _centre_rows(solution) -> np.ndarray:
    """Positions of the centre observations used."""
    return np.flatnonzero(solution.problem.kinds != KIND_PROFILE)


def _station_residuals(solution, members) -> np.ndarray:
    """The points' residuals and the centre residuals' components of shots ``members``, mm."""
    ref = solution.refined
    parts = [ref.residuals[i] for i in members]
    if ref.centre_residuals is not None:
        c = ref.centre_residuals[members]
        parts.append(c[~np.isnan(c[:, 0])].ravel())
    return np.concatenate(parts) if parts else np.zeros(0)


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
    entries += [(f.station, f.index, None, f.reason) for f in result.flagged if _is_profile(solution, f.index)]
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
    black median), drawn as three collections (one artist per box took seconds); beyond
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


def row_percentiles(samples, qs) -> np.ndarray:
    """``np.percentile(v, qs)`` (its default, linear interpolation) of each of
    ``samples`` (non-empty arrays), (len(samples), len(qs)): thousands of profiles
    computed a block at a time (rows sorted together), not one call each."""
    qs = np.asarray(qs, dtype=float) / 100.0
    out = np.empty((len(samples), len(qs)))
    counts = np.array([len(v) for v in samples], dtype=int)
    for p0, p1 in profile_blocks(counts, BLOCK_POINTS):
        k = counts[p0:p1]
        rows = np.full((p1 - p0, k.max()), np.inf)
        rows[np.arange(k.max()) < k[:, None]] = np.concatenate([np.ravel(v) for v in samples[p0:p1]])
        has_nan = np.isnan(rows).any(axis=1)  # (NaN, as numpy gives it)
        rows.sort(axis=1)
        at = qs[None, :] * (k[:, None] - 1)
        lo = np.floor(at).astype(int)
        hi = np.minimum(lo + 1, k[:, None] - 1)
        a = np.take_along_axis(rows, lo, axis=1)
        b = np.take_along_axis(rows, hi, axis=1)
        g = at - lo
        diff = b - a
        # numpy's lerp: from the nearer end, so that a value between two equal ones is exact
        out[p0:p1] = np.where(g >= 0.5, b - diff * (1.0 - g), a + diff * g)
        out[p0:p1][has_nan] = np.nan
    return out


def _fig_per_centre(solution, result, colours) -> Figure:
    """The length of each centre observation's residual (mm), grouped by station; the
    flagged ones marked in red."""
    prob, ref = solution.problem, solution.refined
    entries = [(prob.station_labels[prob.station_of[i]], int(prob.obs_index[i]),
                float(np.linalg.norm(ref.centre_residuals[i]))) for i in _centre_rows(solution)]
    entries += [(f.station, f.index, None) for f in result.flagged if not _is_profile(solution, f.index)]
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
    data = [_station_residuals(solution, np.flatnonzero(prob.station_of == k)) for k in range(len(labels))]
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
    res = _station_residuals(solution, np.arange(solution.problem.n_profiles))
    rms = result.residuals.rms_mm
    point = float(result.diagnostics.get("noise", {}).get("point_noise_mm", 0.0) or 0.0)
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
        for label, q in drawn.items():  # one scatter per station (one per profile took seconds)
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


def plot_sample(n: int, limit: int) -> np.ndarray:
    """Indices of at most ``limit`` of ``n`` points, evenly spread over them (every k-th,
    deterministic): what a figure draws of a large dataset. Statistics use all points."""
    if n <= limit:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, limit).round().astype(int))


def profile_points_and_residuals(solution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every used profile point: its position along the laser line (sensor y, mm), its
    depth (sensor z, the distance from the sensor along its line of sight, mm), and its
    residual (mm); as three arrays of equal length (empty without profiles)."""
    prob, ref = solution.problem, solution.refined
    rows = [i for i in range(prob.n_profiles) if prob.kinds[i] == KIND_PROFILE]
    if not rows:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    yz = np.concatenate([np.asarray(prob.profiles[i], dtype=float) for i in rows])
    res = np.concatenate([np.asarray(ref.residuals[i], dtype=float) for i in rows])
    return yz[:, 0], yz[:, 1], res


def binned_residuals(x: np.ndarray, residuals: np.ndarray, bins: int = RESIDUAL_BINS) -> dict[str, np.ndarray]:
    """The residuals' statistics in ``bins`` equal-width bins of ``x`` (mm), from every
    point: ``centre_mm`` (bin centres), ``count``, ``mean_mm`` and ``rms_mm`` (NaN in an
    empty bin)."""
    x, residuals = np.asarray(x, dtype=float), np.asarray(residuals, dtype=float)
    lo, hi = (float(x.min()), float(x.max())) if x.size else (0.0, 1.0)
    if hi <= lo:
        hi = lo + 1e-9
    edges = np.linspace(lo, hi, bins + 1)
    k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    count = np.bincount(k, minlength=bins)
    total = np.bincount(k, weights=residuals, minlength=bins)
    squares = np.bincount(k, weights=residuals ** 2, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
        rms = np.where(count > 0, np.sqrt(squares / count), np.nan)
    return {"centre_mm": 0.5 * (edges[:-1] + edges[1:]), "count": count, "mean_mm": mean, "rms_mm": rms}


def _residual_limit(res: np.ndarray) -> float:
    """The y range of a residual scatter: its 99.9th percentile of |r|, so that a few
    large residuals do not squash the 0.01 mm structure (they are counted, not hidden)."""
    return max(float(np.percentile(np.abs(res), 99.9)) * 1.15, 1e-3) if res.size else 1e-3


def _fig_along_line(solution, result) -> Figure:
    """Residual against the position along the laser line and against depth: every
    point's residual (a sample of them drawn when there are many) and, from all of them,
    the mean and RMS per bin."""
    y, z, res = profile_points_and_residuals(solution)
    pick = plot_sample(res.size, MAX_POINTS_PLOTTED)
    lim = _residual_limit(res)
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
    # (two lines: on one, the title was wider than the figure)
    fig.suptitle("Residuals against position along the line and against depth\n(all "
                 f"{res.size} points in the lines; residual RMS {result.residuals.rms_mm:.4f} mm"
                 + (f"; {outside} beyond +/-{lim:.3f} mm drawn at the edge" if outside else "") + ")", fontsize=10)
    _margins(fig, 1.1, 0.2, 0.6, 0.75, gap=1.1, columns=2)
    return fig


def sphere_directions(solution, pts: list[np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every used profile point's direction from the fitted centre in the sphere frame
    as azimuth and elevation (deg), with its residual (mm). ``pts``: the
    :func:`mapped_points` of ``solution`` when already at hand."""
    pts = mapped_points(solution) if pts is None else pts
    prob, ref = solution.problem, solution.refined
    rows = [i for i in range(prob.n_profiles) if prob.kinds[i] == KIND_PROFILE]
    if not rows:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    d = np.concatenate([pts[i] for i in rows]) - np.asarray(ref.centre, dtype=float)
    res = np.concatenate([np.asarray(ref.residuals[i], dtype=float) for i in rows])
    az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    el = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])))
    return az, el, res


def _fig_on_sphere(solution, result, pts: list[np.ndarray] | None = None) -> Figure:
    """The residuals mapped on the sphere: each point at its direction from the fitted
    centre (azimuth, elevation in the sphere frame), coloured by its residual."""
    az, el, res = sphere_directions(solution, pts)
    pick = plot_sample(res.size, MAX_POINTS_PLOTTED)
    lim = _residual_limit(res)
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


def interactive_points(solution, limit: int = MAX_POINTS_INTERACTIVE, pts: list[np.ndarray] | None = None) -> dict:
    """The data of the interactive 3-D view: a sample of at most ``limit`` used profile
    points relative to the fitted centre in the sphere frame (mm, 3 decimals) with their
    residuals (mm, 4 decimals), the sphere's radius, the frame's name and the colour
    limit (mm)."""
    pts = mapped_points(solution) if pts is None else pts
    prob, ref = solution.problem, solution.refined
    rows = [i for i in range(prob.n_profiles) if prob.kinds[i] == KIND_PROFILE]
    if not rows:
        return {"points": [], "residuals": [], "radius_mm": float(ref.radius), "limit_mm": 1e-3, "frame": ""}
    d = np.concatenate([pts[i] for i in rows]) - np.asarray(ref.centre, dtype=float)
    res = np.concatenate([np.asarray(ref.residuals[i], dtype=float) for i in rows])
    pick = plot_sample(res.size, limit)
    return {"points": np.round(d[pick], 3).ravel().tolist(), "residuals": np.round(res[pick], 4).tolist(),
            "radius_mm": round(float(ref.radius), 4), "limit_mm": round(_residual_limit(res), 4),
            "total": int(res.size)}


def _interactive_html(solution, result, pts: list[np.ndarray] | None = None) -> str:
    """An interactive 3-D view that works offline: the data inline as JSON and a small
    self-contained script drawing on a canvas (drag to turn, wheel to zoom). Hidden in
    print, where the static figures stand."""
    data = interactive_points(solution, pts=pts)
    if not data["points"]:
        return ""
    data["frame"] = SPHERE_FRAME[result.mounting]
    js = resources.files(__package__).joinpath("view3d.js").read_text(encoding="utf-8")
    payload = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    n = len(data["residuals"])
    return ('<section class="interactive"><h3 id="view3d">Interactive 3-D view</h3>'
            f'<p>{n} of {data["total"]} points, relative to the fitted centre in the {_e(data["frame"])} frame, '
            "coloured by their residual (blue: negative, red: positive). Drag to turn, wheel or +/- to zoom, "
            "double-click to reset; the residuals can be exaggerated radially with the slider. Works offline: "
            "nothing is loaded from the network.</p>"
            '<canvas id="view3d-canvas" width="720" height="520" tabindex="0"></canvas>'
            '<div class="view3d-controls"><label>radial exaggeration <input id="view3d-gain" type="range" '
            'min="0" max="3" step="0.05" value="0"> <output id="view3d-gain-out">x1</output></label></div>'
            f'<script type="application/json" id="view3d-data">{payload}</script>'
            f"<script>{js}</script></section>")


# --- HTML pieces ------------------------------------------------------------------------------------
def _table(header: list[str], rows: list[list[str]], row_classes: list[str] | None = None) -> str:
    head = "".join(f"<th>{h}</th>" for h in header)
    body = []
    for k, row in enumerate(rows):
        cls = f' class="{row_classes[k]}"' if row_classes and row_classes[k] else ""
        body.append(f"<tr{cls}>" + "".join(f"<td>{cell}</td>" for cell in row) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _notes_html(notes: Sequence[ExportNote]) -> str:
    """The exporters' notes: how to use the result on the controller, the robot's own
    exporter first."""
    if not notes:
        return ("<p>No exporter of this run says how to load the result on a controller; the files next to this "
                "report hold it (docs/results.md).</p>")
    return "".join(f"<h4>{_e(n.title)}</h4><p>{_e(n.text)}</p>" + (f"<pre>{_e(n.code)}</pre>" if n.code else "")
                   for n in notes)


def _headline(result: CalibrationResult, ver, th: Thresholds, notes: Sequence[ExportNote] = ()) -> str:
    name = result.transform_name
    a, b = export.frames_of(name)
    inv = export.inverse_name(name)
    x, y, z = result.transform.translation_mm
    q = result.transform.quaternion_wxyz
    sr, st = result.std_rotation_deg, result.std_translation_mm
    reasons = "".join(f'<li><span class="dot {lv}"></span>{_e(text)}</li>' for lv, text in ver.reasons)
    exp = expected_rms_mm(result, th)
    point = result.diagnostics.get("noise", {}).get("point_noise_mm")
    cards = [
        ("translation (mm)", f"{_n(x)}, {_n(y)}, {_n(z)}"),
        ("quaternion (w, x, y, z)", ", ".join(_n(v, 6) for v in q)),
        (f"rotation 1-sigma about {a} x, y, z (deg)", ", ".join(_n(v) for v in sr)
         + f"<br><span class='muted'>U (k = 2): {', '.join(_n(K_EXPANDED * v) for v in sr)}</span>"),
        (f"translation 1-sigma along {a} x, y, z (mm)", ", ".join(_n(v) for v in st)
         + f"<br><span class='muted'>U (k = 2): {', '.join(_n(K_EXPANDED * v) for v in st)}</span>"),
        ("residual RMS (mm)", f"{_n(result.residuals.rms_mm)} <span class='muted'>expected {_n(exp)}</span>"),
        ("sensor point noise (mm)", f"{_n(point)}" + (
            f" <span class='muted'>RMS / noise {result.residuals.rms_mm / point:.1f}</span>" if point else "")),
        ("profiles used / flagged", f"{result.residuals.n_profiles_used} / {len(result.flagged)}"),
        *([("centre observations used", f"{result.residuals.n_centres_used} (residual RMS "
            f"{_n(result.residuals.centre_rms_mm)} mm, 3-D)")] if result.residuals.n_centres_used else []),
        ("points used / rejected", f"{result.residuals.n_points_used} / {result.residuals.n_points_rejected}"),
    ]
    card_html = "".join(f'<div class="card"><div class="label">{_e(lbl)}</div><div class="value">{val}</div></div>'
                        for lbl, val in cards)
    return f"""
<div class="verdict {ver.level}" id="verdict">
  <div class="big">Verdict: {ver.level.upper()} &mdash; {_e(ver.headline)}</div>
  <ul>{reasons}</ul>
</div>
<h2 id="transform">The transform: <code>{_e(name)}</code></h2>
<p class="direction"><b>{_e(name)}</b> maps points from the <b>{_e(b)}</b> frame into the <b>{_e(a)}</b> frame:
<code>p_{_e(a)} = R p_{_e(b)} + t</code>; its translation is the origin of {_e(b)} in {_e(a)} (mm).
Mounting: {_e(result.mounting)}. Its inverse is <code>{_e(inv)}</code>.</p>
<div class="cards">{card_html}</div>
<h3>As 4x4 matrices (mm), both directions</h3>
<pre>{_e(export.matrix_text(result))}</pre>
<h3 id="controller">For the robot controller and for ROS</h3>
{_notes_html(notes)}
<p class="muted">Uncertainties are one standard deviation (double them for about 95 %), after scaling by the
a-posteriori variance factor {result.variance_factor:.3f}. Rotations are small rotations about the axes of the
{_e(a)} frame. The files next to this report hold the same numbers (see docs/results.md).</p>
"""


def _advice_html(items) -> str:
    if not items:
        return "<p>Nothing calls for action: residuals, uncertainties and stations look as they should.</p>"
    return "".join(f'<div class="advice {a.level}"><h3><span class="dot {a.level}"></span>{_e(a.title)}</h3>'
                    f"<p>{_e(a.text)}</p></div>" for a in items)


#: Coverage factor of the expanded uncertainty shown next to the 1-sigma (about 95 %).
K_EXPANDED = 2.0


def _uncertainty_table(result: CalibrationResult) -> str:
    a, b = export.frames_of(result.transform_name)
    frame = result.sphere_centre_frame
    rows = []

    def add(name, value, sd, unit):
        rows.append([name, value, _n(sd), _n(K_EXPANDED * sd) if sd is not None else "&ndash;", unit])

    for k, ax in enumerate("xyz"):
        add(f"rotation about {a} {ax}", "&ndash;", result.std_rotation_deg[k], "deg")
    for k, ax in enumerate("xyz"):
        add(f"translation along {a} {ax}", _n(result.transform.translation_mm[k]), result.std_translation_mm[k], "mm")
    for k, ax in enumerate("xyz"):
        add(f"sphere centre {ax} ({frame} frame)", _n(result.sphere_centre_mm[k]), result.std_sphere_centre_mm[k], "mm")
    if result.radius_fitted:
        add("sphere radius (fitted)", _n(result.sphere_radius_mm), result.std_sphere_radius_mm, "mm")
    else:
        rows.append(["sphere radius (certified, fixed)", _n(result.sphere_radius_mm), "fixed", "fixed", "mm"])
    re = result.robot_error
    note = ""
    if re is not None:
        note = ("<p class=\"muted\">Relative to the robot's own frame (the robot's accuracy shared by every station "
                "left out: what two calibrations on this robot can differ by), 1-sigma / k = 2: rotation "
                + ", ".join(f"{_n(v)} / {_n(K_EXPANDED * v)}" for v in re.std_rotation_deg_robot_frame) + " deg; "
                "translation " + ", ".join(f"{_n(v)} / {_n(K_EXPANDED * v)}" for v in re.std_translation_mm_robot_frame)
                + " mm.</p>")
    return (_table(["quantity", "value", "1-sigma", f"expanded U (k = {K_EXPANDED:g})", "unit"], rows)
            + "<p class=\"muted\">1-sigma is the standard uncertainty; U = 2 sigma the expanded uncertainty, about "
              "95 % coverage for a normal distribution. Both include the robot's accuracy (its error shared by every "
              "station, which no data from one sphere location can see; docs/estimation.md).</p>" + note)


def _short_label(label: str) -> str:
    """``rotation about flange x`` -> ``rot x``; for the correlation matrix's columns."""
    for long, short in (("rotation about ", "rot "), ("translation along ", "t "), ("sphere centre ", "c "),
                        ("sphere radius", "r")):
        if label.startswith(long):
            rest = label[len(long):].split(" (")[0]
            return short + rest.split(" ")[-1] if short != "r" else "r"
    return label


def _correlation_html(result: CalibrationResult) -> str:
    corr = result.correlation
    if corr is None:
        return "<p>No correlation matrix: the result has no covariance.</p>"
    labels = corr.parameters
    m = np.asarray(corr.matrix, dtype=float)
    head = "".join(f"<th title=\"{_e(lbl)}\">{_e(_short_label(lbl))}</th>" for lbl in labels)
    body = []
    for i, lbl in enumerate(labels):
        cells = []
        for j in range(len(labels)):
            v = m[i, j]
            cls = "diag" if i == j else "strong" if abs(v) >= 0.9 else "notable" if abs(v) >= 0.7 else ""
            cells.append(f'<td class="{cls}">{v:+.2f}</td>' if cls else f"<td>{v:+.2f}</td>")
        body.append(f"<tr><th>{_e(lbl)}</th>{''.join(cells)}</tr>")
    strongest = max(((abs(m[i, j]), i, j) for i in range(len(labels)) for j in range(i)), default=None)
    text = ""
    if strongest is not None:
        v, i, j = strongest
        text = (f"<p>Largest correlation: {m[i, j]:+.2f} between {_e(labels[i])} and {_e(labels[j])}. Strongly "
                "correlated parameters (|r| &ge; 0.9, marked) are determined together: each alone is known worse "
                "than their combination; more varied tilts between the stations decorrelate them.</p>")
    return (f'<table class="matrix"><thead><tr><th>correlation</th>{head}</tr></thead><tbody>{"".join(body)}'
            "</tbody></table>" + text + "<p class=\"muted\">Derived from the covariance (result.json "
            "<code>correlation</code>): r = cov / (sigma sigma).</p>")


def point_uncertainty(result: CalibrationResult, distance_mm: float) -> dict:
    """The uncertainty, from the transform's, of a point measured ``distance_mm`` from
    the sensor along its line of sight (the point (0, 0, -d) in the sensor frame, whose
    z points towards the sensor), mapped into the transform's target frame:
    ``dp = w x (R p) + dt``. Returns its 1-sigma per target axis, its RMS 3-D error and
    the expanded 3-D figure (k = 2: twice the RMS), mm."""
    R = result.transform.rotation_matrix
    v = R @ np.array([0.0, 0.0, -float(distance_mm)])
    J = np.hstack([-geo.skew(v), np.eye(3)])
    cov = J @ np.asarray(result.covariance, dtype=float)[:6, :6] @ J.T
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    rms = float(np.sqrt(max(np.trace(cov), 0.0)))
    return {"distance_mm": float(distance_mm), "sd_mm": tuple(float(x) for x in sd), "rms_mm": rms,
            "expanded_k2_mm": K_EXPANDED * rms}


def _point_html(result: CalibrationResult, distance_mm: float) -> str:
    a = export.frames_of(result.transform_name)[0]
    distances = sorted({0.0, distance_mm / 2, float(distance_mm), 2.0 * distance_mm})
    rows, classes = [], []
    for d in distances:
        u = point_uncertainty(result, d)
        rows.append([f"{d:g}", *(_n(x) for x in u["sd_mm"]), _n(u["rms_mm"]), f"<b>{_n(u['expanded_k2_mm'])}</b>"])
        classes.append("chosen" if d == distance_mm else "")
    chosen = point_uncertainty(result, distance_mm)
    return (f"<p>A point measured <b>{distance_mm:g} mm</b> from the sensor, along its line of sight, lands within "
            f"<b>{_n(chosen['expanded_k2_mm'])} mm</b> (3-D, k = 2) of where the calibration puts it, from the "
            f"transform's uncertainty alone (the chosen distance: <code>[report] point_distance_mm</code>). The robot's "
            "pose error and the sensor's noise at that pose come on top (the verdict's point error).</p>"
            + _table(["distance (mm)", f"1-sigma {a} x (mm)", f"1-sigma {a} y (mm)", f"1-sigma {a} z (mm)",
                      "RMS 3-D (mm)", "U 3-D, k = 2 (mm)"], rows, classes))


def _station_table(result: CalibrationResult, th: Thresholds) -> str:
    cons = result.diagnostics.get("station_consistency", {}) or {}
    per = result.residuals.per_station_rms_mm
    bad = inconsistent_stations(result, th)
    flagged_by_station: dict[str, int] = {}
    for f in result.flagged:
        flagged_by_station[f.station] = flagged_by_station.get(f.station, 0) + 1
    labels = list(dict.fromkeys(list(per) + list(cons) + list(flagged_by_station)))
    rows, classes = [], []
    for label in labels:
        c = cons.get(label, {})
        status = '<span class="dot red"></span>inconsistent' if label in bad else '<span class="dot green"></span>ok'
        if label not in per:
            status = '<span class="dot red"></span>not used'
        rows.append([_e(label), str(c.get("n_profiles", "&ndash;")), _n(per.get(label)), _n(c.get("rms_mm")),
                     _n(c.get("max_mm")), str(flagged_by_station.get(label, 0)), status])
        classes.append("bad" if label in bad or label not in per else "")
    return (_table(["station", "profiles", "residual RMS (mm)", "consistency RMS (mm)", "consistency max (mm)",
                    "flagged", "status"], rows, classes)
            + '<p class="muted">Consistency: within a station the robot only translates, so the sphere centre seen '
              "by the sensor must move exactly as the robot moved; RMS and max of the mismatch.</p>")


def _flagged_table(result: CalibrationResult) -> str:
    if not result.flagged:
        return "<p>No observation was flagged: every profile was used.</p>"
    rows = [[str(f.index), _e(f.station), f'<span class="reason">{_e(f.reason)}</span>'] for f in result.flagged]
    return _table(["observation", "station", "why it was left out"], rows, ["bad"] * len(rows))


def _validation_html(validation: Mapping[str, Any]) -> str:
    if not isinstance(validation, Mapping):
        raise InputError(f"validation must be a mapping of acceptance figures, got {type(validation).__name__}")
    columns: list[str] = []
    for value in validation.values():
        for key in (value if isinstance(value, Mapping) else {"value": None}):
            if key not in columns:
                columns.append(key)

    def cell(v):
        if isinstance(v, bool):
            return '<span class="dot green"></span>yes' if v else '<span class="dot red"></span>no'
        if isinstance(v, (int, float, np.floating)) and not isinstance(v, bool):
            return _n(float(v)) if isinstance(v, (float, np.floating)) else str(v)
        return "&ndash;" if v is None else _e(v)

    rows, classes = [], []
    for name, value in validation.items():
        row = value if isinstance(value, Mapping) else {"value": value}
        rows.append([_e(name)] + [cell(row.get(col)) for col in columns])
        failed = any(row.get(k) is False for k in ("passed", "pass", "ok", "accepted"))
        classes.append("bad" if failed else "")
    return _table(["figure"] + [_e(c) for c in columns], rows, classes)


def _positions_html(rows: Sequence[Mapping[str, Any]]) -> str:
    """The validation per position: one row per position and figure."""
    body, classes = [], []
    for r in rows:
        passed = r.get("passed")
        verdict_cell = {True: '<span class="dot green"></span>pass', False: '<span class="dot red"></span>FAIL',
                        None: "not judged"}[passed]
        mpe = r.get("MPE (mm)")
        body.append([_e(r.get("position", "")), _e(r.get("artefact", "")), _e(r.get("figure", "")),
                     _n(r.get("error (mm)")), "&ndash;" if mpe is None else _n(mpe), verdict_cell])
        classes.append("bad" if passed is False else "")
    return ("<h3>Per position</h3>"
            + _table(["position", "artefact", "figure", "error (mm)", "MPE (mm)", "verdict"], body, classes))


def _identity_html(result: CalibrationResult) -> str:
    """What was calibrated, by whom, when, from which files (the result's provenance)."""
    p = result.provenance or {}

    def device(kind: str) -> str:
        d = p.get(kind)
        if not isinstance(d, Mapping):
            return _e(d) if d else "&ndash;"
        parts = [f"<b>{_e(d.get('type') or '?')}</b>"]
        for key in ("manufacturer", "model", "serial_number", "firmware", "controller"):
            if d.get(key):
                parts.append(f"{key.replace('_', ' ')}: {_e(d[key])}")
        if not d.get("serial_number"):
            parts.append('<span class="muted">serial number not reported</span>')
        return "; ".join(parts)

    sphere = p.get("sphere") if isinstance(p.get("sphere"), Mapping) else {}
    radius = sphere.get("radius_mm", result.sphere_radius_mm)
    u = sphere.get("radius_uncertainty_mm_k2")
    cert = (f"radius {_n(radius)} mm" + (f", U = {_n(u)} mm (k = 2)" if u is not None else
                                          ' <span class="muted">(uncertainty not given: sphere.radius_uncertainty_mm)'
                                          "</span>")
            + (f"; certificate {_e(sphere['certificate'])}" if sphere.get("certificate") else ""))

    def sha(key: str, file_key: str) -> str:
        if not p.get(key):
            return "&ndash;"
        return f'<code class="hash">{_e(p[key])}</code><br><span class="muted">{_e(p.get(file_key) or "")}</span>'

    rows = [
        ["cell", _e(p.get("cell") or "&ndash;") if p.get("cell") else "&ndash;"],
        ["robot", device("robot")],
        ["sensor", device("sensor")],
        ["reference sphere", cert],
        ["operator", _e(p["operator"]) if p.get("operator") else "&ndash;"],
        ["calibrated", _e(p.get("calibrated_at") or "&ndash;")],
        ["software", _e(p.get("software") or f"spherecal {__version__}")],
        ["dataset (SHA-256)", sha("dataset_sha256", "dataset_file")],
        ["configuration (SHA-256)", sha("configuration_sha256", "configuration_file")],
    ]
    if p.get("simulated"):
        rows.append(["devices", "simulated cell"])
    return "<table>" + "".join(f'<tr><th>{k}</th><td class="text">{v}</td></tr>' for k, v in rows) + "</table>"


def _signature_html() -> str:
    """Lines to sign on paper: who calibrated, who approved, with dates."""
    return "".join(f'<div class="signature"><div><span>{who} (name)</span></div><div><span>Date</span></div>'
                   "<div><span>Signature</span></div></div>" for who in ("Calibrated by", "Approved by"))


def _details_html(result: CalibrationResult) -> str:
    d = result.diagnostics
    ref = d.get("refinement", {}) or {}
    noise = d.get("noise", {}) or {}
    tsr = d.get("two_step_vs_refined", {}) or {}
    rows = [
        ["method", _e(result.method)],
        ["variance factor (chi&sup2;/dof)", _n(result.variance_factor, 3)],
        ["refinement", f"{ref.get('iterations', '?')} iterations, converged: {ref.get('converged', '?')}"],
        ["information condition number", f"{ref.get('information_condition_number', float('nan')):.3g}"],
        ["orientations (stations)", str(d.get("orientations", "?"))],
        ["two-step vs refined", f"{_n(tsr.get('rotation_deg'))} deg, {_n(tsr.get('translation_mm'))} mm"],
        ["noise used (point / pose translation / pose rotation)",
         f"{_n(noise.get('point_noise_mm'))} mm / {_n(noise.get('pose_translation_noise_mm'))} mm / "
         f"{_n(noise.get('pose_rotation_noise_deg'))} deg"],
        ["residual max |e| / 95th percentile", f"{_n(result.residuals.max_abs_mm)} / {_n(result.residuals.p95_abs_mm)} mm"],
        ["provenance", _e(json.dumps(result.provenance, default=str))],
    ]
    return "<table>" + "".join(f'<tr><th>{k}</th><td class="text">{v}</td></tr>' for k, v in rows) + "</table>"


# --- the report ---------------------------------------------------------------------------------------
def write_report(
    solution,
    out_dir: str | Path,
    title: str = "spherecal calibration report",
    validation: Mapping[str, Any] | None = None,
    *,
    thresholds: Thresholds | None = None,
    filename: str = "report.html",
    verdict_override: Verdict | None = None,
    notes: Sequence[ExportNote] = (),
    validation_positions: Sequence[Mapping[str, Any]] | None = None,
    point_distance_mm: float = POINT_DISTANCE_MM,
) -> Path:
    """Write the HTML report of ``solution`` (a :class:`spherecal.estimation.Solution`)
    into ``out_dir`` (created if needed) as ``filename``, with its figures saved beside
    it as ``<stem>_<figure>.png`` (:data:`FIGURE_NAMES`). ``validation`` is an optional
    mapping ``{figure name: value or {column: value}}`` shown as a table (a row whose
    ``passed`` is False is marked). ``verdict_override``: the verdict to show (e.g. with
    the likely cause the runner found, or with the validation: ``assess.with_validation``),
    else the result's own. ``notes``: what the run's exporters say about using the result
    on the controller (:class:`ExportNote`, from ``ExportPlan.notes(result)``; the robot's
    own exporter first), shown under the transform. ``validation_positions``: the
    validation per position (``validation.position_rows``), shown under its figures.
    ``point_distance_mm``: the report gives the uncertainty of a point this far from the
    sensor. Returns the path of the HTML file. Overwrites an earlier report of the same
    name."""
    result = getattr(solution, "result", None)
    if not isinstance(result, CalibrationResult) or not hasattr(solution, "problem"):
        raise InputError(
            f"write_report needs the Solution returned by spherecal.estimation.solve, got {type(solution).__name__}"
        )
    if not filename.endswith(".html") or Path(filename).name != filename:
        raise InputError(f"filename {filename!r} must be a plain file name ending in .html")
    if isinstance(notes, (str, bytes)) or not all(isinstance(n, ExportNote) for n in notes):
        raise InputError("notes must be a sequence of spherecal.io.exporters.ExportNote")
    if validation is not None and not isinstance(validation, Mapping):
        raise InputError(f"validation must be a mapping of acceptance figures, got {type(validation).__name__}")
    if validation_positions is not None and (isinstance(validation_positions, (str, bytes, Mapping)) or not all(
            isinstance(r, Mapping) for r in validation_positions)):
        raise InputError("validation_positions must be a sequence of rows (mappings)")
    if not (isinstance(point_distance_mm, (int, float)) and np.isfinite(point_distance_mm) and point_distance_mm > 0):
        raise InputError(f"point_distance_mm must be a positive number of mm, got {point_distance_mm!r}")
    th = thresholds or Thresholds()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = filename[: -len(".html")]

    colours = _station_colours(list(solution.problem.station_labels)
                               + sorted({f.station for f in result.flagged} - set(solution.problem.station_labels)))
    has_profiles = bool((solution.problem.kinds == KIND_PROFILE).any())
    mapped_once: list = []

    def mapped() -> list[np.ndarray]:  # the points in the sphere frame, mapped once for every figure
        if not mapped_once:
            mapped_once.append(mapped_points(solution))
        return mapped_once[0]

    has_centres = len(_centre_rows(solution)) > 0
    makers = {
        "residuals_per_profile": (lambda: _fig_per_profile(solution, result, colours),
                                  "Residuals of every profile used, grouped by station; flagged observations "
                                  "(left out of the solution) are marked in red."),
        "residuals_per_centre": (lambda: _fig_per_centre(solution, result, colours),
                                 "The residual of every centre observation used (its length, mm), grouped by "
                                 "station; flagged observations are marked in red."),
        "residuals_per_station": (lambda: _fig_per_station(solution, result, colours),
                                  "Residuals per station. A station clearly wider than the others deserves a look."),
        "residual_histogram": (lambda: _fig_histogram(solution, result),
                               "All residuals. Solid: a normal curve with the residual RMS; dashed: with the sensor "
                               "point noise alone (the gap is the robot's pose noise). Heavy tails mean strays."),
        "residuals_along_line": (lambda: _fig_along_line(solution, result),
                                 "Residuals against the position along the laser line and against depth (distance "
                                 "from the sensor). The lines (mean and RMS per bin) use every point; the dots are "
                                 "a sample when there are many. A slope or a curve is a systematic error of the "
                                 "sensor (scale, tilt of the line) or of the sphere radius, not noise."),
        "residuals_on_sphere": (lambda: _fig_on_sphere(solution, result, mapped()),
                                "Every point at its direction from the fitted centre, coloured by its residual. "
                                "Noise looks like salt and pepper; a patch or a band of one colour is a bias "
                                "(a dirty or damaged area of the sphere, a reflection, a wrong radius)."),
        "sphere_3d": (lambda: _fig_sphere(solution, result, colours, mapped()),
                      "The fitted sphere (wireframe) and the profile points mapped into the sphere frame through "
                      "A_i X, coloured by station: they should lie on the sphere."),
    }
    if not has_profiles:
        del makers["residuals_per_profile"], makers["residuals_along_line"], makers["residuals_on_sphere"]
    if not has_centres:
        del makers["residuals_per_centre"]
    figures = {}
    for key, (make, caption) in makers.items():
        with matplotlib.rc_context({"text.parse_math": False}):  # labels are data: '$x$' is not mathtext
            png = _png(make())
        safeio.write_bytes(out / f"{stem}_{key}.png", png)
        figures[key] = (base64.b64encode(png).decode("ascii"), caption)

    def fig_html(key):
        if key not in figures:
            return ""
        data, caption = figures[key]
        return (f'<figure id="fig-{key}"><img alt="{_e(key.replace("_", " "))}" '
                f'src="data:image/png;base64,{data}"><figcaption>{_e(caption)}</figcaption></figure>')

    ver = verdict_override or verdict(result, th)
    items = advice(result, th)
    now = datetime.now(timezone.utc).isoformat(timespec="seconds")
    nav = ["verdict", "identity", "transform", "advice", "residuals", "sphere", "uncertainty", "stations", "flagged"]
    if validation is not None or validation_positions is not None:
        nav.append("validation")
    nav += ["details", "signature"]
    sections = [
        f"<h1>{_e(title)}</h1>",
        f'<p class="sub">{_e(result.mounting)} &middot; {_e(result.transform_name)} &middot; '
        f"{result.residuals.n_profiles_used} profiles"
        + (f" &middot; {result.residuals.n_centres_used} centre observations" if has_centres else "")
        + f" &middot; generated {now} by spherecal {_e(__version__)}</p>",
        "<nav>" + "".join(f'<a href="#{s}">{s}</a>' for s in nav) + "</nav>",
        _headline(result, ver, th, notes),
        '<section class="keep"><h2 id="identity">What was calibrated</h2>',
        _identity_html(result) + "</section>",
        '<h2 id="advice">What to do when something is off</h2>',
        _advice_html(items),
        '<section class="keep"><h2 id="residuals">Residuals</h2>',
        "<p>"
        + ("A residual is the in-plane distance (mm) of a profile point from the circle where the laser plane cuts "
           "the fitted sphere. " if has_profiles else "")
        + ("A centre observation's residual has three components (mm): a sphere centre's x, y and z from where "
           "the fit puts the centre; a circle's centre y and z, and its radius against the circle the laser plane "
           "cuts from the fitted sphere." if has_centres else "")
        + "</p>",
        fig_html("residuals_per_profile") + "</section>",
        fig_html("residuals_per_centre"),
        fig_html("residuals_per_station"),
        fig_html("residual_histogram"),
        fig_html("residuals_along_line"),
        fig_html("residuals_on_sphere"),
        '<section class="keep"><h2 id="sphere">The sphere and the mapped points</h2>',
        fig_html("sphere_3d") + "</section>",
        _interactive_html(solution, result, mapped()) if has_profiles else "",
        '<section class="keep"><h2 id="uncertainty">Uncertainties</h2>',
        _uncertainty_table(result) + "</section>",
        '<section class="keep"><h3 id="correlation">Correlations of the parameters</h3>',
        _correlation_html(result) + "</section>",
        '<section class="keep"><h3 id="point">A point at a distance from the sensor</h3>',
        _point_html(result, float(point_distance_mm)) + "</section>",
        '<h2 id="stations">Stations</h2>',
        _station_table(result, th),
        '<h2 id="flagged">Flagged observations</h2>',
        _flagged_table(result),
    ]
    if validation is not None or validation_positions is not None:
        sections += ['<section class="keep"><h2 id="validation">Validation</h2>',
                     (_validation_html(validation) if validation is not None else "") + "</section>"]
        if validation_positions is not None:
            sections.append('<section class="keep">' + _positions_html(validation_positions) + "</section>")
    sections += ['<h2 id="details">Details</h2>', _details_html(result),
                 '<section class="keep"><h2 id="signature">Sign-off</h2>',
                 _signature_html() + "</section>",
                 f"<footer>spherecal {_e(__version__)} &middot; conventions: docs/conventions.md &middot; "
                 "this report: docs/results.md</footer>"]

    template = Template(resources.files(__package__).joinpath("report.html").read_text(encoding="utf-8"))
    css = resources.files(__package__).joinpath("report.css").read_text(encoding="utf-8")
    page = template.substitute(title=_e(title), css=css, body="\n".join(sections), version=_e(__version__))
    path = out / filename
    safeio.write_text(path, page)
    return path
