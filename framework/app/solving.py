"""Solve a dataset, grade the result (naming the likely cause of a RED one) and write the
result, exports, calibrated robot model and report: the end of calibrate and solve."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from spherecal.app.outputs import CALIBRATED_URDF_NAME, check_output_targets
from spherecal.config import ReportConfig
from spherecal.core.errors import FitBreakdownError, SpherecalError
from spherecal.core.kinematics import chain_with_errors
from spherecal.core.models import CalibrationResult, Dataset
from spherecal.core.urdf import chain_to_urdf
from spherecal.estimation import CalibrationOptions, Solution, solve
from spherecal.estimation import diagnose
from spherecal.io import files as safeio
from spherecal.io.exporters import ExportPlan, red_warning, write_exports
from spherecal.io.runlog import Notice, progress_log
from spherecal.report.assess import (
    Thresholds, Verdict, absurd_ratio, expected_rms_mm, implausible_disagreement, is_absurd, station_disagreement_text,
    verdict,
)

if TYPE_CHECKING:
    from spherecal.config import RunConfig

_LOG = progress_log("run")  # the default ``log``: logger spherecal.run


@dataclass
class Outcome:
    """What a calibrate/solve run produced."""

    solution: Solution | None = None
    files: dict[str, Path] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    verdict: Verdict | None = None
    #: False when the result is RED and was not written (no ``force``)
    exports_written: bool = False
    #: ``--resume`` found a finished run (its result.json): nothing was done
    finished: bool = False
    #: the dataset solved (the journal or replayed file of calibrate, solve's dataset)
    dataset: Dataset | None = None
    #: calibrate's acquisition timing, when it took shots: ``profiles``, ``robot_time_s``,
    #: ``profiles_per_minute``, ``simulated`` (simulated robot time or the wall clock)
    acquisition: dict | None = None


def calibration_options(cfg: RunConfig) -> CalibrationOptions:
    """The configuration's ``[calibration]`` with its nominal transform."""
    return cfg.calibration.model_copy(update={"nominal_transform": cfg.nominal_transform.pose()})


def solve_and_write(
    dataset: Dataset,
    options: CalibrationOptions,
    out: Path,
    exports: ExportPlan,
    fk=None,
    log: Callable[[str], None] = _LOG,
    report: bool = True,
    force: bool = False,
    kinematics=None,
    provenance: dict | None = None,
    report_settings: ReportConfig | None = None,
    solver: Callable[[], Solution] | None = None,
    recheck: Callable[[str], CalibrationResult] | None = None,
) -> tuple[Solution, Verdict, bool]:
    """Solve ``dataset``, grade the result (:func:`assess_solution`) and write
    ``result.json``, the exports and the HTML report in ``out``. A RED result's
    ``result.json`` and exports are written only with ``force``; its report is written
    (it says why). Returns the solution, its verdict and whether the result and exports
    were written. ``exports``: the run's :class:`~spherecal.io.exporters.ExportPlan`
    (``PluginHost.export_plan``); ``kinematics``: the robot's arm model, for the
    kinematic robot error model; ``provenance``: the result's
    (:func:`spherecal.app.provenance.traceability`); ``report_settings``: the
    configuration's ``[report]``; ``solver``: what solves instead of :func:`solve` of
    ``dataset`` (a recording's solve; ``dataset`` then holds its header and provenance),
    ``recheck`` its solve as another mounting (:func:`assess_solution`)."""
    check_output_targets(out, exports)  # a planted link: refuse before solving, write nothing
    try:
        solution = solver() if solver is not None else solve(dataset, options, fk, progress=log, kinematics=kinematics)
    except FitBreakdownError as exc:
        if recheck is not None:  # a recording: of the re-readings, only the mounting's applies
            cause = _other_mounting_cause(dataset.mounting, recheck, log, "the fit broke down")
        else:
            cause = _breakdown_cause(dataset, options, fk, log, kinematics)
        if cause is None:
            raise
        raise FitBreakdownError(f"{cause}. ({exc})") from None
    if provenance is not None:
        solution = replace(solution, result=solution.result.model_copy(update={"provenance": provenance}))
    graded = assess_solution(solution, dataset, options, fk, log, kinematics=kinematics, recheck=recheck)
    out.mkdir(parents=True, exist_ok=True)
    written = graded.level != "red" or force
    # the verdict travels with the result: a RED one written with --force says so in result.json
    solution = replace(solution, result=solution.result.model_copy(update={
        "diagnostics": solution.result.diagnostics.model_copy(update={"verdict": {
            "level": graded.level, "headline": graded.headline, "written_with_force": graded.level == "red"}})}))
    notes = exports.notes(solution.result)  # the exporters' notes: their warnings here, their text in the report
    urdf = None
    if written:
        write_exports(solution.result, out, exports, overwrite=True)  # result.json among them; derived files only
        for note in notes:
            if note.warning:
                log(Notice(f"warning: {note.title}: {note.warning}"))
        urdf = write_calibrated_urdf(solution, kinematics, out)
        if urdf is not None:
            log(f"calibrated robot model: {urdf}")
    if report:
        # (imported only for a report: matplotlib is not loaded by `solve --no-report`,
        # tests/cli/test_startup_imports.py)
        from spherecal.report.html import CALIBRATION_VERSION, write_report

        chosen = {} if report_settings is None else {"point_distance_mm": report_settings.point_distance_mm}
        write_report(solution, out, verdict_override=graded, notes=notes, version=CALIBRATION_VERSION,
                     calibrated_urdf=urdf, **chosen)
    return solution, graded, written


