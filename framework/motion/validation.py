"""Validation with the calibrated system: sweeps at views other than the calibration's,
points mapped through the calibrated transform into the frame the artefacts are fixed
in, and the acceptance figures of docs/validation-and-scanning.md (P_F, P_S, SD, F) plus
the spread of the sphere centres fitted from the different views (which catches a
translation error that no single view can show)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from spherecal.core import geometry as geo
from spherecal.io.runlog import progress_log
from spherecal.motion.acquisition import Progress, Target, move_and_shoot, targets_from_poses
from spherecal.config import AcquisitionConfig, SphereConfig, SweepSite, ValidationConfig
from spherecal.core.errors import ConfigError, DegenerateDataError
from spherecal.core.mapping import frame_from_sensor_stack, map_profile_list, rt_from_poses
from spherecal.core.metrology import (
    AcceptanceReport,
    MaximumPermissibleErrors,
    acceptance_report,
    flatness_error,
    probing_errors,
    sphere_spacing_error,
)
from spherecal.core.models import SPHERE_FRAME, MountingMode, Pose
from spherecal.motion.planning import SweepPlan, plan_stations, site_offset_mm

if TYPE_CHECKING:  # pragma: no cover
    from spherecal.devices.contract import SensorFieldOfView

_LOG = progress_log("validation")  # the default ``log``: logger spherecal.validation


@dataclass(frozen=True)
class Sweep:
    """One validation sweep: a group label, what it looks at, and its targets."""

    label: str
    kind: str  # "sphere", "ball_a", "ball_b", "flat"
    targets: list[Target]


def _sweep(acq: AcquisitionConfig, mounting: MountingMode, X: Pose, label: str, kind: str, centre,
           half_length_mm: float, site: SweepSite, n: int, first_index: int,
           field_of_view: "SensorFieldOfView | None", sensor_type: str | None) -> Sweep:
    R_ref = geo.matrix_from_quat_wxyz(acq.reference_flange_quaternion_wxyz)
    if field_of_view is None:
        raise ConfigError(f"sensor type {sensor_type!r} declares no field of view: validation plans its "
                          "sweeps in it (give it in the sensor plugin, or [simulation.fov] for a simulated run)")
    # a sphere's centre at the sensor's sweep standoff, a flat's surface in the middle of the range
    standoff = field_of_view.sweep_standoff_z_mm if kind != "flat" else field_of_view.middle_z_mm
    offset = site_offset_mm(site.offset_mm, site.offset_percent, field_of_view, standoff, f"validation ({label})")
    plan = SweepPlan(profiles_per_station=n, sweep_fraction=0.9, lateral_amplitude_mm=0.0,
                     standoff_z_mm=standoff,
                     station_offsets_mm=[offset], tilts_deg=[site.tilt_deg])
    (_, poses), = plan_stations(mounting, X, centre, half_length_mm / 0.9, plan, R_ref)
    return Sweep(label, kind, targets_from_poses(poses, label, first_index, acq.approach_speed_mm_s, acq.speed_mm_s))


def plan_validation(v: ValidationConfig, acq: AcquisitionConfig | None, mounting: MountingMode, X: Pose,
                    sphere: SphereConfig, field_of_view: "SensorFieldOfView | None" = None,
                    sensor_type: str | None = None) -> list[Sweep]:
    """The validation sweeps of ``v``, planned with the calibrated transform ``X`` in the
    sensor's ``field_of_view`` (a sphere's centre at its ``sweep_standoff_z_mm``, a flat
    in the middle of its range), with the reference orientation and speeds of ``acq``
    (whose rough sphere centre places the sphere's sweeps); ``sensor_type`` names the
    sensor in the message when there is no field of view."""
    n = v.profiles_per_sweep
    r = sphere.radius_mm
    centre = acq.sphere_centre_mm if acq else None
    sweeps: list[Sweep] = []
    count = lambda: sum(len(s.targets) for s in sweeps)  # noqa: E731

    def add(label: str, kind: str, centre, half_length_mm: float, site: SweepSite) -> None:
        sweeps.append(_sweep(acq, mounting, X, label, kind, centre, half_length_mm, site, n, count(), field_of_view,
                             sensor_type))

    if centre is not None:
        for k, site in enumerate(v.sphere_positions):
            add(f"P{k + 1}", "sphere", centre, 0.9 * r, site)
    if v.ball_bar is not None:
        bb = v.ball_bar
        for k, site in enumerate(bb.positions):
            other = bb.positions[(k + 1) % len(bb.positions)]
            add(f"B{k + 1}", "ball_a", bb.centre_a_mm, 0.9 * bb.ball_radius_mm, site)
            add(f"B{k + 1}", "ball_b", bb.centre_b_mm, 0.9 * bb.ball_radius_mm, other)
    if v.flat is not None:
        for k, site in enumerate(v.flat.positions):
            add(f"F{k + 1}", "flat", v.flat.centre_mm, v.flat.sweep_length_mm / 2, site)
    if not sweeps:
        raise DegenerateDataError("nothing to validate: give [acquisition] sphere_centre_mm, [validation.ball_bar] or [validation.flat]")
    return sweeps


@dataclass
class Measured:
    """Poses and profiles of one sweep."""

    sweep: Sweep
    poses: list[Pose] = field(default_factory=list)
    profiles: list[np.ndarray] = field(default_factory=list)


def measure(robot, sensor, sweeps: list[Sweep], acq: AcquisitionConfig, log: Callable[[str], None] = _LOG,
            progress: Progress | None = None, on_shot: Callable | None = None) -> list[Measured]:
    """Move through every sweep and take its profiles (poses read before and after, with
    the checks and retries of ``acq``)."""
    total = sum(len(s.targets) for s in sweeps)
    progress = progress or Progress(total)
    out, done = [], 0
    for sw in sweeps:
        m = Measured(sw)
        for t in sw.targets:
            pose, _joints, profile, _ = move_and_shoot(robot, sensor, t, acq, log)
            if profile is not None:
                m.poses.append(pose)
                m.profiles.append(profile.points_mm)
                if on_shot is not None:
                    on_shot(sw, t, pose, profile)
            done += 1
            progress.update(done, sw.label)
        out.append(m)
    return out


def points_in_object_frame(mounting: str, X: Pose, poses: list[Pose], profiles: list[np.ndarray]) -> np.ndarray:
    """All points of a sweep mapped through the calibrated X into the frame the
    artefacts are fixed in (base in eye-in-hand, flange in eye-to-hand), (N, 3) mm."""
    R0, t0 = rt_from_poses(poses)
    R, t = frame_from_sensor_stack(mounting, R0, t0, X, SPHERE_FRAME[mounting])
    pts, _ = map_profile_list(R, t, profiles)
    return pts


#: What each figure measures against: ``relative`` ones come from one sweep each (a sphere's
#: form and size, a flat's form) and do not depend on where the robot thinks it is, only
#: on how its error changes along the sweep; ``absolute`` ones set positions measured
#: from poses far apart against each other in the artefacts' frame (the ball bar's
#: length, the spread of the sphere centres fitted from different views), so they
#: include the robot's own error between those poses.
FIGURE_SCOPE = {"P_F": "relative", "P_S": "relative", "F": "relative", "SD": "absolute", "centre spread": "absolute"}


def scope_note(mounting: MountingMode) -> str:
    """What ``absolute`` and ``relative`` mean in the validation table, for ``mounting``."""
    return (f"absolute: positions measured from poses far apart, set against each other in the {SPHERE_FRAME[mounting]} "
            "frame through the robot's poses: they include the robot's own error; relative: from one sweep each, "
            "independent of where the robot thinks it is (only how its error changes along the sweep)")


@dataclass
class ValidationOutcome:
    report: AcceptanceReport
    centre_spread_mm: float | None
    centre_spread_passed: bool | None
    centres_mm: dict[str, list[float]]
    mpe_centre_spread_mm: float | None = None
    #: the verdict with this validation (``report.assess.with_validation``), set by ``app.validate``
    verdict: object | None = None
    #: the transform validated (``transform_name``, e.g. flange_from_sensor) and where it came from (a
    #: result.json, --transform, --controller-frame), set by ``app.validate``
    transform: Pose | None = None
    transform_name: str | None = None
    transform_source: str | None = None
    #: the files ``app.validate`` wrote: the figures (``validation-<time>.json``) and the report's new version
    #: (``report-<n>.html``; None when none was written)
    figures_path: Path | None = None
    report_path: Path | None = None
    #: the likely cause of a failure and its remedy when named (``report.validation_advice.robot_cause``)
    cause: object | None = None

    @property
    def passed(self) -> bool:
        verdicts = [self.report.passed, self.centre_spread_passed]
        return all(v is not False for v in verdicts)

    def table(self) -> dict[str, dict]:
        """Rows for the HTML report and the console: one per figure."""
        rows = {}
        for v in self.report.verdicts:
            if v.n_positions:
                rows[v.figure] = {"max error (mm)": v.max_error_mm, "worst position": v.worst_position,
                                  "positions": v.n_positions, "MPE (mm)": v.mpe_mm, "passed": v.passed}
        if self.centre_spread_mm is not None:
            rows["centre spread"] = {"max error (mm)": self.centre_spread_mm, "worst position": None,
                                     "positions": len(self.centres_mm), "MPE (mm)": self.mpe_centre_spread_mm, "passed": self.centre_spread_passed}
        for name, row in rows.items():
            row["scope"] = FIGURE_SCOPE.get(name)
        return rows


def _judge(value: float, mpe: float | None) -> bool | None:
    return None if mpe is None else abs(value) <= mpe


def position_rows(outcome: "ValidationOutcome") -> list[dict]:
    """One row per position and figure, for the report's per-position table and
    validation.json: ``position``, ``artefact``, ``figure``, ``error (mm)`` (signed for
    P_S, SD), ``MPE (mm)`` and ``passed`` (None: no MPE). A sphere position has P_F, P_S
    and the distance of its fitted centre from the mean of the views' (judged against
    ``mpe_centre_spread_mm``)."""
    rep, mpe = outcome.report, outcome.report.mpe
    rows: list[dict] = []

    def row(position, artefact, figure, value, limit):
        rows.append({"position": position, "artefact": artefact, "figure": figure, "error (mm)": float(value),
                     "MPE (mm)": limit, "passed": _judge(value, limit)})

    mean = np.mean(list(outcome.centres_mm.values()), axis=0) if len(outcome.centres_mm) >= 2 else None
    for pr in rep.probing:
        row(pr.position, "sphere", "P_F", pr.probing_form_error_mm, mpe.probing_form_mm)
        row(pr.position, "sphere", "P_S", pr.probing_size_error_mm, mpe.probing_size_mm)
        if mean is not None and pr.position in outcome.centres_mm:
            off = float(np.linalg.norm(np.subtract(outcome.centres_mm[pr.position], mean)))
            row(pr.position, "sphere", "centre from mean", off, outcome.mpe_centre_spread_mm)
    for sd in rep.sphere_spacing:
        row(sd.position, "ball bar", "SD", sd.sphere_spacing_error_mm, mpe.sphere_spacing_mm)
    for f in rep.flatness:
        row(f.position, "flat", "F", f.flatness_error_mm, mpe.flatness_mm)
    return rows


def evaluate(v: ValidationConfig, mounting: MountingMode, X: Pose, sphere: SphereConfig,
             measured: list[Measured]) -> ValidationOutcome:
    """The acceptance figures from the measured sweeps, mapped through ``X``, against
    the MPEs of ``v`` and the certified radius of ``sphere``."""
    probing, spacing, flatness = [], [], []
    centres: dict[str, list[float]] = {}
    balls: dict[str, dict[str, np.ndarray]] = {}
    for m in measured:
        if not m.profiles:
            raise DegenerateDataError(f"validation sweep {m.sweep.label} ({m.sweep.kind}) saw nothing: check its position")
        pts = points_in_object_frame(mounting, X, m.poses, m.profiles)
        if m.sweep.kind == "sphere":
            pr = probing_errors(pts, 2 * sphere.radius_mm, position=m.sweep.label)
            probing.append(pr)
            centres[m.sweep.label] = list(pr.fit.centre_mm)
        elif m.sweep.kind in ("ball_a", "ball_b"):
            balls.setdefault(m.sweep.label, {})[m.sweep.kind] = pts
        else:
            flatness.append(flatness_error(pts, position=m.sweep.label))
    for label, pair in balls.items():
        spacing.append(sphere_spacing_error(pair["ball_a"], pair["ball_b"], v.ball_bar.certified_distance_mm, position=label))
    report = acceptance_report(MaximumPermissibleErrors(**v.mpe.model_dump()), probing=probing, sphere_spacing=spacing, flatness=flatness)
    spread = passed = None
    if len(centres) >= 2:
        c = np.array(list(centres.values()))
        spread = float(np.linalg.norm(c - c.mean(axis=0), axis=1).max())
        passed = None if v.mpe_centre_spread_mm is None else spread <= v.mpe_centre_spread_mm
    return ValidationOutcome(report, spread, passed, centres, v.mpe_centre_spread_mm)


def format_outcome(outcome: ValidationOutcome, mounting: MountingMode | None = None) -> str:
    """The validation table (each figure with its scope, absolute or relative, explained
    under it for ``mounting``) and the figures per position, as the terminal prints them."""
    lines = [f"{'figure':14s} {'max error (mm)':>15s} {'worst':>6s} {'MPE (mm)':>9s}  {'verdict':10s}  scope"]
    for name, row in outcome.table().items():
        mpe = "-" if row["MPE (mm)"] is None else f"{row['MPE (mm)']:.4f}"
        verdict = {True: "pass", False: "FAIL", None: "not judged"}[row["passed"]]
        lines.append(f"{name:14s} {row['max error (mm)']:15.4f} {row['worst position'] or '-':>6s} {mpe:>9s}  "
                     f"{verdict:10s}  {row['scope'] or '-'}")
    if mounting is not None:
        lines.append(f"  ({scope_note(mounting)})")
    for pr in outcome.report.probing:
        lines.append(f"  {pr.position}: P_F {pr.probing_form_error_mm:.4f} mm, P_S {pr.probing_size_error_mm:+.4f} mm "
                     f"({pr.fit.n_points_used} points used, {pr.fit.n_points_dropped} dropped)")
    for sd in outcome.report.sphere_spacing:
        lines.append(f"  {sd.position}: SD {sd.sphere_spacing_error_mm:+.4f} mm "
                     f"({sd.fit_a.n_points_used}+{sd.fit_b.n_points_used} points used, "
                     f"{sd.fit_a.n_points_dropped + sd.fit_b.n_points_dropped} dropped)")
    for f in outcome.report.flatness:
        lines.append(f"  {f.position}: F {f.flatness_error_mm:.4f} mm ({f.fit.n_points_used} points used, "
                     f"{f.fit.n_points_dropped} dropped)")
    return "\n".join(lines)
