"""The keep-out check of a motion plan, before anything moves: the sensor's body against
the reference sphere and its stand (eye-in-hand) or stem (eye-to-hand), at every planned
target and along every straight move between them (the geometry:
:mod:`spherecal.core.keep_out`). Any plan of targets (calibration, validation, scan)
takes it; it needs no device, and from where the arm stands it checks the first move too."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from spherecal.core.keep_out import Closest, KeepOutGeometry, closest_along_moves, closest_at_poses
from spherecal.core.models import Pose

#: The longest way any point of the moving body (or sphere) travels between two poses
#: checked along a move, mm.
KEEP_OUT_STEP_MM = 1.0
#: Problems listed one by one; the rest are counted.
MAX_LISTED = 8


@dataclass(frozen=True)
class KeepOut:
    """A run's keep-out check: the geometry, the least gap allowed (``clearance_mm``),
    where the body box comes from (``body_source``, for messages) and what to change in
    this command's configuration when a target (``fix_target``) or a move between
    targets (``fix_move``) comes too close."""

    geometry: KeepOutGeometry
    clearance_mm: float
    body_source: str
    fix_target: str = ""
    fix_move: str = ""
    step_mm: float = KEEP_OUT_STEP_MM

    @property
    def rod_name(self) -> str:
        """What holds the sphere: ``stand`` (eye-in-hand) or ``stem`` (eye-to-hand)."""
        return self.geometry.rod_name

    def describe(self) -> str:
        """The geometry checked, in the words of the configuration."""
        g = self.geometry
        lo, hi = g.body.min_mm, g.body.max_mm
        box = ", ".join(f"{a} {lo[i]:g}..{hi[i]:g}" for i, a in enumerate("xyz"))
        if g.mounting == "eye_to_hand":
            rod = f"its stem a rod of radius {g.rod_radius_mm:g} mm from its centre to the flange"
        elif g.rod_length_mm > 0:
            rod = f"its stand a rod of radius {g.rod_radius_mm:g} mm reaching {g.rod_length_mm:g} mm down from its centre"
        else:
            rod = "no stand"
        return (f"the sensor's body the box {box} mm in the sensor frame ({self.body_source}), the sphere of radius "
                f"{g.sphere_radius_mm:g} mm at acquisition.sphere_centre_mm, {rod} ([keep_out] stand_radius_mm, "
                "stand_length_mm, sensor_body)")


@dataclass
class KeepOutFinding:
    """What the check found: ``problems`` (one line each, empty when the plan keeps its
    distance), the closest approach and where, the moves and poses checked, the time, and
    whether the first move from where the arm stands was among them (``from_arm``)."""

    problems: list[str] = field(default_factory=list)
    closest: Closest | None = None
    closest_where: str = ""
    moves: int = 0
    poses: int = 0
    seconds: float = 0.0
    from_arm: bool = False

    def summary(self, keep_out: KeepOut) -> str:
        """One line: the closest approach, where, and what was checked. A check from where
        the arm stands (with the devices open, after the plan's own check) says so: it has
        one move more, and its poses along it."""
        if self.closest is None:
            return "keep-out: nothing to check"
        head = "keep-out, from where the arm stands (its first move too)" if self.from_arm else "keep-out"
        return (f"{head}: the sensor's body stays {self.closest.clearance_mm:.1f} mm or more from the sphere and its "
                f"{keep_out.rod_name} (clearance {keep_out.clearance_mm:g} mm; closest "
                f"{self.closest_where}, to the {self.closest.part}); {self.moves} moves, {self.poses} poses checked in "
                f"{self.seconds:.2f} s")


def _target_name(t) -> str:
    return f"target {t.index} (station {t.station})"


def _gap_text(c: Closest) -> str:
    if c.clearance_mm < 0:
        return f"the sensor's body overlaps the {c.part} by {-c.clearance_mm:.1f} mm"
    return f"the sensor's body comes within {c.clearance_mm:.1f} mm of the {c.part}"


def _at(c: Closest) -> str:
    return f"flange at {np.round(c.flange_mm, 1).tolist()} mm"


def _near_targets(targets: list, at_targets: list[Closest], limit: float) -> list[str]:
    """One line per station with targets nearer than ``limit``: which, and the worst."""
    lines = []
    for station in dict.fromkeys(t.station for t in targets):
        ks = [k for k, t in enumerate(targets) if t.station == station]
        near = [k for k in ks if at_targets[k].clearance_mm < limit]
        if not near:
            continue
        worst = min(near, key=lambda k: at_targets[k].clearance_mm)
        which = (_target_name(targets[worst]) if len(near) == 1 else
                 f"targets {', '.join(str(targets[k].index) for k in near)} ({len(near)} of {len(ks)}) of station "
                 f"{station}, worst target {targets[worst].index}")
        lines.append(f"{which}, {_at(at_targets[worst])}: {_gap_text(at_targets[worst])}")
    return lines


def check_keep_out(targets: list, keep_out: KeepOut, start: Pose | None = None) -> KeepOutFinding:
    """Every planned target of ``targets`` (each with ``index``, ``station``, ``pose``:
    ``base_from_flange``) and every straight move between consecutive ones, and with
    ``start`` (where the arm stands) the first move too, against ``keep_out``: a problem
    line for each target and each move (from its closest pose) nearer than the clearance.
    A move whose end target is itself too near is left to that target's line."""
    began = time.perf_counter()
    finding = KeepOutFinding(from_arm=start is not None)
    if not targets:
        return finding
    g, limit = keep_out.geometry, keep_out.clearance_mm
    at_targets = closest_at_poses(g, [t.pose for t in targets])
    poses = ([start] if start is not None else []) + [t.pose for t in targets]
    along, finding.poses = closest_along_moves(g, poses, keep_out.step_mm)
    finding.moves = len(along)
    target_names = [_target_name(t) for t in targets]
    names = (["where the arm stands"] if start is not None else []) + target_names
    # a move whose end is a target too near is left to that target's line (the start is no target)
    near_end = ([False] if start is not None else []) + [c.clearance_mm < limit for c in at_targets]
    candidates = [(c, target_names[k]) for k, c in enumerate(at_targets)]
    finding.problems += _near_targets(targets, at_targets, limit)
    for k, c in enumerate(along):
        what = (f"the first move, from where the arm stands to {names[k + 1]}" if start is not None and k == 0
                else f"the move from {names[k]} to {names[k + 1]}")
        candidates.append((c, f"{what}, {c.fraction:.0%} of the way"))
        if c.clearance_mm < limit and not (near_end[k] or near_end[k + 1]):
            finding.problems.append(f"{what}, {c.fraction:.0%} of the way, {_at(c)}: {_gap_text(c)}")
    # (a move that comes no nearer than its end target is not named as the closest)
    finding.closest, finding.closest_where = min(candidates, key=lambda item: round(item[0].clearance_mm, 6))
    finding.seconds = time.perf_counter() - began
    return finding


def keep_out_message(what: str, finding: KeepOutFinding, keep_out: KeepOut) -> str:
    """The refusal of a plan that comes too near: the lines, what to change, the geometry."""
    lines = finding.problems[:MAX_LISTED]
    if len(finding.problems) > MAX_LISTED:
        lines.append(f"... and {len(finding.problems) - MAX_LISTED} more")
    fixes = []
    if any(p.startswith(("target ", "targets ")) for p in finding.problems) and keep_out.fix_target:
        fixes.append(f"At a target: {keep_out.fix_target}.")
    if any(p.startswith("the move ") for p in finding.problems) and keep_out.fix_move:
        fixes.append("On a move between targets: the straight move between them brings the sensor's body and the "
                     f"sphere together on its way; {keep_out.fix_move}.")
    if any(p.startswith("the first move") for p in finding.problems):
        fixes.append("On the first move: jog the arm clear of the sphere, near the first target, and start again.")
    return (f"the {what} brings the sensor's body within keep_out.clearance_mm = {keep_out.clearance_mm:g} mm of the "
            f"sphere or its {keep_out.rod_name}; nothing was "
            "moved:\n  " + "\n  ".join(lines) + "\n" + " ".join(fixes)
            + f" The check takes {keep_out.describe()}: if that is not the cell, give the cell's.")