def write_calibrated_urdf(solution: Solution, kinematics, out: Path) -> Path | None:
    """With identified kinematic parameters, the robot with its identified geometry as a
    URDF (metres, joints in the model's convention): the nominal chain with the identified
    errors applied and the others left at zero. Joint and link names are the arm's when
    its kinematics name them (``joint_names``, ``base_link``, ``flange_link``: a robot
    described by its URDF reads the file back with the same settings), else ``joint_1``
    ... with ``base_link`` and ``tool0``. None when nothing was identified."""
    ref = solution.refined
    ke = ref.diagnostics.get("kinematic_effects")
    if kinematics is None or not ke or not any(ke["identified"]):
        return None
    kappa = np.where(ke["identified"], ref.kinematic_errors, 0.0)
    limits = getattr(kinematics, "model_joint_limits_rad", None)
    n_id = sum(ke["identified"])
    text = chain_to_urdf(
        chain_with_errors(kinematics.chain, kappa), "spherecal_calibrated_robot",
        joint_names=getattr(kinematics, "joint_names", None),
        base_link=getattr(kinematics, "base_link", "base_link"),
        flange_link=getattr(kinematics, "flange_link", "tool0"),
        joint_limits_rad=limits() if callable(limits) else None,
        warning=red_warning(solution.result) or None,
        comment=f"Identified by spherecal from {solution.problem.n_profiles} profiles: {n_id} of "
                f"{len(ke['identified'])} geometric parameters (result.json, robot_error.kinematic_parameters); "
                "joint zero offsets are folded into the joint origins.",
    )
    path = out / CALIBRATED_URDF_NAME
    safeio.write_text(path, text)
    return path


def _breakdown_cause(dataset: Dataset, options: CalibrationOptions, fk, log, kinematics,
                     what: str = "the fit broke down") -> str | None:
    """When the fit broke down or is absurd (``what``): the reading of the dataset that is
    not absurd, if there is one (:func:`spherecal.estimation.diagnose.breakdown_cause`);
    None for a recording (its re-readings are a dataset's)."""
    if not dataset.observations:
        return None
    return diagnose.breakdown_cause(dataset, options, fk, log, kinematics, what,
                                    fits=lambda res: not is_absurd(res), ratio=absurd_ratio)


def _other_mounting_cause(mounting: str, recheck: Callable[[str], CalibrationResult], log: Callable[[str], None],
                          what: str) -> str | None:
    """A recording solved as the other mounting (``recheck``) after ``what``: the cause
    named when the same data fit that way, else None."""
    th = Thresholds()
    other = diagnose.other_mounting(mounting)
    log(f"{what}: checking whether the recording is {other} data")
    try:
        alt = recheck(other)
    except SpherecalError:
        return None
    if is_absurd(alt, th):
        return None
    return (f"likely cause: the recording's mounting is probably wrong: it says {mounting}, but solved as {other} "
            f"the same data fit with residual RMS {alt.residuals.rms_mm:.4f} mm ({absurd_ratio(alt, th):.2f} x the "
            "expected). Check the sensor's mounting (--mounting)")


