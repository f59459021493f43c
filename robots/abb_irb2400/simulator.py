"""A simulated IRB 2400 controller that serves the spherecal line protocol over a real
link, in one of three flavours (``SimulatedControllerSettings.transport``):

* ``tcp``: the serial server's line (``SpherecalSerial.mod``) carried over TCP on
  127.0.0.1 (``socket://``), as a serial device server would; a serial line has no
  sessions, so a reconnecting driver finds the controller as it left it;
* ``pty``: the serial server on a pseudo-terminal pair (the driver opens the slave
  device path);
* ``socket``: the IRC5 socket server (``SpherecalSocket.mod``) on 127.0.0.1
  (``socket://``): one connection at a time (others wait in the listen backlog), and
  every accepted connection is a new session, in which no target is staged.

The brand-free controller and its server live in the core
(:class:`spherecal.plugins.SimulatedController` and its server): moves by inverse kinematics from the current joints,
the cell's true arm, pose and joint noise, the sessions of a socket server, fault
injection (the connection closed mid-request among them). :class:`SimulatedIrb2400`
adds the IRB 2400's kinematics and its RAPID server's read loop:
:meth:`~SimulatedIrb2400.handle` is one turn of the loop (clear the line, read one, serve
it), and :meth:`~SimulatedIrb2400.read_timeout` and :meth:`~SimulatedIrb2400.restart`
model a read that ends without a line, so that tests can show a line is never served
twice (a loop that goes on with ``Serve line`` after such a read serves its last line
again: tests/robots/test_irb2400_no_replay.py).

The server's EGM position stream (``SpherecalEgm.mod``): ``SSTART`` and ``SSTOP``
start and stop a :class:`~.egm_sim.SimulatedEgmServer`, which sends ``EgmRobot``
messages over UDP to :attr:`SimulatedIrb2400.egm`'s ``destination`` (the UDPUC
device's remote address and port; the driver sets it in simulated runs). Each executed
``MOVL`` is a move in simulated time: its samples, covering the move's duration, are
all sent before its ``OK``. The poses come from ``egm_source`` (default: the
controller's own pose, held while standing and along each move's straight line) on the
simulated clock ``egm_clock`` (default: an internal one; see :mod:`.egm_sim`).

The server's programmed-line stamps (``SpherecalLine.mod``): ``LSTART`` (its reset flag
restarts the controller's clock, a RAPID clock: ``(T - T_reset) (1 + clock_drift_ppm
1e-6)``), ``LSTOP`` and ``LTIME``. While stamping, each executed ``MOVL`` is stamped, in
whole ms of that clock (rounded, as ``Round(ClkRead(...) * 1000)``), when its path on the
motion timeline passes the stamp's distance from its start (the arm's true
acceleration), plus ``start_latency_s`` and a normal jitter of ``start_jitter_s`` (the
trap's), and at its end in position (after the settle). The arm moves on the timeline with the controller's
``acceleration_mm_s2``, not with the acceleration the PC assumes: the simulated world
is not the PC's model. :attr:`SimulatedIrb2400.line_faults` injects a start stamp that
is not taken.

The controller's base frame (``settings.base_frame``, world_from_base), as a riser, an
inverted mount or a multi-robot cell configures it, is the core controller's: the server
reads and moves tool0 in wobj0, the WORLD frame, so ``GETP`` reports world poses and
``TGT`` targets are taken in world, while the joints, the kinematics and the cell stay in
the robot base.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from spherecal.plugins import ControllerServer, Faults, SimulatedController
from spherecal.plugins import line_protocol as P

from . import protocol as SP
from .config import SimulatedControllerSettings
from .egm_sim import ControllerMotionSource, PoseSource, SimulatedEgmServer
from .kinematics import Irb2400Kinematics

if TYPE_CHECKING:  # pragma: no cover
    from spherecal.plugins import SimulatedCell


class SimulatorServer(ControllerServer):
    """The server of a simulated IRB 2400: the core's, which also stops the EGM stream
    when it stops."""

    def stop(self) -> None:
        try:
            super().stop()
        finally:
            egm = getattr(self.controller, "egm", None)
            if egm is not None:
                egm.close()


__all__ = ["Faults", "LineFaults", "SimulatedIrb2400", "SimulatorServer", "start_simulator"]


@dataclass
class LineFaults:
    """Faults of the programmed-line stamps to inject; counters count down."""

    miss_start_next: int = 0  #: the next N stamped moves have no start stamp (the trap did not run)


class SimulatedIrb2400(SimulatedController):
    """Controller logic of a simulated IRB 2400 running SpherecalServer.mod."""

    def __init__(
        self,
        kinematics: Irb2400Kinematics | None = None,
        settings: SimulatedControllerSettings | None = None,
        cell: "SimulatedCell | None" = None,
        egm_source: PoseSource | None = None,
        egm_clock: Callable[[], float] | None = None,
        egm_controller_clock=None,
    ):
        super().__init__(kinematics or Irb2400Kinematics(), settings or SimulatedControllerSettings(), cell, 6)
        # (wobj0 is world: the core controller's base frame, settings.base_frame, puts GETP
        # (CRobT tool0 in wobj0) and TGT in the world frame)
        #: the default EGM pose source: the controller's pose, held and along each move
        self.egm_motion = ControllerMotionSource(self.nominal_flange_pose(), self.joints_deg,
                                                 egm_clock() if egm_clock is not None else 0.0)
        #: the EGM stream (its ``destination``, ``faults``, ``sent``, ``lost``)
        self.egm = SimulatedEgmServer(self.settings.egm, egm_source or self.egm_motion, clock=egm_clock,
                                      seed=self.settings.seed, report_frame=self.settings.base_frame,
                                      controller_clock=egm_controller_clock)
        line = self.settings.line
        self.line_rng = np.random.default_rng(line.seed if line.seed is not None else self.settings.seed)
        self.line_on = False  #: whether moves are stamped (LSTART .. LSTOP)
        self.line_clock_reset_s: float | None = None  #: true time of the clock's reset (None: never started)
        self.line_moves = 0  #: moves stamped since LSTART
        self.line_distance_mm = 0.0  #: the stamp's distance from each path's start, mm
        #: the last stamped move's stamps, ms: start, cruise end, in position
        self.line_stamps_ms: tuple[int | None, int | None, int | None] = (None, None, None)
        #: per stamped move: (true start, true end in position, its three stamps, ms)
        self.line_log: list[tuple] = []
        self.line_faults = LineFaults()

    # the programmed-line stamps ------------------------------------------------------------
    def line_clock_s(self, T_true_s: float) -> float:
        """The controller's clock (s since its reset) at true time ``T_true_s``; 0 while it
        was never started (RAPID's ClkRead of a clock not started)."""
        if self.line_clock_reset_s is None:
            return 0.0
        return (T_true_s - self.line_clock_reset_s) * (1.0 + self.settings.line.clock_drift_ppm * 1e-6)

    def line_clock_true_s(self, clock_s) -> np.ndarray:
        """The true time at which the controller's clock read ``clock_s`` (inverse of
        :meth:`line_clock_s`)."""
        return self.line_clock_reset_s + np.asarray(clock_s, dtype=float) / (
            1.0 + self.settings.line.clock_drift_ppm * 1e-6)

    def _serve_line(self, msg) -> bytes:
        if msg.kind == "LSTART":
            try:
                reset, self.line_distance_mm = SP.parse_line_start(msg)
            except P.ProtocolError as exc:
                return P.error_reply(msg.seq, P.ErrorCode.RANGE, str(exc))
            if reset:
                self.line_clock_reset_s = self.clock.now_s
            self.line_on, self.line_moves, self.line_stamps_ms = True, 0, (None, None, None)
            return P.ok_reply(msg.seq)
        if msg.kind == "LSTOP":
            self.line_on = False
            return P.ok_reply(msg.seq)
        return SP.line_time_reply(msg.seq, SP.LineStamps(self.line_moves, *self.line_stamps_ms))

    def _passes(self, T0: float, distance_mm: float, from_end: bool = False) -> float:
        """True time at which the move on the timeline that starts at ``T0`` passes
        ``distance_mm`` from its start (or before its end) (bisection on the timeline's own
        path fraction)."""
        seg = next(s for s in reversed(self.timeline.segments) if s.T0_s == T0 and s.kind == "move")
        goal = min(distance_mm / seg.length_mm, 1.0) if seg.length_mm > 0 else 0.0
        goal = 1.0 - goal if from_end else goal
        lo, hi = seg.T0_s, seg.T1_s
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if float(seg.fraction(mid)) < goal else (lo, mid)
        return hi

    def _stamp_move(self) -> None:
        """Stamp the move just executed (its timeline start and end in position)."""
        lm, line = self.last_move, self.settings.line
        T0 = lm["start_s"]
        T1 = T0 + lm["motion_s"] + lm["settle_s"]
        T_stamp = self._passes(T0, self.line_distance_mm)
        T_cruise_end = self._passes(T0, self.line_distance_mm, from_end=True)
        def trap(T: float) -> int:
            jitter = self.line_rng.normal(0.0, line.start_jitter_s) if line.start_jitter_s > 0 else 0.0
            return int(np.round(1e3 * self.line_clock_s(T + line.start_latency_s + jitter)))

        start: int | None = None
        if self.line_faults.miss_start_next > 0:
            self.line_faults.miss_start_next -= 1
        else:
            start = trap(T_stamp)
        cruise_end = trap(T_cruise_end)
        end = int(np.round(1e3 * self.line_clock_s(T1)))
        self.line_moves += 1
        self.line_stamps_ms = (start, cruise_end, end)
        self.line_log.append((T0, T1, start, cruise_end, end))

    # the EGM stream ------------------------------------------------------------------------
    def _serve(self, line: bytes) -> bytes:
        try:
            msg = SP.decode_stream_request(line)
        except P.ProtocolError as exc:
            return P.error_reply(None, P.ErrorCode.SYNTAX, str(exc))
        if msg is None:
            return super()._serve(line)
        self.requests.append(msg.kind)
        if msg.kind in ("LSTART", "LSTOP", "LTIME"):
            return self._serve_line(msg)
        if msg.kind == "SSTOP":
            self.egm.stop()
            return P.ok_reply(msg.seq)
        try:
            period_ms = SP.parse_stream_start(msg)
        except P.ProtocolError as exc:
            return P.error_reply(msg.seq, P.ErrorCode.RANGE, str(exc))
        try:
            self.egm.start(period_ms)
        except RuntimeError as exc:  # no UDPUC destination: the device is not configured
            return P.error_reply(msg.seq, SP.ERR_STREAM, str(exc))
        return P.ok_reply(msg.seq)

    def _move(self, msg: P.Message) -> bytes:
        """The core's move; an executed move also streams its samples (before the reply)."""
        moves, start_joints, start_pose = self.moves, self.joints_deg.copy(), self.nominal_flange_pose()
        self.egm.pause()  # simulated time stands (internal clock) until the move is done
        T0 = self.egm.now_true_s()
        try:
            reply = super()._move(msg)
        finally:
            if self.moves > moves:
                duration = self.last_move["duration_s"]
                self.egm_motion.add_move(T0, duration, start_pose, self.nominal_flange_pose(), start_joints,
                                         self.joints_deg)
                self.egm.move_done(T0, duration)
                if self.line_on:
                    self._stamp_move()
            else:
                self.egm.resume()
        return reply

    def jog(self, joints_deg) -> None:
        super().jog(joints_deg)
        self.egm_motion.hold(self.egm.now_true_s(), self.nominal_flange_pose(), self.joints_deg)

    # the RAPID server's read loop -------------------------------------------------------
    # SpherecalServer.mod loops: ``line := "";``, ``line := ReadStr(channel
    # \Time:=WAIT_MAX);``, serve the line. A read that ends without a line (the
    # ERR_DEV_MAXTIME timeout, or the program stopped in the read and started again)
    # serves nothing; the loop reads again. Class attributes are the initial values.
    line: bytes = b""  #: the RAPID ``line`` variable: the last line read, b"" after a failed read
    reads_without_line: int = 0  #: reads that ended without a line (timeouts, restarts)

    def handle(self, line: bytes) -> bytes:
        """One turn of the server's loop with ``line`` read: the reply to it (both with
        their LF)."""
        reply = self._serve_read(line)
        assert reply is not None  # a line read is always answered
        return reply

    def read_timeout(self) -> bytes | None:
        """The read ends without a line (``ERR_DEV_MAXTIME``): the server logs it and
        reads again. Returns what the server sends (None: nothing; only a model of the
        old server's ``TRYNEXT`` sends something, see the tests)."""
        return self._serve_read(None)

    def restart(self, pp_to_main: bool = False) -> bytes | None:
        """The operator stops the program and starts it again while the server waits
        for a request (where it spends its time between requests): the read starts
        again and nothing is served. With ``pp_to_main`` the program is reset first: the
        module's data return to their initial values, so no target is staged (the
        server also clears its input buffer, which this class does not hold). Returns
        what the server sends, as :meth:`read_timeout`. A stop during a move is not
        modelled: the controller finishes an interrupted move on restart."""
        if pp_to_main:
            self.staged = None
            self._reached = None
            self.line = b""
        return self._serve_read(None)

    def _serve_read(self, line: bytes | None) -> bytes | None:
        """One turn of the loop; ``line`` is what the read returned, None if it ended
        without a line."""
        self.line = b""  # line := "";
        if line is None:  # the read failed: haveLine is FALSE, nothing is served
            self.reads_without_line += 1
            return None
        self.line = line  # line := ReadStr(...);
        return self._serve(self.line)


def start_simulator(
    kinematics: Irb2400Kinematics | None = None,
    settings: SimulatedControllerSettings | None = None,
    cell: "SimulatedCell | None" = None,
    egm_source: PoseSource | None = None,
    egm_clock: Callable[[], float] | None = None,
    egm_controller_clock=None,
) -> SimulatorServer:
    """Start a simulated IRB 2400 controller on the settings' transport; returns the
    running server (its ``url`` is the driver's port). ``egm_source``, ``egm_clock`` and
    ``egm_controller_clock``: the EGM stream's pose source, simulated clock and the
    controller's clock (:mod:`.egm_sim`)."""
    settings = settings or SimulatedControllerSettings()
    controller = SimulatedIrb2400(kinematics, settings, cell, egm_source=egm_source, egm_clock=egm_clock,
                                  egm_controller_clock=egm_controller_clock)
    return SimulatorServer(controller, settings.transport).start()
