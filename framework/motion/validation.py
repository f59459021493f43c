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
    COVERAGE_FACTOR,
    AcceptanceReport,
    MaximumPermissibleErrors,
    ShotNoise,
    acceptance_report,
    exceeds,
    flatness_error,
    probing_errors,
    sphere_spacing_error,
)
from spherecal.core.models import SPHERE_FRAME, MountingMode, Pose
from spherecal.motion.planning import SweepPlan, plan_stations, site_offset_mm, sphere_standoff_z_mm

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
    radius_mm = half_length_mm / 0.9  # the sphere's or the ball's (swept over 0.9 of it)
    standoff = sphere_standoff_z_mm(field_of_view, radius_mm) if kind != "flat" else field_of_view.middle_z_mm
    offset = site_offset_mm(site.offset_mm, site.offset_percent, field_of_view, standoff, f"validation ({label})")
    plan = SweepPlan(profiles_per_station=n, sweep_fraction=0.9, lateral_amplitude_mm=0.0,
                     standoff_z_mm=standoff,
                     station_offsets_mm=[offset], tilts_deg=[site.tilt_deg])
    (_, poses), = plan_stations(mounting, X, centre, radius_mm, plan, R_ref)
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
    return _mapped(mounting, X, poses, profiles)[0]


def _mapped(mounting: str, X: Pose, poses: list[Pose], profiles: list[np.ndarray]):
    """:func:`points_in_object_frame`, with the shot (profile) of each point and each
    shot's flange origin in that frame (about which a pose's rotation error turns it)."""
    R0, t0 = rt_from_poses(poses)
    R, t = frame_from_sensor_stack(mounting, R0, t0, X, SPHERE_FRAME[mounting])
    pts, shot = map_profile_list(R, t, profiles)
    origins = t0 if SPHERE_FRAME[mounting] == "base" else np.zeros_like(t0)
    return pts, shot, origins


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
    #: the noise P_S was judged with (the sensor's points, the robot's shots), None: not known
    noise: ShotNoise | None = None
    #: the laser line's width where the sphere's sweeps put its centre, mm (None: not known)
    line_width_mm: float | None = None
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
                if v.uncertainty_mm is not None:
                    rows[v.figure]["U (mm, k = 2)"] = v.uncertainty_mm
        if self.centre_spread_mm is not None:
            rows["centre spread"] = {"max error (mm)": self.centre_spread_mm, "worst position": None,
                                     "positions": len(self.centres_mm), "MPE (mm)": self.mpe_centre_spread_mm, "passed": self.centre_spread_passed}
        for name, row in rows.items():
            row["scope"] = FIGURE_SCOPE.get(name)
        return rows


def _judge(value: float, mpe: float | None, uncertainty_mm: float | None = None) -> bool | None:
    return None if mpe is None else not exceeds(value, mpe, uncertainty_mm)


def _expanded(std_mm: float | None) -> float | None:
    return None if std_mm is None else COVERAGE_FACTOR * std_mm


def position_rows(outcome: "ValidationOutcome") -> list[dict]:
    """One row per position and figure, for the report's per-position table and
    validation.json: ``position``, ``artefact``, ``figure``, ``error (mm)`` (signed for
    P_S, SD), ``MPE (mm)`` and ``passed`` (None: no MPE); P_S with its ``U (mm, k = 2)``
    when known, judged with it. A sphere position has P_F, P_S and the distance of its
    fitted centre from the mean of the views' (judged against ``mpe_centre_spread_mm``)."""
    rep, mpe = outcome.report, outcome.report.mpe
    rows: list[dict] = []

    def row(position, artefact, figure, value, limit, uncertainty_mm=None):
        rows.append({"position": position, "artefact": artefact, "figure": figure, "error (mm)": float(value),
                     "MPE (mm)": limit, "passed": _judge(value, limit, uncertainty_mm)})
        if uncertainty_mm is not None:
            rows[-1]["U (mm, k = 2)"] = uncertainty_mm

    mean = np.mean(list(outcome.centres_mm.values()), axis=0) if len(outcome.centres_mm) >= 2 else None
    for pr in rep.probing:
        row(pr.position, "sphere", "P_F", pr.probing_form_error_mm, mpe.probing_form_mm)
        row(pr.position, "sphere", "P_S", pr.probing_size_error_mm, mpe.probing_size_mm,
            _expanded(pr.probing_size_std_mm))
        if mean is not None and pr.position in outcome.centres_mm:
            off = float(np.linalg.norm(np.subtract(outcome.centres_mm[pr.position], mean)))
            row(pr.position, "sphere", "centre from mean", off, outcome.mpe_centre_spread_mm)
    for sd in rep.sphere_spacing:
        row(sd.position, "ball bar", "SD", sd.sphere_spacing_error_mm, mpe.sphere_spacing_mm)
    for f in rep.flatness:
        row(f.position, "flat", "F", f.flatness_error_mm, mpe.flatness_mm)
    return rows


