"""The part of ABB's Externally Guided Motion (EGM) messages that pose streaming reads:
``abb.egm.EgmRobot``, the message the controller sends every sample period over UDP.

The message definitions are written here as a protobuf descriptor built at run time
(no ``.proto`` file, no protoc step): only the fields a position stream needs, with the
field numbers and types of ABB's published ``egm.proto`` (proto2, package ``abb.egm``).
Fields left out (test signals, measured force, external joints' meaning) are skipped by
the parser as unknown fields, so a controller that sends them still decodes.

What a sample carries (:class:`EgmSample`):

* ``header``: ``seqno`` (field 1, uint32, one more per message: a gap is a lost
  message), ``tm`` (2, uint32, the controller's send time in ms), ``mtype`` (3, enum;
  2 = data sent by the robot controller);
* ``feedBack`` (EgmRobot field 2): the measured position. ``joints`` (1: repeated
  double, degrees, controller convention), ``cartesian`` (2: ``pos`` x, y, z in mm and
  ``orient`` u0..u3, **u0 the scalar**: (w, x, y, z), the project's order), ``time`` (4:
  EgmClock ``sec`` and ``usec``, uint64, the controller's clock; ABB documents it as
  since 1970, some RobotWare versions count from elsewhere: it is the controller's own
  count either way);
* ``planned`` (3): the same for the planned position;
* ``motorState`` (4), ``mciState`` (5), ``rapidExecState`` (8): states as enums.

:func:`decode_egm_robot` turns one datagram into an :class:`EgmSample`;
:func:`encode_egm_robot` does the reverse (the simulated controller sends with it).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from spherecal.plugins import DeviceError

__all__ = ["EgmDecodeError", "EgmSample", "MSGTYPE_DATA", "decode_egm_robot", "encode_egm_robot", "message_classes"]

#: ``EgmHeader.MessageType`` value of a message sent by the robot controller.
MSGTYPE_DATA = 2
#: ``EgmMotorState``: 1 motors on, 2 off; ``EgmMCIState``: 1 error, 2 stopped, 3 running;
#: ``EgmRapidCtrlExecState``: 1 stopped, 2 running (0: undefined, each).
MOTORS_ON, MOTORS_OFF = 1, 2
RAPID_STOPPED, RAPID_RUNNING = 1, 2

_PACKAGE = "abb.egm"


class EgmDecodeError(DeviceError):
    """A datagram that is not an ``EgmRobot`` message with a measured pose."""


@dataclass(frozen=True)
class EgmSample:
    """One ``EgmRobot`` message. Translations in mm, quaternions (w, x, y, z) (EGM's
    u0..u3), joints in degrees (controller convention), ``time_s`` the feedback clock
    (``sec + usec / 1e6``, the controller's clock), ``tm_ms`` the header's send time, ms
    (uint32). None where the message does not carry the field."""

    seqno: int
    tm_ms: int | None
    mtype: int
    translation_mm: tuple[float, float, float]
    quaternion_wxyz: tuple[float, float, float, float]
    joints_deg: tuple[float, ...] | None = None
    time_s: float | None = None
    time_sec: int | None = None
    time_usec: int | None = None
    planned_translation_mm: tuple[float, float, float] | None = None
    planned_quaternion_wxyz: tuple[float, float, float, float] | None = None
    planned_joints_deg: tuple[float, ...] | None = None
    motor_state: int | None = None
    mci_state: int | None = None
    rapid_exec_state: int | None = None


# --- the descriptor -----------------------------------------------------------------------------
def _file_descriptor():
    """The ``FileDescriptorProto`` of the messages used here (ABB's field numbers)."""
    from google.protobuf import descriptor_pb2

    F = descriptor_pb2.FieldDescriptorProto
    fdp = descriptor_pb2.FileDescriptorProto(name="spherecal/abb_egm_subset.proto", package=_PACKAGE,
                                             syntax="proto2")

    def message(name: str, fields, enums=()):
        m = fdp.message_type.add(name=name)
        for enum_name, values in enums:
            e = m.enum_type.add(name=enum_name)
            for value_name, number in values:
                e.value.add(name=value_name, number=number)
        for field_name, number, kind, label, type_name in fields:
            f = m.field.add(name=field_name, number=number, type=kind, label=label)
            if type_name:
                f.type_name = type_name if type_name.startswith(".") else f".{_PACKAGE}.{type_name}"
        return m

    opt, req, rep = F.LABEL_OPTIONAL, F.LABEL_REQUIRED, F.LABEL_REPEATED
    u32, u64, dbl, msg, enum, boolean = (F.TYPE_UINT32, F.TYPE_UINT64, F.TYPE_DOUBLE, F.TYPE_MESSAGE, F.TYPE_ENUM,
                                         F.TYPE_BOOL)
    message("EgmHeader", [("seqno", 1, u32, opt, ""), ("tm", 2, u32, opt, ""),
                          ("mtype", 3, enum, opt, "EgmHeader.MessageType")],
            [("MessageType", [("MSGTYPE_UNDEFINED", 0), ("MSGTYPE_COMMAND", 1), ("MSGTYPE_DATA", 2),
                              ("MSGTYPE_CORRECTION", 3), ("MSGTYPE_PATH_CORRECTION", 4)])])
    message("EgmCartesian", [("x", 1, dbl, req, ""), ("y", 2, dbl, req, ""), ("z", 3, dbl, req, "")])
    message("EgmQuaternion", [(f"u{i}", i + 1, dbl, req, "") for i in range(4)])
    message("EgmClock", [("sec", 1, u64, req, ""), ("usec", 2, u64, req, "")])
    message("EgmPose", [("pos", 1, msg, opt, "EgmCartesian"), ("orient", 2, msg, opt, "EgmQuaternion")])
    message("EgmJoints", [("joints", 1, dbl, rep, "")])
    position = [("joints", 1, msg, opt, "EgmJoints"), ("cartesian", 2, msg, opt, "EgmPose"),
                ("externalJoints", 3, msg, opt, "EgmJoints"), ("time", 4, msg, opt, "EgmClock")]
    message("EgmFeedBack", position)
    message("EgmPlanned", position)
    message("EgmMotorState", [("state", 1, enum, req, "EgmMotorState.MotorStateType")],
            [("MotorStateType", [("MOTORS_UNDEFINED", 0), ("MOTORS_ON", 1), ("MOTORS_OFF", 2)])])
    message("EgmMCIState", [("state", 1, enum, req, "EgmMCIState.MCIStateType")],
            [("MCIStateType", [("MCI_UNDEFINED", 0), ("MCI_ERROR", 1), ("MCI_STOPPED", 2), ("MCI_RUNNING", 3)])])
    message("EgmRapidCtrlExecState", [("state", 1, enum, req, "EgmRapidCtrlExecState.RapidCtrlExecStateType")],
            [("RapidCtrlExecStateType", [("RAPID_UNDEFINED", 0), ("RAPID_STOPPED", 1), ("RAPID_RUNNING", 2)])])
    message("EgmRobot", [
        ("header", 1, msg, opt, "EgmHeader"), ("feedBack", 2, msg, opt, "EgmFeedBack"),
        ("planned", 3, msg, opt, "EgmPlanned"), ("motorState", 4, msg, opt, "EgmMotorState"),
        ("mciState", 5, msg, opt, "EgmMCIState"), ("mciConvergenceMet", 6, boolean, opt, ""),
        ("rapidExecState", 8, msg, opt, "EgmRapidCtrlExecState"), ("utilizationRate", 10, dbl, opt, ""),
    ])
    return fdp


@lru_cache(maxsize=1)
def message_classes() -> dict[str, type]:
    """{message name: class} of the messages above, built once in a pool of their own
    (so they never clash with another ``abb.egm`` in the process's default pool)."""
    from google.protobuf import descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    pool.Add(_file_descriptor())
    names = ("EgmRobot", "EgmHeader", "EgmFeedBack", "EgmPlanned", "EgmPose", "EgmClock")
    return {n: message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{_PACKAGE}.{n}")) for n in names}


# --- decoding and encoding -------------------------------------------------------------------------
def _pose(cartesian) -> tuple[tuple[float, float, float], tuple[float, float, float, float]] | None:
    if not (cartesian.HasField("pos") and cartesian.HasField("orient")):
        return None
    p, q = cartesian.pos, cartesian.orient
    return (p.x, p.y, p.z), (q.u0, q.u1, q.u2, q.u3)


def decode_egm_robot(data: bytes) -> EgmSample:
    """One ``EgmRobot`` datagram as an :class:`EgmSample`; :class:`EgmDecodeError` when it
    is not one (unparseable, no header seqno, or no measured Cartesian pose)."""
    from google.protobuf.message import DecodeError

    robot = message_classes()["EgmRobot"]()
    try:
        robot.ParseFromString(data)
    except DecodeError as exc:
        raise EgmDecodeError(f"EGM datagram of {len(data)} bytes is not an EgmRobot message: {exc}") from None
    if not robot.IsInitialized():  # a required field (a coordinate, a quaternion component) is missing
        raise EgmDecodeError(f"EGM datagram of {len(data)} bytes is not an EgmRobot message: required field(s) "
                             f"{', '.join(robot.FindInitializationErrors())} missing")
    if not robot.HasField("header") or not robot.header.HasField("seqno"):
        raise EgmDecodeError(f"EGM message without header.seqno ({len(data)} bytes)")
    header, fb = robot.header, robot.feedBack
    pose = _pose(fb.cartesian) if robot.HasField("feedBack") and fb.HasField("cartesian") else None
    if pose is None:
        raise EgmDecodeError(f"EGM message seqno {header.seqno} carries no feedBack.cartesian pos and orient")
    sec = usec = time_s = None
    if fb.HasField("time"):
        sec, usec = int(fb.time.sec), int(fb.time.usec)
        time_s = sec + usec * 1e-6
    planned = robot.planned if robot.HasField("planned") else None
    planned_pose = _pose(planned.cartesian) if planned is not None and planned.HasField("cartesian") else None
    return EgmSample(
        seqno=int(header.seqno), tm_ms=int(header.tm) if header.HasField("tm") else None, mtype=int(header.mtype),
        translation_mm=pose[0], quaternion_wxyz=pose[1],
        joints_deg=tuple(fb.joints.joints) if fb.HasField("joints") else None,
        time_s=time_s, time_sec=sec, time_usec=usec,
        planned_translation_mm=None if planned_pose is None else planned_pose[0],
        planned_quaternion_wxyz=None if planned_pose is None else planned_pose[1],
        planned_joints_deg=tuple(planned.joints.joints) if planned is not None and planned.HasField("joints")
        else None,
        motor_state=int(robot.motorState.state) if robot.HasField("motorState") else None,
        mci_state=int(robot.mciState.state) if robot.HasField("mciState") else None,
        rapid_exec_state=int(robot.rapidExecState.state) if robot.HasField("rapidExecState") else None,
    )


def _set_position(target, translation_mm, quaternion_wxyz, joints_deg, sec=None, usec=None) -> None:
    if joints_deg is not None:
        target.joints.joints.extend(float(v) for v in joints_deg)
    pos, orient = target.cartesian.pos, target.cartesian.orient
    pos.x, pos.y, pos.z = (float(v) for v in translation_mm)
    orient.u0, orient.u1, orient.u2, orient.u3 = (float(v) for v in quaternion_wxyz)
    if sec is not None:
        target.time.sec, target.time.usec = int(sec), int(usec)


def encode_egm_robot(sample: EgmSample) -> bytes:
    """The ``EgmRobot`` datagram of ``sample`` (its ``time_sec``/``time_usec``, when set, as
    the feedback clock; ``time_s`` alone is not encoded)."""
    robot = message_classes()["EgmRobot"]()
    robot.header.seqno = int(sample.seqno) % 2**32
    if sample.tm_ms is not None:
        robot.header.tm = int(sample.tm_ms) % 2**32
    robot.header.mtype = int(sample.mtype)
    if not np.all(np.isfinite(sample.translation_mm)) or not np.all(np.isfinite(sample.quaternion_wxyz)):
        raise ValueError(f"EGM sample seqno {sample.seqno}: the pose is not finite")
    _set_position(robot.feedBack, sample.translation_mm, sample.quaternion_wxyz, sample.joints_deg,
                  sample.time_sec, sample.time_usec)
    if sample.planned_translation_mm is not None and sample.planned_quaternion_wxyz is not None:
        _set_position(robot.planned, sample.planned_translation_mm, sample.planned_quaternion_wxyz,
                      sample.planned_joints_deg, sample.time_sec, sample.time_usec)
    for name, value in (("motorState", sample.motor_state), ("mciState", sample.mci_state),
                        ("rapidExecState", sample.rapid_exec_state)):
        if value is not None:
            getattr(robot, name).state = int(value)
    return robot.SerializeToString()