def assess_solution(solution: Solution, dataset: Dataset, options: CalibrationOptions, fk=None,
                    log: Callable[[str], None] = _LOG, kinematics=None,
                    recheck: Callable[[str], CalibrationResult] | None = None) -> Verdict:
    """The verdict of ``solution`` (:func:`spherecal.report.assess.verdict`); for a RED
    one, the likely cause named where the data can tell it
    (:mod:`spherecal.estimation.diagnose`):

    - an absurd solution (residuals many times the noise), or one whose stations disagree
      by more than any arm's geometry makes (the per-station effects took in a data
      error, :func:`~spherecal.report.assess.implausible_disagreement`), solved again
      with the quaternions read (x, y, z, w), with the other mounting, with one station's
      quaternions read the other way: when one fits, it is named;
    - residuals above the expected with the certified radius, or such a disagreement:
      solved again with the radius fitted; when the data prefer another radius, it is named;
    - stations that disagree by more than 0.1 mm: each left out in turn.

    Each check costs one more solve, and only for a RED result or such a disagreement (a
    cause named makes the verdict RED). ``kinematics`` (the arm's,
    as given to :func:`solve`) is passed to every such solve: without it a solve that
    identifies the arm's geometry or uses the kinematic error model refuses to run, and
    the check would say nothing. ``recheck`` (a recording's, ``dataset`` then holds only
    its header): its result solved as another mounting, for an absurd result."""
    th = Thresholds()
    result = solution.result
    v = verdict(result, th)
    if not dataset.observations:  # a recording: of the re-readings below, only the mounting's applies
        if is_absurd(result, th) and recheck is not None:
            cause = _other_mounting_cause(dataset.mounting, recheck, log,
                                          f"the result is absurd ({absurd_ratio(result, th):.3g} x the expected)")
            if cause is not None:
                v.level = "red"
                v.reasons.append(("red", cause))
                v.headline = f"{v.headline} Likely cause: the mounting."
        return v
    absurd = is_absurd(result, th)
    implausible = not absurd and implausible_disagreement(result)
    if v.level != "red" and not implausible:
        return v
    ratio = result.residuals.rms_mm / expected_rms_mm(result, th)
    causes: list[str] = []
    if absurd:
        cause = _breakdown_cause(dataset, options, fk, log, kinematics,
                                 f"the result is absurd ({absurd_ratio(result, th):.3g} x the expected)")
        if cause is not None:
            causes.append(cause)
    elif implausible:  # a reading of the data that fits must also make the stations agree as an arm's can
        cause = diagnose.breakdown_cause(
            dataset, options, fk, log, kinematics,
            f"the stations disagree by {station_disagreement_text(result.robot_error)}, more than any arm",
            fits=lambda res: not is_absurd(res, th) and not implausible_disagreement(res), ratio=absurd_ratio)
        if cause is not None:
            causes.append(cause)
    if not causes and not result.radius_fitted and (ratio > th.residual_ratio_amber or implausible):
        cause = diagnose.radius_cause(result, dataset, options, fk, log, kinematics)
        if cause is not None:
            causes.append(cause)
    if not causes and v.level == "red" and not absurd and not implausible:
        # rows each at its own orientation written (x, y, z, w) are read as other, poorly
        # spread orientations: the fit is not absurd but determines little; read right, it does
        cause = diagnose.quaternions_xyzw(
            dataset, options, fk, log, kinematics, "the result is RED",
            lambda alt: verdict(alt, th).level != "red" and alt.residuals.rms_mm <= 1.5 * result.residuals.rms_mm,
            absurd_ratio)
        if cause is not None:
            causes.append(cause)
    robot_error = result.robot_error
    if not causes and robot_error is not None and len(dataset.observations) and robot_error.station_translation_mm > 0.1:
        cause = diagnose.odd_station(solution, dataset, options, fk, log, kinematics,
                                     level=lambda alt: verdict(alt, th).level)
        if cause is None and not absurd and not implausible:  # (those have had their stations read the other way)
            spread = robot_error.station_translation_mm
            cause = diagnose.station_quaternions_xyzw(
                dataset, options, fk, log, kinematics, f"the stations disagree by {spread:.3f} mm",
                lambda alt: verdict(alt, th).level != "red" and alt.robot_error is not None
                and alt.robot_error.station_translation_mm < spread / 3)
        if cause is not None:
            causes.append(cause)
    if causes:  # a data error named: whatever the grade of the result as it was read, it is wrong
        if v.level != "red":
            v.level, v.headline = "red", "Do not use yet: see the checks and the advice below."
        v.reasons.extend(("red", "likely cause: " + c) for c in causes)
        v.headline = f"{v.headline} Likely cause: {causes[0].split(':')[0]}."
    return v
