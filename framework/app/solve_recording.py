"""``spherecal solve`` of a recording: a pose stream and a profile stream on two clocks
(the stream form, or a ROS 2 bag converted once into it), solved with their clock
relation (docs/on-the-fly.md)."""

from __future__ import annotations

import re
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np

from spherecal.app import plugin_host
from spherecal.app.outputs import check_output_folder
from spherecal.app.provenance import provenance_type, recorded_options, traceability, with_clock_truth
from spherecal.app.solve import solve_kinematics, solve_robot_type
from spherecal.app.solving import Outcome, solve_and_write
from spherecal.core.errors import ConfigError, DatasetFileError, InputError
from spherecal.core.kinematics import arm_joint_names
from spherecal.core.models import Dataset
from spherecal.core.streams import Recording
from spherecal.estimation.on_the_fly import solve_recording
from spherecal.io.bag_frames import bag_frames
from spherecal.io.rosbag import read_bag
from spherecal.io.runlog import progress_log
from spherecal.io.streams import write_recording
from spherecal.io.transform_text import parse_xyz_quat

_LOG = progress_log("run")  # the default ``log``: logger spherecal.run


def run_solve_recording(recording: Recording, path: Path, out: Path, *, nominal: str | None = None,
                        robot_type: str | None = None, robot_config: Path | None = None,
                        fit_radius: bool | None = None, robot_error_model: str | None = None,
                        offset_ms: float | None = None, overwrite: bool = False, report: bool = True,
                        force: bool = False, operator: str | None = None,
                        log: Callable[[str], None] = _LOG) -> Outcome:
    """``spherecal solve`` of a recording (a pose stream and a profile stream,
    :mod:`spherecal.core.streams`) read from ``path``: the clock relation estimated with
    the transform (:func:`spherecal.estimation.on_the_fly.solve_recording`); ``offset_ms``
    a known start for the clock offset. The estimator's settings are those the recording
    holds (:func:`~spherecal.app.provenance.recorded_options`), else the defaults; ``nominal``, ``fit_radius`` and
    ``robot_error_model`` given (not None) replace theirs. Otherwise as :func:`run_solve`."""
    nominal_pose = parse_xyz_quat(nominal, "--nominal") if nominal is not None else None
    header = Dataset(mounting=recording.mounting, sphere_radius_mm=recording.sphere_radius_mm,
                     provenance=with_clock_truth(recording))
    options = recorded_options(recording.provenance, path, log, **{k: v for k, v in (
        ("nominal_transform", nominal_pose), ("fit_radius", fit_radius), ("robot_error_model", robot_error_model))
        if v is not None})
    host = plugin_host.make_host()
    arm = None
    robot_type = robot_type or solve_robot_type(header, robot_type, robot_config)
    if robot_type is not None and recording.poses.joints_deg is not None and options.robot_error_model != "station":
        _, _, arm = solve_kinematics(header, robot_type, robot_config, "reported", host=host)
    exports = host.export_plan(None, recording.mounting, robot_type)
    if not overwrite:
        check_output_folder(out, "solve", "give a new folder with --out, or --overwrite to replace its result, "
                            "exports and report", exports)

    frames = bag_frames(recording.provenance)  # the bag's frame ids, for the result and the ROS exports

    def solver():
        solution = solve_recording(recording, options, kinematics=arm, progress=log, offset_ms=offset_ms)
        return replace(solution, result=solution.result.model_copy(update={"data_frames": frames}))

    def as_mounting(mounting: str):
        return solve_recording(replace(recording, mounting=mounting), options, kinematics=arm).result

    solution, graded, written = solve_and_write(header, options, out, exports, None, log=log, report=report,
                                                force=force, kinematics=arm, solver=solver, recheck=as_mounting,
                                                provenance=traceability(header, path, operator=operator))
    host.calibration_finished(result=solution.result, dataset=header, out_dir=out, exports_written=written,
                              robot_type=robot_type, sensor_type=provenance_type(header, "sensor"))
    return Outcome(solution=solution, verdict=graded, exports_written=written, dataset=header)


