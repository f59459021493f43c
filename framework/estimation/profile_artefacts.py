"""What a sensor does to a profile that can look like a robot's fault: clipping at the
edge of the field of view and coarse quantisation.

A profile whose values the sensor held at a limit (points piling at one extreme z or y),
which the field of view cut short (an end of the arc at the measuring range's limit or at
the line's edge), or whose depths lie on a coarse grid (z in steps of 0.05 mm) gives a
circle off the sphere's true one. Screening then finds it inconsistent with the robot's
moves, and the generic cause (a pose read at the wrong moment, a mis-paired shot) would
send a device author to the robot. :func:`profile_artefact` names the sensor's artefact
instead; :func:`name_profile_artefacts` puts it in the flags of a solve.

Only z is tested for a grid: a sensor may report y at its columns' fixed positions, a grid
that is exact. The field of view is the one the sensor type declares, as the dataset's
provenance records it (``provenance["fov"]``); without it, clipping is recognised only by
points piling at a limit.
"""

from __future__ import annotations

import numpy as np

from spherecal.core.field_of_view import SensorFieldOfView
from spherecal.core.models import Dataset, ObservationFlag

#: The causes screening gives a profile inconsistent with the others when it knows no better.
GENERIC_CAUSES = ("a pose read at the wrong moment or a mis-paired shot",
                  "a pose read at the wrong moment or a bad pairing")
#: Points at one extreme (within :data:`SAME_VALUE_MM`) that make a pile: at least this
#: many, this share of the profile and this many times the typical count per value.
PILE_MIN_POINTS = 3
PILE_MIN_SHARE = 0.02
PILE_OVER_TYPICAL = 3.0
SAME_VALUE_MM = 1e-5
#: A grid step smaller than this is the storage's resolution, not the sensor's quantisation.
MIN_GRID_STEP_MM = 0.005
#: Share of a profile's distinct z values that must lie on the grid (within
#: :data:`GRID_TOLERANCE` of a step) for it to count as quantised.
GRID_SHARE = 0.95
GRID_TOLERANCE = 0.02
#: An end of the arc this close to a limit of the field of view (mm), and nearer the
#: circle's middle than this share of its radius (not at its rim), was cut by it.
EDGE_TOLERANCE_MM = 0.5
RIM_SHARE = 0.95
#: ... and only when the arc left spans less than this share of the circle's diameter.
CUT_SPAN_SHARE = 0.6


def _pile(values: np.ndarray, high_end: bool = True) -> tuple[float, int] | None:
    """(value, count) of the larger pile of points at the extreme values (the lowest
    only, without ``high_end``), or None."""
    rounded = np.round(values / SAME_VALUE_MM).astype(np.int64)
    keys, counts = np.unique(rounded, return_counts=True)
    typical = float(np.median(counts))
    best = None
    for k in (0, len(keys) - 1) if high_end else (0,):
        c = int(counts[k])
        if c >= max(PILE_MIN_POINTS, PILE_MIN_SHARE * len(values), PILE_OVER_TYPICAL * typical):
            if best is None or c > best[1]:
                best = (float(keys[k]) * SAME_VALUE_MM, c)
    return best


def grid_step_mm(values) -> float | None:
    """The step of the grid the values lie on (mm), or None when they do not lie on one
    coarser than :data:`MIN_GRID_STEP_MM`."""
    v = np.unique(np.round(np.asarray(values, dtype=float) / SAME_VALUE_MM)) * SAME_VALUE_MM
    if len(v) < 5:
        return None
    d = np.diff(v)
    step = float(d.min())
    if step < MIN_GRID_STEP_MM:
        return None
    k = (v - v[0]) / step
    on_grid = np.abs(k - np.round(k)) <= GRID_TOLERANCE
    return step if on_grid.mean() >= GRID_SHARE else None


def _circle_yz(points: np.ndarray) -> tuple[float, float, float] | None:
    """(y, z, radius) of the circle through the points (algebraic least squares), mm."""
    y, z = points[:, 0], points[:, 1]
    A = np.column_stack([2.0 * y, 2.0 * z, np.ones(len(y))])
    sol, *_ = np.linalg.lstsq(A, y * y + z * z, rcond=None)
    r2 = sol[2] + sol[0] ** 2 + sol[1] ** 2
    return (float(sol[0]), float(sol[1]), float(np.sqrt(r2))) if np.isfinite(r2) and r2 > 0 else None


