"""The PC side of an EGM position stream: a UDP socket read in a thread of its own.

The thread drains the socket every cycle (every datagram waiting is read and decoded,
so no backlog builds up and nothing goes stale in the buffer) and keeps each sample's
**controller stamp** (``feedBack.time``, microseconds; ``header.tm``, milliseconds, when
a message has no feedback clock), never the PC's receive time. Sequence numbers
(``header.seqno``, uint32; a wrap adds 2**32) count the samples lost on the way, the
samples that arrive after a newer one (``late``, put back in their place) and those
received twice.

The stream ends on a fault, keeping what came before it:

* **a stall**: no sample for ``stall_timeout_s`` (PC clock) while the stream is on
  (:class:`~spherecal.plugins.PoseStreamStalled`);
* **a clock jump**: a newer sample (by sequence number) whose stamp does not increase,
  or whose step differs from ``seqno step x sample period`` by more than
  ``clock_jump_tolerance_ms`` (:class:`~spherecal.plugins.PoseStreamClockError`): the
  samples after it are on another clock and are not kept.

:meth:`EgmReceiver.feed` is the per-message logic, callable without a socket (tests
drive it with their own PC clock through :meth:`EgmReceiver.check_stall`).
"""

from __future__ import annotations

import errno
import select
import socket
import threading
import time
from typing import Callable

import numpy as np

from spherecal.plugins import PoseStream, PoseStreamClockError, PoseStreamCounts, PoseStreamError, PoseStreamStalled

from .config import EgmSettings
from .egm_messages import EgmDecodeError, EgmSample, decode_egm_robot

__all__ = ["EgmReceiver"]

_U32 = 2**32
#: Header message types a robot controller never sends (a sensor's commands and corrections).
_NOT_FROM_A_CONTROLLER = frozenset({1, 3, 4})
_MAX_DATAGRAM = 65535


