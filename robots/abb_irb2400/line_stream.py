"""The programmed-line pose stream on the driver's side (``robot.pose_stream``; see
:mod:`.programmed_line` for the poses and docs/robot-abb-irb2400.md, "Programmed-line
poses").

:class:`ProgrammedLineStreaming` is mixed into :class:`~.driver.AbbIrb2400Robot`:
``LSTART`` turns stamping on (the first stream of a connection restarts the
controller's clock, so that every stream of a run is on one clock), every move then
made is followed by ``LTIME``, whose stamps are checked (the move counted, both stamps
taken, the clock within the range RAPID's num holds exactly, the duration that of the
profile assumed), and ``LSTOP`` turns it off; the stream is computed from the moves
stamped. A stamp that fails ends the stream's data there: later moves are not used, and
:meth:`stop_line_stream` raises the fault with the stream of the moves before it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from spherecal.plugins import DeviceError, Pose, PoseStreamClockError, PoseStreamCounts, PoseStreamError

from . import protocol as SP
from .config import ProgrammedLineSettings
from .programmed_line import ProgrammedMove, check_move_stamps, programmed_line_stream

if TYPE_CHECKING:  # pragma: no cover - the streams' model is loaded when a stream is taken
    from spherecal.plugins import PoseStream

__all__ = ["ProgrammedLineStreaming"]


class ProgrammedLineStreaming:
    """The programmed-line stream's part of the driver (see the module docstring)."""

    _line: list[ProgrammedMove] | None = None  #: the moves stamped by the running stream, or None
    _line_fault: PoseStreamError | None = None  #: the fault that ended the running stream's data
    _line_clock_started = False  #: whether this connection has restarted the controller's clock
    _line_last: PoseStream | None = None  #: the last stream computed (for its counts)

    def _line_settings(self) -> ProgrammedLineSettings:
        settings = self.config.pose_stream
        if settings is None:  # pragma: no cover - the driver dispatches only when configured
            raise PoseStreamError(f"{self.name}: robot.pose_stream is not configured")
        return settings

    def pose_stream_assumption(self) -> str | None:
        """What this robot's stream assumes (:func:`spherecal.devices.pose_streaming.pose_stream_assumption`):
        the programmed line's assumption when ``robot.pose_stream`` is set, else None
        (EGM measures)."""
        settings = self.config.pose_stream
        return settings.assumption() if settings is not None else None

    def start_line_stream(self) -> None:
        """``LSTART``: stamp every following move. PoseStreamError when the server cannot
        (SpherecalLine.mod not loaded); nothing moves."""
        self._line_settings()
        self.check_open()
        if self._line is not None:
            raise PoseStreamError(f"{self.name}: a pose stream is already running; stop it first")
        reset = not self._line_clock_started
        try:
            distance = self._line_settings().stamp_distance_mm
            self._exchange("LSTART", lambda seq: SP.line_start_request(seq, reset, distance), "OK")
        except DeviceError as exc:
            raise PoseStreamError(
                f"{exc}. The server must be SpherecalServer.mod of this package with SpherecalLine.mod loaded "
                "beside it (docs/robot-abb-irb2400.md, 'Programmed-line poses')") from exc
        self._line_clock_started = True
        self._line, self._line_fault, self._line_last = [], None, None

    def moved(self, start: Pose, target: Pose, speed_mm_s: float, orientation_speed_deg_s: float) -> None:
        """After a move while the stream runs: its stamps (``LTIME``), checked, kept. A
        fault is kept for :meth:`stop_line_stream` and ends the stream's data."""
        if self._line is None or self._line_fault is not None:
            return
        try:
            self._line.append(self._stamped(start, target, speed_mm_s, orientation_speed_deg_s))
        except PoseStreamError as exc:
            self._line_fault = exc
        except DeviceError as exc:
            self._line_fault = PoseStreamError(f"{self.name}: the move's stamps could not be read: {exc}")

    def _stamped(self, start: Pose, target: Pose, speed_mm_s: float, orientation_speed_deg_s: float) -> ProgrammedMove:
        settings = self._line_settings()
        msg = self._exchange("LTIME", SP.line_time_request, "T")
        stamps = SP.parse_line_time_reply(msg)
        n = len(self._line) + 1
        where = f"{self.name}: move {n} of the programmed-line stream"
        if stamps.moves != n:
            raise PoseStreamError(
                f"{where}: the controller has stamped {stamps.moves} moves since LSTART, not {n}: the program was "
                "restarted or a move was not stamped (SpherecalLine.mod)")
        missing = [what for what, v in (("its start (the first TriggInt did not fire)", stamps.start_ms),
                                        ("its path's end (the second TriggInt did not fire)", stamps.cruise_end_ms),
                                        ("its end in position", stamps.end_ms)) if v is None]
        if missing:
            raise PoseStreamError(f"{where}: the controller has no stamp of {' and '.join(missing)}")
        if stamps.end_ms > SP.MAX_CLOCK_MS:
            raise PoseStreamClockError(
                f"{where}: the controller's clock reads {stamps.end_ms} ms, beyond the {SP.MAX_CLOCK_MS} ms RAPID's "
                "num holds exactly (2 h 19 min after the clock's restart at this connection's first stream): "
                "connect again to restart it")
        if self._line and stamps.start_ms * 1e-3 < self._line[-1].t_end_s:
            raise PoseStreamClockError(
                f"{where}: its start stamp {stamps.start_ms} ms comes before the previous move's end "
                f"{self._line[-1].t_end_s * 1e3:.0f} ms: the controller's clock went back (restarted)")
        move = ProgrammedMove(start, target, float(speed_mm_s), float(orientation_speed_deg_s),
                              stamps.start_ms * 1e-3, stamps.cruise_end_ms * 1e-3, stamps.end_ms * 1e-3,
                              settings.stamp_distance_mm)
        check_move_stamps(move, settings, where)
        return move

    def stop_line_stream(self) -> PoseStream:
        """``LSTOP``, and the stream computed from the moves stamped. Raises the fault
        that ended the stream's data (with the stream of the moves before it, or None), a
        failed stop, or PoseStreamError when no move was stamped."""
        moves, fault = self._line, self._line_fault
        if moves is None:
            raise PoseStreamError(f"{self.name}: no pose stream is running (start_pose_stream first)")
        self._line, self._line_fault = None, None
        failure: DeviceError | None = None
        try:
            self._exchange("LSTOP", SP.line_stop_request, "OK")
        except DeviceError as exc:
            failure = exc
        stream = programmed_line_stream(moves, self._line_settings()) if moves else None
        self._line_last = stream
        counts = self.pose_stream_counts()
        if fault is not None:
            fault.stream, fault.counts = stream, counts
            raise fault
        if failure is not None:
            raise PoseStreamError(f"{self.name}: the programmed-line stream could not be stopped: {failure}", stream,
                                  counts) from failure
        if stream is None:
            raise PoseStreamError(f"{self.name}: no move was made while the programmed-line stream ran: its poses "
                                  "come from the moves' stamps, so a stream without a move has none", None, counts)
        return stream

    def line_stream_counts(self) -> PoseStreamCounts:
        """Samples computed so far (the running stream's moves, else the last stream's)."""
        if self._line:
            return PoseStreamCounts(received=programmed_line_stream(self._line, self._line_settings()).n)
        return PoseStreamCounts(received=self._line_last.n if self._line_last is not None else 0)

    def _close_line_stream(self) -> None:
        """Closing: turn stamping off (best effort)."""
        if self._line is None:
            return
        self._line = None
        try:
            if not self._closed:
                self._exchange("LSTOP", SP.line_stop_request, "OK")
        except DeviceError:
            pass  # closing: the link may be gone already