def _cut_by_field_of_view(points: np.ndarray, fov: SensorFieldOfView) -> str | None:
    """Where an end of the arc lies at a limit of ``fov`` short of the circle's rim (the
    arc goes on beyond it), said; else None."""
    y, z = points[:, 0], points[:, 1]
    circle = _circle_yz(points)
    if circle is None:
        return None
    yc, _, rho = circle
    if np.ptp(y) >= CUT_SPAN_SHARE * 2.0 * rho:  # most of the arc is there: its circle holds
        return None
    order = np.argsort(y)
    for end in (order[0], order[-1]):
        if abs(y[end] - yc) >= RIM_SHARE * rho:  # the arc ends at its rim, not at the limit
            continue
        if z[end] - fov.z_far_mm <= EDGE_TOLERANCE_MM:
            return f"its arc ends at z = {z[end]:.3f} mm, the far end of the sensor's measuring range " \
                   f"(z_far_mm = {fov.z_far_mm:g})"
        if fov.z_near_mm - z[end] <= EDGE_TOLERANCE_MM:
            return f"its arc ends at z = {z[end]:.3f} mm, the near end of the sensor's measuring range " \
                   f"(z_near_mm = {fov.z_near_mm:g})"
        half = fov.width_at_mm(float(np.clip(z[end], fov.z_far_mm, fov.z_near_mm))) / 2.0
        if half - abs(y[end]) <= EDGE_TOLERANCE_MM:
            return f"its arc ends at y = {y[end]:.3f} mm, the edge of the laser line ({2 * half:.1f} mm wide there)"
    return None


def profile_artefact(points_mm, fov: SensorFieldOfView | None = None) -> str | None:
    """The sensor's artefact in a profile ((N, 2) points (y, z), mm), said for the user:
    clipped (values held at a limit, or the arc cut by ``fov``) or quantised (z on a
    coarse grid); None when neither shows."""
    p = np.asarray(points_mm, dtype=float).reshape(-1, 2)
    if len(p) < PILE_MIN_POINTS:
        return None
    step = grid_step_mm(p[:, 1])
    # on a grid, the flat top of the arc fills its highest step: only the far end, where
    # the arc is steep, shows a pile there
    for axis, name, high_end in ((1, "z", step is None), (0, "y", True)):
        pile = _pile(p[:, axis], high_end)
        if pile is not None:
            return (f"the profile is clipped at the edge of the sensor's field of view: {pile[1]} of {len(p)} points "
                    f"pile at {name} = {pile[0]:.3f} mm (values held at the limit); the sensor should leave out "
                    "points beyond its range, and the sweep keep the sphere inside it")
    if fov is not None:
        cut = _cut_by_field_of_view(p, fov)
        if cut is not None:
            return (f"the profile is clipped at the edge of the sensor's field of view: {cut}, so part of the "
                    "sphere's arc is missing; keep the sphere inside the field of view (acquisition.sweep)")
    if step is not None:
        return (f"the profile is coarsely quantised: its z values lie on a {step:.4g} mm grid, which moves a fitted "
                "circle by up to a fraction of a step; report depths at the sensor's full resolution")
    return None


def _field_of_view(dataset: Dataset) -> SensorFieldOfView | None:
    given = dataset.provenance.get("fov") if isinstance(dataset.provenance, dict) else None
    try:
        return SensorFieldOfView.model_validate(given) if isinstance(given, dict) else None
    except ValueError:
        return None


def name_profile_artefacts(flags: list[ObservationFlag], dataset: Dataset) -> list[ObservationFlag]:
    """``flags`` with the sensor's artefact named (:func:`profile_artefact`) in each flag
    of a profile that shows one: in place of the generic cause (:data:`GENERIC_CAUSES`),
    else after the reason. The field of view is the dataset's
    (``provenance["fov"]``), when it records one."""
    fov = _field_of_view(dataset)
    by_index = {o.index: o for o in dataset.observations}
    out = []
    for f in flags:
        obs = by_index.get(f.index)
        artefact = None if obs is None or obs.profile is None else profile_artefact(obs.profile.points_mm, fov)
        if artefact is None:
            out.append(f)
            continue
        generic = next((g for g in GENERIC_CAUSES if g in f.reason), None)
        reason = (f.reason.replace(generic, f"{artefact} (more likely than {generic})") if generic is not None
                  else f"{f.reason}; likely cause: {artefact}")
        out.append(f.model_copy(update={"reason": reason}))
    return out


def artefacts_note(dataset: Dataset) -> str | None:
    """How many of the dataset's profiles show the sensor's artefact, with the first one's,
    for the message of a solve that failed; None when none does."""
    fov = _field_of_view(dataset)
    found = [(o.index, a) for o in dataset.observations if o.profile is not None
             for a in [profile_artefact(o.profile.points_mm, fov)] if a is not None]
    if not found:
        return None
    index, first = found[0]
    return (f"{len(found)} of {len(dataset.observations)} profiles show the sensor's doing, not the robot's "
            f"(observation {index}: {first})")