#: The library's parameters as the command line names them, in the bag reader's and the
#: file writer's messages: (the library's words, the command line's)
_PARAMETER_FLAGS = (
    (re.compile(r"\bline_axis='([xy])'"), r"--line-axis \1"),
    (re.compile(r"\b(base|flange)_frame\b"), r"--\1-frame"),
    (re.compile(r"\bpass overwrite=True\b"), "give --overwrite"),
)


@contextmanager
def _flags_for_parameters():
    """An error of the bag reader or the file writer raised again in the same type, its
    message naming the command line's flags (``--line-axis x``) where the library names
    its parameters (``line_axis='x'``)."""
    try:
        yield
    except (DatasetFileError, InputError) as exc:
        text = str(exc)
        for pattern, flag in _PARAMETER_FLAGS:
            text = pattern.sub(flag, text)
        try:
            again = type(exc)(text) if text != str(exc) else None
        except TypeError:  # an error class built from other arguments: its own words stand
            again = None
        if again is None:
            raise
        raise again from None


def convert_bag(path: Path, out: Path, *, profile_topic: str | None, pose_topic: str | None, mounting: str | None,
                sphere_radius_mm: float | None, line_axis: str = "y", base_frame: str | None = None,
                flange_frame: str | None = None, robot_type: str | None = None, robot_config: Path | None = None,
                overwrite: bool = False, log: Callable[[str], None] = _LOG) -> Recording:
    """A ROS 2 bag read into a recording (:func:`spherecal.io.rosbag.read_bag`) and written
    once in the stream form, ``out/recording.jsonl``, so that a re-run reads that file.
    Joint states go through the robot plugin's kinematics: the robot type is
    ``robot_type`` (``--robot``), else the ``type`` of ``robot_config``
    (:func:`~spherecal.app.solve.solve_robot_type`), with that file's settings; they are
    picked out of each message by the names the arm's kinematics gives its joints
    (:func:`~spherecal.core.kinematics.arm_joint_names`), else taken in the message's order."""
    missing = [flag for flag, value in (("--profile-topic", profile_topic), ("--pose-topic", pose_topic),
                                        ("--mounting", mounting), ("--sphere-radius-mm", sphere_radius_mm))
               if value is None]
    if missing:
        raise ConfigError(f"{path} is a ROS 2 bag: give {', '.join(missing)} (a bag does not record them; "
                          "docs/on-the-fly.md)")
    header = Dataset(mounting=mounting, sphere_radius_mm=sphere_radius_mm)
    robot_type = solve_robot_type(header, robot_type, robot_config)
    joints_to_pose = joint_names = None
    if robot_type is not None:
        fk, _, arm = solve_kinematics(header, robot_type, robot_config, "joints", host=plugin_host.make_host())
        flange_pose = arm.flange_pose_from_joints if arm is not None else fk
        joint_names = arm_joint_names(arm) if arm is not None else None
        if flange_pose is not None:
            def joints_to_pose(q_deg):
                poses = [flange_pose(q) for q in np.asarray(q_deg, dtype=float)]
                return (np.array([p.rotation_matrix for p in poses]), np.array([p.translation for p in poses]))
    target = out / "recording.jsonl"
    if target.exists() and not overwrite:  # said before the bag is read, which may take a while
        raise InputError(f"{target} exists: {out} holds a bag converted by an earlier run, and solve would replace "
                         "it (nothing is overwritten silently); give a new folder with --out, or --overwrite to "
                         "replace it")
    with _flags_for_parameters():
        recording = read_bag(path, profile_topic=profile_topic, pose_topic=pose_topic, mounting=mounting,
                             sphere_radius_mm=sphere_radius_mm, line_axis=line_axis, base_frame=base_frame,
                             flange_frame=flange_frame, joints_to_pose=joints_to_pose, joint_names=joint_names)
        out.mkdir(parents=True, exist_ok=True)
        write_recording(target, recording, overwrite=overwrite)
    log(f"bag {path}: {recording.poses.n} poses and {recording.profiles.n} profiles, written as {target}")
    # the solve takes the points in double precision, as read_recording gives them from the file
    profiles = recording.profiles
    return replace(recording, profiles=replace(profiles, points_yz_mm=profiles.points_yz_mm.astype(np.float64)))
