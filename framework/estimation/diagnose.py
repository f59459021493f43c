"""The likely cause of a failed solve, found by solving the dataset again another way."""

from __future__ import annotations

from typing import Callable

import numpy as np

from spherecal.core.errors import SpherecalError
from spherecal.core.models import CalibrationResult, Dataset, Pose
from spherecal.estimation import CalibrationOptions, Solution, solve

#: A criterion on a result solved another way (``True``: that reading fits).
Criterion = Callable[[CalibrationResult], bool]


def solved_other_way(dataset: Dataset, options: CalibrationOptions, fk, kinematics) -> CalibrationResult | None:
    """The result of ``dataset`` (read another way than given), without the nominal
    transform (it was given for the data as first read); None when it cannot be solved."""
    try:
        return solve(dataset, options.model_copy(update={"nominal_transform": None}), fk,
                     kinematics=kinematics).result
    except SpherecalError:
        return None


def quaternions_read_xyzw(dataset: Dataset, station: str | None = None) -> Dataset:
    """``dataset`` with its poses' quaternions (or one station's) taken as written
    (x, y, z, w): the w-first reading of a pose written scalar last, undone."""
    return dataset.model_copy(update={"observations": [
        o.model_copy(update={"base_from_flange": Pose(
            translation_mm=o.base_from_flange.translation_mm,
            quaternion_wxyz=np.roll(np.asarray(o.base_from_flange.quaternion_wxyz, float), 1))})
        if station is None or o.station == station else o for o in dataset.observations]})


def other_mounting(mounting: str) -> str:
    return "eye_to_hand" if mounting == "eye_in_hand" else "eye_in_hand"


def breakdown_cause(dataset: Dataset, options: CalibrationOptions, fk, log: Callable[[str], None], kinematics,
                    what: str, fits: Criterion, ratio: Callable[[CalibrationResult], float]) -> str | None:
    """When the fit of ``dataset`` broke down or is absurd (``what``): the dataset read
    another way that ``fits``, if one does (one solve each, only then): the quaternions
    read (x, y, z, w) instead of (w, x, y, z), the other mounting, one station's
    quaternions read (x, y, z, w). ``ratio``: a result's residuals over the expected,
    for the sentence. The sentence naming the reading, or None."""

    def solved(ds: Dataset) -> CalibrationResult | None:
        res = solved_other_way(ds, options, fk, kinematics)
        return res if res is not None and fits(res) else None

    cause = quaternions_xyzw(dataset, options, fk, log, kinematics, what, fits, ratio)
    if cause is not None:
        return cause
    other = other_mounting(dataset.mounting)
    log(f"{what}: checking whether the data are {other} data")
    alt = solved(dataset.model_copy(update={"mounting": other}))
    if alt is not None:
        return (f"the dataset's mounting is probably wrong: it says {dataset.mounting}, but solved as {other} the "
                f"same data fit with residual RMS {alt.residuals.rms_mm:.4f} mm ({ratio(alt):.2f} x the "
                "expected). Check the sensor's mounting and the 'mounting' of the configuration or dataset")
    return station_quaternions_xyzw(dataset, options, fk, log, kinematics, what, fits)


def quaternions_xyzw(dataset: Dataset, options: CalibrationOptions, fk, log: Callable[[str], None], kinematics,
                     what: str, fits: Criterion, ratio: Callable[[CalibrationResult], float]) -> str | None:
    """Every pose's quaternion read (x, y, z, w) instead of (w, x, y, z) (one solve):
    the sentence naming that reading when the result ``fits`` read so, else None."""
    if any(o.base_from_flange is None for o in dataset.observations):
        return None
    log(f"{what}: trying the quaternions as (x, y, z, w)")
    alt = solved_other_way(quaternions_read_xyzw(dataset), options, fk, kinematics)
    if alt is None or not fits(alt):
        return None
    return ("the poses' quaternions are probably written (x, y, z, w): read that way the same data fit, with "
            f"residual RMS {alt.residuals.rms_mm:.4f} mm ({ratio(alt):.2f} x the expected). spherecal "
            "reads base_from_flange quaternions w first, as ABB writes them (docs/conventions.md); convert "
            "them, or export them w first")


