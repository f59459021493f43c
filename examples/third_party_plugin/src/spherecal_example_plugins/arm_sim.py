"""A simulated example arm controller: XA/1 (:mod:`.xa_protocol`) served over TCP on the
simulated cell, so that the real driver (:class:`.arm.ExampleArm`) runs against it.

What a simulator of one's own protocol does with the cell (docs/writing-a-robot-plugin.md,
"A simulator of your own protocol"):

- the arm: ``cell.arm`` (with the run's geometric error when ``[simulation.robot_error]``
  is set) or, when the cell has none yet, ``cell.attach_arm(kinematics)``. Joints come from
  the nominal inverse kinematics (as a controller's do); the flange goes where the arm's
  true geometry puts them (``cell.move_flange_to(arm.true_flange_pose(joints))``), and the
  controller reports its nominal model's pose;
- time: every move goes onto ``cell.timeline`` (``move_linear``: a trapezoid, then the
  settle), which advances ``cell.clock``; ``POSE`` and ``DONE`` carry the controller's
  clock at that true time (``cell.controller_clock.stamp(cell.clock.now_s)``);
- noise: the reported pose through ``cell.report_pose``, drawn from the controller's own
  random stream (``cell.standstill_rng("example_arm controller")``), once per standstill;
- the server: :class:`spherecal.plugins.SimulatedDeviceServer` (thread, port, stop, the
  handler's errors surfaced);
- the pose stream: a move takes no wall time (the timeline advances the clock at once),
  so the samples covering it are sent when it is executed, before its ``DONE``:
  ``cell.timeline.sample`` over the true time since the last sample sent, ticking on
  the controller's clock, with the stream's own random numbers
  (``cell.device_rng("example_arm pose stream")``).
"""

from __future__ import annotations

import numpy as np

from spherecal.plugins import InputError, Pose, SimulatedDeviceServer, quat_wxyz_from_matrix

from . import xa_protocol as XA
from .arm_kinematics import HOME_JOINTS_DEG, ExampleArmKinematics

#: the controller's own speed limits (whatever the driver is configured to), mm/s and deg/s
MAX_SPEED_MM_S = 2000.0
MAX_ORIENTATION_SPEED_DEG_S = 360.0
IDENTITY = ("Example", "XA-6", "SIM-0001", "1.0")


class SimulatedExampleController:
    """The controller's logic: :meth:`handle` gives the reply to one request line."""

    def __init__(self, kinematics: ExampleArmKinematics, cell, home_joints_deg=HOME_JOINTS_DEG):
        self.kin = kinematics
        self.cell = cell
        self.arm = cell.arm if cell.arm is not None else cell.attach_arm(kinematics)
        self.joints_deg = kinematics.check_joint_limits(home_joints_deg, "home_joints_deg")
        self.moves = 0
        self._reported: Pose | None = None  # the pose read at this standstill
        self.period_s: float | None = None  # the pose stream's period (controller clock), None: not streaming
        self._streamed_to_s = 0.0  # true time up to which the stream's samples were sent
        self._stream_rng = cell.device_rng("example_arm pose stream")
        #: samples still sent before the stream goes silent while on (a stall, for tests); None: no stall
        self.samples_left: int | None = None
        cell.timeline.arm = self.arm
        cell.timeline.jump(kinematics.flange_pose_from_joints(self.joints_deg), self.joints_deg)
        cell.move_flange_to(self.arm.true_flange_pose(self.joints_deg))

    def t_robot_s(self) -> float:
        return float(self.cell.controller_clock.stamp(self.cell.clock.now_s))

    def handle(self, line: bytes) -> bytes:
        try:
            verb, args = XA.parse(line, XA.VERBS)
        except XA.XaError as exc:
            return XA.fail("SYNTAX", str(exc))
        if verb == "HELLO":
            return XA.words_line("HELLO", *IDENTITY)
        if verb == "JOINTS":
            return XA.line("JOINTS", *self.joints_deg)
        if verb == "POSE":
            if self._reported is None:  # the controller's model at its joints, with its positioning noise
                nominal = self.kin.flange_pose_from_joints(self.joints_deg, check_limits=False)
                self._reported = self.cell.report_pose(nominal, self.cell.standstill_rng("example_arm controller"))
            p = self._reported
            return XA.line("POSE", self.t_robot_s(), *p.translation_mm, *p.quaternion_wxyz, decimals=9)
        if verb == "STREAM":
            return self._stream_on(args[0] * 1e-3)
        if verb == "UNSTREAM":
            samples, self.period_s = self._samples(), None
            return samples + XA.line("UNSTREAMED", self.t_robot_s(), decimals=9)
        return self._move(args)

    def _stream_on(self, period_s: float) -> bytes:
        """Start the stream: its first sample comes one period of the controller's clock later."""
        if not 0.001 <= period_s <= 0.1:
            return XA.fail("SYNTAX", f"STREAM period {period_s * 1e3:g} ms outside 1..100 ms")
        self.period_s, self._streamed_to_s = period_s, self.cell.clock.now_s
        self.cell.clock.advance(period_s / self.cell.controller_clock.rate)  # the arm stands meanwhile
        return self._samples() + XA.line("STREAMING", self.t_robot_s(), decimals=9)

    def _samples(self) -> bytes:
        """The SAMPLE lines of the stream since the last sent, up to the true time now."""
        T_now = self.cell.clock.now_s
        if self.period_s is None or T_now <= self._streamed_to_s:
            return b""
        s = self.cell.timeline.sample(self._streamed_to_s, T_now, self.period_s, self.cell.controller_clock,
                                      self._stream_rng)
        self._streamed_to_s = T_now
        n = len(s.tick) if self.samples_left is None else min(len(s.tick), self.samples_left)
        if self.samples_left is not None:
            self.samples_left -= n
        quats = quat_wxyz_from_matrix(s.R)
        return b"".join(XA.line("SAMPLE", s.tick[i], s.stamp_s[i], *s.t_mm[i], *quats[i], *s.joints_deg[i],
                                decimals=9) for i in range(n))

    def _move(self, args: list[float]) -> bytes:
        q = np.asarray(args[3:7])
        target = Pose.from_xyz_quat_wxyz(args[:3], q / np.linalg.norm(q))
        v_mm_s, v_deg_s = args[7], args[8]
        if not (0 < v_mm_s <= MAX_SPEED_MM_S and 0 < v_deg_s <= MAX_ORIENTATION_SPEED_DEG_S):
            return XA.fail("SPEED", f"speeds {v_mm_s} mm/s, {v_deg_s} deg/s outside 0..{MAX_SPEED_MM_S:g}, "
                                    f"0..{MAX_ORIENTATION_SPEED_DEG_S:g}")
        try:
            joints = self.kin.joints_from_flange_pose(target, seed_joints_deg=self.joints_deg)
        except InputError as exc:
            return XA.fail("REACH", str(exc))
        self.cell.timeline.move_linear(target, v_mm_s, v_deg_s, joints_deg=joints)  # the clock moves on
        self.joints_deg = joints
        self._reported = None  # a new standstill
        self.moves += 1
        self.cell.move_flange_to(self.arm.true_flange_pose(joints))
        return self._samples() + XA.line("DONE", self.t_robot_s())  # the move's samples first


def start_simulated_controller(kinematics: ExampleArmKinematics, cell) -> SimulatedDeviceServer:
    """A simulated controller on ``cell``, serving on a free port of 127.0.0.1 (``server.port``)."""
    controller = SimulatedExampleController(kinematics, cell)
    server = SimulatedDeviceServer(controller.handle, name="simulated example arm controller")
    server.controller = controller  # for tests
    return server.start()