class EgmReceiver:
    """Receives one EGM stream: :meth:`open`, then :meth:`wait_first`, ...,
    :meth:`finish`, then :meth:`stream` (raises the fault that ended it, with the samples
    kept). ``wall_clock`` is the PC clock of the stall check (``time.monotonic``)."""

    def __init__(self, settings: EgmSettings, *, name: str = "EGM", wall_clock: Callable[[], float] = time.monotonic,
                 decode: Callable[[bytes], EgmSample] = decode_egm_robot):
        self.settings = settings
        self.name = name
        self._clock = wall_clock
        self._decode = decode
        self._period_s = settings.sample_period_ms * 1e-3
        self._tolerance_s = settings.clock_jump_tolerance_ms * 1e-3
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self._first = threading.Event()
        self.error: PoseStreamError | None = None  #: the fault that ended the stream, if any
        self.receive_buffer_bytes = 0  #: the receive buffer the system granted
        self.clock_field: str | None = None  #: "feedBack.time" or "header.tm": where the stamps come from
        self._ending = False  # the stop command is on its way: silence is no stall
        self._last_rx: float | None = None  # PC clock of the last datagram
        # per kept sample: unwrapped seqno, stamp (s), translation, quaternion, joints
        self._u: list[int] = []
        self._t: list[float] = []
        self._xyz: list[tuple[float, float, float]] = []
        self._q: list[tuple[float, float, float, float]] = []
        self._joints: list[tuple[float, ...] | None] = []
        self._was_late: list[bool] = []
        self._seen: set[int] = set()
        self._newest: tuple[int, int, float] | None = None  # (raw seqno, unwrapped, stamp) of the newest
        self._tm_last: tuple[int, int] | None = None  # (raw tm, unwrapped tm) when stamping by header.tm
        self._late = self._duplicates = self._rejected = 0

    # --- socket and thread -------------------------------------------------------------------
    def open(self) -> "EgmReceiver":
        """Bind the UDP socket (``settings.address``, ``settings.port``) and start the thread."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.settings.receive_buffer_bytes)
            sock.bind((self.settings.address, self.settings.port))
        except OSError as exc:
            sock.close()
            hint = " (another program, or another robot, listens there)" if exc.errno == errno.EADDRINUSE else ""
            raise PoseStreamError(f"{self.name}: cannot listen for the EGM stream on UDP "
                                  f"{self.settings.address}:{self.settings.port}: {exc}{hint}; check robot.egm.port "
                                  "and robot.egm.address") from exc
        sock.setblocking(False)
        self.receive_buffer_bytes = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        self._sock = sock
        self._thread = threading.Thread(target=self._run, name="spherecal-egm-receiver", daemon=True)
        self._thread.start()
        return self

    @property
    def port(self) -> int:
        """The UDP port the socket is bound to (the configured one, or the one the system chose for 0)."""
        if self._sock is None:
            raise PoseStreamError(f"{self.name}: the EGM receiver is not open")
        return self._sock.getsockname()[1]

    def _run(self) -> None:
        poll_s = min(self.settings.stall_timeout_s / 4.0, 0.02)
        while not self._stop.is_set():
            ready, _, _ = select.select([self._sock], [], [], poll_s)
            if ready:
                self.drain()
            self.check_stall(self._clock())

    def drain(self) -> int:
        """Read and decode every datagram waiting on the socket now; returns how many."""
        n = 0
        sock = self._sock
        while sock is not None:
            try:
                data = sock.recv(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # closed under us
                break
            n += 1
            self.feed(data, self._clock())
        return n

    def wait_first(self, timeout_s: float) -> bool:
        """Whether a first sample has come within ``timeout_s``."""
        return self._first.wait(timeout_s)

    def finish(self, quiet_s: float) -> None:
        """The stream is being stopped: wait until nothing has come for ``quiet_s`` (the
        samples on their way), stop the thread, read what is left, close the socket."""
        with self._lock:
            self._ending = True
        start = self._clock()
        while self._sock is not None:
            last = self._last_rx if self._last_rx is not None else start
            if self._clock() - max(last, start) >= quiet_s:
                break
            time.sleep(min(quiet_s / 4.0, 0.005))
        self.close()

    def close(self) -> None:
        """Stop the thread and close the socket (what was received is kept). Idempotent."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        if self._sock is not None:
            self.drain()
            self._sock.close()
            self._sock = None

    # --- the per-message logic ---------------------------------------------------------------------
    def feed(self, data: bytes, now: float) -> None:
        """One datagram received at PC time ``now``."""
        with self._lock:
            self._last_rx = now
            if self.error is not None:
                return  # the stream has ended: nothing after the fault is used
            try:
                sample = self._decode(data)
            except EgmDecodeError:
                self._rejected += 1
                return
            self._take(sample)

    def _stamp(self, s: EgmSample) -> float | None:
        if s.time_s is not None and self.clock_field != "header.tm":
            self.clock_field = "feedBack.time"
            return s.time_s
        if s.tm_ms is None or self.clock_field == "feedBack.time":
            return None
        self.clock_field = "header.tm"
        raw = int(s.tm_ms) % _U32
        if self._tm_last is None:
            unwrapped = raw
        else:
            d = (raw - self._tm_last[0]) % _U32
            unwrapped = self._tm_last[1] + (d if d < _U32 // 2 else d - _U32)
        if self._tm_last is None or unwrapped > self._tm_last[1]:
            self._tm_last = (raw, unwrapped)
        return unwrapped * 1e-3

    def _take(self, s: EgmSample) -> None:
        if s.mtype in _NOT_FROM_A_CONTROLLER or not _finite_unit(s):
            self._rejected += 1
            return
        t = self._stamp(s)
        if t is None:
            self._rejected += 1
            return
        raw = int(s.seqno) % _U32
        if self._newest is None:
            u = raw
        else:
            d = (raw - self._newest[0]) % _U32
            u = self._newest[1] + (d if d < _U32 // 2 else d - _U32)
        if u in self._seen:
            self._duplicates += 1
            return
        late = self._newest is not None and u < self._newest[1]
        if self._newest is not None and not late and not self._clock_step_ok(u, t):
            return
        self._late += late
        self._was_late.append(late)
        self._seen.add(u)
        self._u.append(u)
        self._t.append(t)
        self._xyz.append(s.translation_mm)
        self._q.append(s.quaternion_wxyz)
        self._joints.append(s.joints_deg)
        if self._newest is None or u > self._newest[1]:
            self._newest = (raw, u, t)
        self._first.set()

    def _clock_step_ok(self, u: int, t: float) -> bool:
        """Check the stamp of a newer sample against the newest's; end the stream if not."""
        _, u0, t0 = self._newest
        steps = u - u0
        dt = t - t0
        if dt > 0 and abs(dt - steps * self._period_s) <= self._tolerance_s:
            return True
        what = "went backwards" if dt <= 0 else "jumped"
        self.error = PoseStreamClockError(
            f"{self.name}: the controller's clock {what} at EGM seqno {u % _U32}: stamp {t:.6f} s after "
            f"{t0:.6f} s at seqno {u0 % _U32} ({steps} sample(s) of {self._period_s * 1e3:g} ms apart: a step of "
            f"{dt * 1e3:.3f} ms, allowed {steps * self._period_s * 1e3:.3f} +- "
            f"{self.settings.clock_jump_tolerance_ms:g} ms, robot.egm.clock_jump_tolerance_ms); the stream ended "
            "there and the samples before it are kept")
        return False

    def check_stall(self, now: float) -> None:
        """End the stream as stalled when no sample has come for ``stall_timeout_s`` at PC
        time ``now`` (after the first sample, and not while the stream is being stopped)."""
        with self._lock:
            if self.error is not None or self._ending or self._last_rx is None or not self._u:
                return
            quiet = now - self._last_rx
            if quiet <= self.settings.stall_timeout_s:
                return
            newest = self._newest[1] % _U32 if self._newest is not None else "-"
            self.error = PoseStreamStalled(
                f"{self.name}: the EGM pose stream stalled: no sample for {quiet:.3f} s (more than "
                f"robot.egm.stall_timeout_s = {self.settings.stall_timeout_s:g} s) after seqno {newest}; the stream "
                "ended there and the samples before it are kept")

    def newest(self) -> EgmSample:
        """The newest sample kept (by sequence number)."""
        with self._lock:
            if not self._u:
                raise PoseStreamError(f"{self.name}: no EGM sample received yet")
            i = int(np.argmax(self._u))
            return EgmSample(seqno=self._u[i] % _U32, tm_ms=None, mtype=2, translation_mm=self._xyz[i],
                             quaternion_wxyz=self._q[i], joints_deg=self._joints[i], time_s=self._t[i])

    # --- results ---------------------------------------------------------------------------------
    def _ordered(self) -> tuple[np.ndarray, int]:
        """Indices of the kept samples in sequence order, and how many late samples were
        dropped because their stamp does not lie between their neighbours' (the samples
        that came in order have increasing stamps: checked as they came)."""
        order = np.argsort(np.asarray(self._u, dtype=np.int64), kind="stable")
        t = np.asarray(self._t, dtype=float)[order]
        late = np.asarray(self._was_late, dtype=bool)[order]
        keep = np.ones(len(order), dtype=bool)
        in_order = np.flatnonzero(~late)
        for i in np.flatnonzero(late):
            k = np.searchsorted(in_order, i)
            before = t[in_order[k - 1]] if k > 0 else -np.inf
            after = t[in_order[k]] if k < len(in_order) else np.inf
            keep[i] = before < t[i] < after
        t_kept = t[keep]
        if np.any(np.diff(t_kept) <= 0):  # two late samples in one gap out of order: keep neither
            bad = np.zeros(len(t_kept), dtype=bool)
            k = np.flatnonzero(np.diff(t_kept) <= 0)
            bad[k] = bad[k + 1] = True
            kept_idx = np.flatnonzero(keep)
            keep[kept_idx[bad & late[keep]]] = False
        return order[keep], int(len(order) - keep.sum())

    def _counts(self, kept: int, misfits: int) -> PoseStreamCounts:
        span = (max(self._u) - min(self._u) + 1) if self._u else 0
        return PoseStreamCounts(received=kept, lost=span - len(self._seen), late=self._late - misfits,
                                duplicates=self._duplicates, rejected=self._rejected + misfits)

    def counts(self) -> PoseStreamCounts:
        """What has been delivered so far, as :meth:`stream` would keep it."""
        with self._lock:
            idx, misfits = self._ordered()
            return self._counts(len(idx), misfits)

    def stream(self) -> PoseStream:
        """Every sample kept, in sequence order (``seq`` unwrapped: a wrap adds 2**32),
        stamps on the controller's clock. Raises the fault that ended the stream with
        this stream attached, or :class:`~spherecal.plugins.PoseStreamError` when fewer
        than two samples came."""
        with self._lock:
            idx, misfits = self._ordered()
            counts = self._counts(len(idx), misfits)
            stream = None
            if len(idx) >= 2:
                joints = [self._joints[i] for i in idx]
                have_joints = all(j is not None and len(j) == len(joints[0]) for j in joints)
                stream = PoseStream.from_quaternions(
                    np.asarray(self._t)[idx], np.asarray(self._xyz)[idx], np.asarray(self._q)[idx],
                    joints_deg=np.asarray(joints, dtype=float) if have_joints else None,
                    seq=np.asarray(self._u, dtype=np.int64)[idx])
            error = self.error
        if error is not None:
            error.stream, error.counts = stream, counts
            raise error
        if stream is None:
            raise PoseStreamError(f"{self.name}: the EGM stream delivered {len(idx)} sample(s); a pose stream needs "
                                  f"at least 2 ({counts.text()})", None, counts)
        return stream


def _finite_unit(s: EgmSample) -> bool:
    """A finite pose with a unit quaternion (within 1e-3)."""
    q = np.asarray(s.quaternion_wxyz, dtype=float)
    ok = np.all(np.isfinite(s.translation_mm)) and np.all(np.isfinite(q)) and abs(np.linalg.norm(q) - 1.0) <= 1e-3
    return bool(ok and (s.joints_deg is None or np.all(np.isfinite(s.joints_deg))))