def station_quaternions_xyzw(dataset: Dataset, options: CalibrationOptions, fk, log: Callable[[str], None],
                             kinematics, what: str, good: Criterion) -> str | None:
    """The station whose quaternions, read (x, y, z, w), make the result ``good`` (one
    solve a station, only for a result that failed): a station's poses exported by
    another tool. The sentence naming it, or None."""
    if any(o.base_from_flange is None for o in dataset.observations):
        return None
    labels = list(dict.fromkeys(o.station for o in dataset.observations))
    log(f"{what}: trying each station's quaternions as (x, y, z, w)")
    for label in labels:
        alt = solved_other_way(quaternions_read_xyzw(dataset, label), options, fk, kinematics)
        if alt is not None and good(alt):
            return (f"station {label}'s quaternions are probably written (x, y, z, w): read that way the stations fit "
                    f"together (residual RMS {alt.residuals.rms_mm:.4f} mm). spherecal reads base_from_flange "
                    "quaternions w first, as ABB writes them (docs/conventions.md): convert that station's poses")
    return None


def radius_cause(result: CalibrationResult, dataset: Dataset, options: CalibrationOptions, fk,
                 log: Callable[[str], None], kinematics) -> str | None:
    """For residuals above the expected with the certified radius: the dataset solved
    again with the radius fitted (one solve); the sentence naming the radius the data
    prefer when it differs clearly from the given one and fits clearly better. When that
    names none (a fit started from a diameter often breaks down), the dataset solved with
    half the radius given (one more solve, profiles only): the sentence naming the
    diameter given as the radius when that fits far better. Else None."""
    log("residuals above the expected: checking which sphere radius the data prefer")
    given = result.sphere_radius_mm
    try:
        alt = solve(dataset, options.model_copy(update={"fit_radius": True}), fk, kinematics=kinematics).result
    except SpherecalError:
        alt = None
    if alt is not None and alt.std_sphere_radius_mm is not None:
        fitted = alt.sphere_radius_mm
        if (abs(fitted - given) > max(5 * alt.std_sphere_radius_mm, 0.01)
                and alt.residuals.rms_mm < 0.7 * result.residuals.rms_mm):
            return (f"the sphere radius is probably wrong: the data prefer {fitted:.3f} mm (1-sigma "
                    f"{alt.std_sphere_radius_mm:.3f} mm; residual RMS then {alt.residuals.rms_mm:.4f} mm) but "
                    f"{given:g} mm was given. Check the certificate (radius in mm, not the diameter)")
    if not result.residuals.n_profiles_used:  # sphere centres do not depend on the radius
        return None
    log(f"checking whether {given:g} mm is the sphere's diameter")
    try:
        half = solve(dataset.model_copy(update={"sphere_radius_mm": given / 2}), options, fk,
                     kinematics=kinematics).result
    except SpherecalError:
        return None
    if half.residuals.rms_mm < 0.2 * result.residuals.rms_mm:
        return (f"the sphere's diameter is probably given as its radius: with {given / 2:g} mm the same data fit "
                f"with residual RMS {half.residuals.rms_mm:.4f} mm (with {given:g} mm, "
                f"{result.residuals.rms_mm:.4f} mm). Give the certified radius, in mm")
    return None


def odd_station(solution: Solution, dataset: Dataset, options: CalibrationOptions, fk, log: Callable[[str], None],
                kinematics, level: Callable[[CalibrationResult], str]) -> str | None:
    """The station whose leaving out makes the others agree, when there is one: each
    station left out in turn (one solve each); ``level`` grades a result (``"red"``:
    not acceptable). The sentence naming it, or None."""
    result = solution.result
    labels = list(solution.problem.station_labels)
    if len(labels) < 4:
        return None
    log(f"the stations disagree by {result.robot_error.station_translation_mm:.3f} mm: leaving each out in turn")
    best = None
    for label in labels:
        keep = [o for o in dataset.observations if o.station != label]
        try:
            alt = solve(dataset.model_copy(update={"observations": keep}), options, fk, kinematics=kinematics).result
        except SpherecalError:
            continue
        spread = alt.robot_error.station_translation_mm if alt.robot_error is not None else 0.0
        if best is None or spread < best[1]:
            best = (label, spread, level(alt))
    if best is None or best[2] == "red" or best[1] > result.robot_error.station_translation_mm / 3:
        return None
    return (f"station {best[0]} disagrees with the others: without it they agree to {best[1]:.3f} mm (with it "
            f"{result.robot_error.station_translation_mm:.3f} mm). Its profiles or poses are offset (the sensor or "
            "the sphere moved, another tool or work object, a pose read in another frame): re-acquire that station")
