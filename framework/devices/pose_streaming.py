"""What the core may ask of a robot that streams its pose while ordinary moves run.

A controller that can stream (an ABB IRC5 with Externally Guided Motion, a UR over RTDE,
a KUKA over RSI) sends the measured flange pose every few milliseconds, stamped by its
own clock, while the robot executes the usual linear moves. A robot plugin that offers
this implements :class:`PoseStreamingRobot` on top of :class:`~spherecal.devices.contract.Robot`:
the core starts a stream before a sweep, moves, and stops it, getting a
:class:`~spherecal.core.streams.PoseStream` on the robot's clock (``t_robot_s``: the
controller's stamps, never the PC's receive time) with the controller's sequence numbers.

A stream that misbehaves ends with a :class:`PoseStreamError` that names what happened
(:class:`PoseStreamStalled`: no sample for longer than the configured time while
streaming; :class:`PoseStreamClockError`: the controller's clock went backwards or jumped)
and keeps what was received before the fault in ``stream``, so a run can stop with its
data kept; nothing after the fault is used.

A controller that cannot stream (an S4C+) may still offer the contract by computing the
poses: the programmed line between a move's two ends, timed by the controller's own
stamps of the move's start and end. Such a stream says what its poses assume in
:attr:`~spherecal.core.streams.PoseStream.assumption`, and the robot says it before any
stream runs through an optional ``pose_stream_assumption()`` method
(:func:`pose_stream_assumption`), so that a recording's header can carry it into the
result (the recording provenance's ``poses_assumed``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from spherecal.core.errors import DeviceError

if TYPE_CHECKING:  # pragma: no cover
    from spherecal.core.streams import PoseStream

__all__ = ["PoseStreamClockError", "PoseStreamCounts", "PoseStreamError", "PoseStreamStalled", "PoseStreamingRobot",
           "pose_stream_assumption"]


@dataclass(frozen=True)
class PoseStreamCounts:
    """What a pose stream delivered, by the controller's sequence numbers.

    ``received``: samples kept; ``lost``: sequence numbers never received between the
    first and the last kept; ``late``: samples that arrived after a newer one (kept, in
    their place); ``duplicates``: a sequence number received again (dropped);
    ``rejected``: samples dropped because they did not fit (a late sample whose stamp
    does not lie between its neighbours', a message of another type, or one that did not
    decode)."""

    received: int = 0
    lost: int = 0
    late: int = 0
    duplicates: int = 0
    rejected: int = 0

    def text(self) -> str:
        return (f"{self.received} samples received, {self.lost} lost, {self.late} late, "
                f"{self.duplicates} duplicated, {self.rejected} rejected")


class PoseStreamError(DeviceError):
    """A pose stream that ended on a fault or could not run. ``stream`` holds the samples
    received before the fault (a :class:`~spherecal.core.streams.PoseStream`, or None
    when fewer than two came), ``counts`` what was delivered."""

    def __init__(self, message: str, stream: "PoseStream | None" = None, counts: PoseStreamCounts | None = None):
        super().__init__(message)
        self.stream = stream
        self.counts = counts or PoseStreamCounts()


class PoseStreamStalled(PoseStreamError):
    """No sample came for longer than the stall time while the stream was on."""


class PoseStreamClockError(PoseStreamError):
    """The controller's stamps went backwards, or jumped forward by more than the sequence
    numbers allow: the samples after the jump are on another clock and are not kept."""


@runtime_checkable
class PoseStreamingRobot(Protocol):
    """A robot that can stream its measured flange pose while :meth:`move_linear` runs
    (optional, beside :class:`~spherecal.devices.contract.Robot`).

    Poses are ``base_from_flange``, mm (the stream's ``R`` and ``t_mm``; quaternions, where
    stored, (w, x, y, z)); joints in degrees, controller convention; stamps in seconds on
    the controller's clock."""

    def can_stream_poses(self) -> bool:
        """Whether this robot is configured to stream (False: :meth:`start_pose_stream`
        refuses, saying what to configure)."""

    def start_pose_stream(self) -> None:
        """Start the stream and return once its first sample has come (and was checked
        against the controller's own pose). Raises :class:`PoseStreamError` (or a
        :class:`~spherecal.core.errors.DeviceError`) when it cannot, nothing having moved."""

    def stop_pose_stream(self) -> "PoseStream":
        """Stop the stream and return every sample received since the start, in sequence
        order with the controller's stamps and sequence numbers. Raises
        :class:`PoseStreamError` (with what was kept) when the stream ended on a fault."""

    def pose_stream_counts(self) -> PoseStreamCounts:
        """What the current (or last) stream has delivered so far."""


def pose_stream_assumption(robot: Any) -> str | None:
    """What the poses of ``robot``'s stream assume when they are not measured (the
    robot's optional ``pose_stream_assumption()``: a text starting with
    :data:`~spherecal.core.streams.PROGRAMMED_LINE_ASSUMPTION`), or None: measured (or
    the robot does not say). For a recording's provenance (``poses_assumed``), before the
    first stream runs."""
    method = getattr(robot, "pose_stream_assumption", None)
    if not callable(method):
        return None
    found = method()
    return str(found) if found else None