def evaluate(v: ValidationConfig, mounting: MountingMode, X: Pose, sphere: SphereConfig,
             measured: list[Measured], noise: ShotNoise | None = None) -> ValidationOutcome:
    """The acceptance figures from the measured sweeps, mapped through ``X``, against
    the MPEs of ``v`` and the certified radius of ``sphere``. With ``noise`` (the
    sensor's points, the robot's shots, as the calibration found them) each P_S carries
    its uncertainty from that noise on its view, and is judged with it."""
    probing, spacing, flatness = [], [], []
    centres: dict[str, list[float]] = {}
    balls: dict[str, dict[str, np.ndarray]] = {}
    for m in measured:
        if not m.profiles:
            raise DegenerateDataError(f"validation sweep {m.sweep.label} ({m.sweep.kind}) saw nothing: check its position")
        pts, shot, origins = _mapped(mounting, X, m.poses, m.profiles)
        if m.sweep.kind == "sphere":
            pr = probing_errors(pts, 2 * sphere.radius_mm, position=m.sweep.label, shot_index=shot, noise=noise,
                                shot_origin_mm=origins)
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
    return ValidationOutcome(report, spread, passed, centres, v.mpe_centre_spread_mm, noise=noise)


def _row_verdict(row: dict) -> str:
    passed, mpe = row["passed"], row["MPE (mm)"]
    if passed and row.get("U (mm, k = 2)") is not None and abs(row["max error (mm)"]) > mpe:
        return "within U"  # beyond the MPE by less than its uncertainty: not shown to exceed it
    return {True: "pass", False: "FAIL", None: "not judged"}[passed]


def probing_size_note(outcome: ValidationOutcome) -> str | None:
    """What P_S can show on these views, when its uncertainty from the noise (U, k = 2)
    is more than half its MPE: where that uncertainty comes from, the rule P_S is judged
    by, and what would make it smaller. None otherwise."""
    mpe = outcome.report.mpe.probing_size_mm
    judged = [pr for pr in outcome.report.probing if pr.probing_size_std_mm is not None]
    if mpe is None or not judged or outcome.noise is None:
        return None
    U = [COVERAGE_FACTOR * pr.probing_size_std_mm for pr in judged]
    if max(U) <= mpe / 2:
        return None
    shots = max(pr.n_shots or 0 for pr in judged)
    noise = outcome.noise
    spread = f"{max(U):.4f} mm" if len(U) == 1 else f"{min(U):.4f}-{max(U):.4f} mm over the views"
    diameter = judged[0].certified_diameter_mm
    partial = ""
    if outcome.line_width_mm is not None and outcome.line_width_mm < diameter:
        partial = (f", the more so as each view covers only part of the sphere (the line is {outcome.line_width_mm:.1f} "
                   f"mm wide where the sphere's centre passes, the sphere {diameter:.1f} mm across)")
    return (f"note: P_S shows a size error only beyond its uncertainty from the noise, U (k = 2) {spread}, against its "
            f"MPE {mpe:g} mm: the robot's repeatability ({noise.shot_translation_noise_mm:.3f} mm per axis) moves each "
            f"of a view's {shots} profiles as a whole, and the sphere fit turns that into its diameter{partial}. The "
            "calibration hardly changes P_S. A P_S beyond its MPE by less than U is not shown to exceed it and does "
            "not fail (\"within U\"). To judge P_S more closely: more profiles per sweep ([validation] "
            "profiles_per_sweep; U falls as its square root)"
            + (", or a sphere the line spans." if partial else "."))


def format_outcome(outcome: ValidationOutcome, mounting: MountingMode | None = None) -> str:
    """The validation table (each figure with its scope, absolute or relative, explained
    under it for ``mounting``) and the figures per position, as the terminal prints them."""
    lines = [f"{'figure':14s} {'max error (mm)':>15s} {'worst':>6s} {'MPE (mm)':>9s}  {'verdict':10s}  scope"]
    for name, row in outcome.table().items():
        mpe = "-" if row["MPE (mm)"] is None else f"{row['MPE (mm)']:.4f}"
        lines.append(f"{name:14s} {row['max error (mm)']:15.4f} {row['worst position'] or '-':>6s} {mpe:>9s}  "
                     f"{_row_verdict(row):10s}  {row['scope'] or '-'}")
    if mounting is not None:
        lines.append(f"  ({scope_note(mounting)})")
    for pr in outcome.report.probing:
        U = _expanded(pr.probing_size_std_mm)
        lines.append(f"  {pr.position}: P_F {pr.probing_form_error_mm:.4f} mm, P_S {pr.probing_size_error_mm:+.4f} mm"
                     + ("" if U is None else f" (U {U:.4f} mm, k = 2)")
                     + f" ({pr.fit.n_points_used} points used, {pr.fit.n_points_dropped} dropped)")
    for sd in outcome.report.sphere_spacing:
        lines.append(f"  {sd.position}: SD {sd.sphere_spacing_error_mm:+.4f} mm "
                     f"({sd.fit_a.n_points_used}+{sd.fit_b.n_points_used} points used, "
                     f"{sd.fit_a.n_points_dropped + sd.fit_b.n_points_dropped} dropped)")
    for f in outcome.report.flatness:
        lines.append(f"  {f.position}: F {f.flatness_error_mm:.4f} mm ({f.fit.n_points_used} points used, "
                     f"{f.fit.n_points_dropped} dropped)")
    note = probing_size_note(outcome)
    if note:
        lines.append(note)
    return "\n".join(lines)
