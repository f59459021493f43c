"""The simulated controller's EGM position stream: ``EgmRobot`` messages over UDP.

While streaming, the simulated controller samples the arm every sample period of **its
own clock** and sends one message per sample to the configured destination (the UDPUC
device's remote address and port). Each sample's pose comes from a **source**, a
callable ``source(T_true_s) -> (R (N, 3, 3), t_mm (N, 3), joints_deg (N, 6) | None)``
of simulated true time; the default (:class:`ControllerMotionSource`) holds the
controller's pose while the arm stands and follows each move's straight line at
constant speed, and a caller may give its own (a motion timeline with the arm's path
noise). Poses are those the controller reports: ``base_from_flange`` of its model, mm,
or world poses when the controller has a base frame (``report_frame``, world_from_base).

Time. Simulated true time ``T`` comes from ``clock()`` when one is given (a simulated
clock the cell advances); otherwise from an internal clock that runs with the PC's
clock while the arm stands and jumps by a move's simulated duration when a move is
executed. A move happens in simulated time: :meth:`SimulatedEgmServer.move_done` sends
every sample covering it at once (paced only so that a receive buffer keeps up), before
the move's reply, so that a receiver has them when the move returns. Between moves a
thread sends the samples of the standing arm as their time comes.

The controller's clock: ``t_ctrl = clock_epoch_s + T (1 + clock_drift_ppm 1e-6)``, or
``controller_clock.stamp(T)`` when a simulated world gives its controller a clock (an
object with ``stamp(T_true_s)`` and ``rate``, a ``spherecal.sim`` ``DeviceClock``), plus
any injected jump; samples are taken every ``sample_period_ms`` of that clock, stamped
``t_ctrl`` plus a normal jitter (``stamp_jitter_s``) to the microsecond
(``feedBack.time``) and in whole milliseconds modulo 2**32 (``header.tm``). Samples are
lost at random (``drop_probability``), and :class:`EgmFaults` injects a burst of
losses, a stall (the controller goes silent while streaming), a clock jump, samples
out of order and duplicated.
"""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from spherecal.plugins import Pose, matrix_from_rotvec, quat_wxyz_from_matrix, rotvec_from_matrix

from .config import SimulatedEgmSettings
from .egm_messages import MSGTYPE_DATA, EgmSample, encode_egm_robot

__all__ = ["ControllerMotionSource", "EgmFaults", "PoseSource", "SimulatedEgmServer"]

#: ``source(T_true_s (N,)) -> (R (N, 3, 3), t_mm (N, 3), joints_deg (N, J) or None)``.
PoseSource = Callable[[np.ndarray], "tuple[np.ndarray, np.ndarray, np.ndarray | None]"]

_U32 = 2**32
#: Datagrams sent back to back before the sender yields (a receive buffer keeps up).
_BURST = 32
_BURST_PAUSE_S = 0.0005


@dataclass
class EgmFaults:
    """Stream faults to inject, changeable while streaming; counters count down."""

    drop_next: int = 0  #: a burst: the next N samples are lost
    #: the controller goes silent after N more samples while it goes on streaming (None: no stall)
    stall_after: int | None = None
    clock_jump_s: float = 0.0  #: added to the controller's clock from the next sample on, once
    swap_next: int = 0  #: the next N pairs of samples leave in the wrong order (the first arrives late)
    duplicate_next: int = 0  #: the next N samples are sent twice


class ControllerMotionSource:
    """The default pose source: the controller's own pose, held while the arm stands,
    along each move's straight line at constant speed (translation linear, rotation by
    the constant-rate rotation between the ends) for the move's simulated duration.
    Joints are interpolated linearly between the move's end joints: exact at the ends,
    an approximation between (a straight line in space is not one in joints)."""

    def __init__(self, pose: Pose, joints_deg: np.ndarray, T_true_s: float = 0.0):
        # segments (T0, T1, R0, t0, rotvec of R0^T R1, t1 - t0, q0, q1); a hold is T0 == T1
        self._segments: list[tuple] = []
        self.hold(T_true_s, pose, joints_deg)

    def hold(self, T_true_s: float, pose: Pose, joints_deg) -> None:
        """From ``T_true_s`` on, the arm stands at ``pose`` (jogged there)."""
        q = np.asarray(joints_deg, dtype=float)
        self._segments.append((float(T_true_s), float(T_true_s), pose.rotation_matrix, pose.translation,
                               np.zeros(3), np.zeros(3), q, q))

    def add_move(self, T_true_s: float, duration_s: float, start: Pose, end: Pose, q_start, q_end) -> None:
        """A straight move from ``start`` to ``end`` over ``[T_true_s, T_true_s + duration_s]``."""
        R0, R1 = start.rotation_matrix, end.rotation_matrix
        self._segments.append((float(T_true_s), float(T_true_s) + float(duration_s), R0, start.translation,
                               rotvec_from_matrix(R0.T @ R1), end.translation - start.translation,
                               np.asarray(q_start, dtype=float), np.asarray(q_end, dtype=float)))

    def __call__(self, T_true_s: np.ndarray):
        T = np.atleast_1d(np.asarray(T_true_s, dtype=float))
        starts = np.array([s[0] for s in self._segments])
        k = np.clip(np.searchsorted(starts, T, side="right") - 1, 0, len(starts) - 1)
        R = np.empty((len(T), 3, 3))
        t = np.empty((len(T), 3))
        q = np.empty((len(T), len(self._segments[0][6])))
        for j in np.unique(k):
            T0, T1, R0, t0, phi, dt, q0, q1 = self._segments[j]
            sel = k == j
            s = np.clip((T[sel] - T0) / (T1 - T0), 0.0, 1.0) if T1 > T0 else np.ones(int(sel.sum()))
            R[sel] = R0 @ matrix_from_rotvec(s[:, None] * phi)
            t[sel] = t0 + s[:, None] * dt
            q[sel] = q0 + s[:, None] * (q1 - q0)
        return R, t, q


class SimulatedEgmServer:
    """The EGM stream of a simulated controller (see the module's docstring)."""

    def __init__(self, settings: SimulatedEgmSettings, source: PoseSource, *, clock: Callable[[], float] | None = None,
                 seed: int | None = None, report_frame: Pose | None = None, controller_clock=None):
        self.settings = settings
        self.source = source
        self.clock = clock
        #: the controller's clock given by the simulated world (``stamp(T)``, ``rate``), or
        #: None: ``settings.clock_epoch_s`` and ``clock_drift_ppm``
        self.controller_clock = controller_clock
        self.report_frame = report_frame
        self.faults = EgmFaults()
        self.rng = np.random.default_rng(settings.seed if settings.seed is not None else seed)
        #: (host, port) the samples go to: the UDPUC device's remote address and port
        self.destination: tuple[str, int] | None = None
        self.streaming = False
        self.sent = 0  #: datagrams sent
        self.lost = 0  #: samples lost on purpose (at random, bursts, a stall)
        self._seqno = int(settings.first_seqno)
        self._jump_s = 0.0
        self._held: bytes | None = None  # the first of a swapped pair, sent after the next
        self._lock = threading.RLock()
        self._paused = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self._T_ref, self._wall_ref = 0.0, time.monotonic()  # the internal clock
        self._period_true_s = 0.0
        self._T_next = 0.0  # true time of the next sample

    def set_faults(self, **changes) -> int:
        """Change :attr:`faults` between two samples; returns the samples sent until then
        (so that a test knows which samples a fault applies to)."""
        with self._lock:
            for name, value in changes.items():
                if not hasattr(self.faults, name):
                    raise AttributeError(f"EgmFaults has no {name!r}")
                setattr(self.faults, name, value)
            return self.sent

    # --- time ------------------------------------------------------------------------------------
    def now_true_s(self) -> float:
        """Simulated true time now: ``clock()``, or the internal clock."""
        if self.clock is not None:
            return float(self.clock())
        with self._lock:
            if self._paused:
                return self._T_ref
            return self._T_ref + (time.monotonic() - self._wall_ref)

    def _clock_rate(self) -> float:
        """The controller's clock seconds per true second."""
        if self.controller_clock is not None:
            return float(self.controller_clock.rate)
        return 1.0 + self.settings.clock_drift_ppm * 1e-6

    def controller_time_s(self, T_true_s) -> np.ndarray:
        """The controller's clock at true time ``T_true_s`` (no jitter, no injected jump)."""
        if self.controller_clock is not None:
            return np.asarray(self.controller_clock.stamp(np.asarray(T_true_s, dtype=float)), dtype=float)
        s = self.settings
        return s.clock_epoch_s + np.asarray(T_true_s, dtype=float) * (1.0 + s.clock_drift_ppm * 1e-6)

    # --- streaming -------------------------------------------------------------------------------
    def start(self, sample_period_ms: int) -> None:
        """Start streaming (EGMStreamStart): the first sample is sent now, the rest as
        their time comes. Needs :attr:`destination`."""
        if self.destination is None:
            raise RuntimeError("no UDPUC destination configured for the EGM stream")
        with self._lock:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._period_true_s = sample_period_ms * 1e-3 / self._clock_rate()
            self._T_next = self.now_true_s()
            self.streaming = True
            self._held = None
            self.emit_until(self._T_next)
        if self._thread is None or not self._thread.is_alive():
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="spherecal-sim-egm", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop streaming (EGMStreamStop) after the samples due until now."""
        with self._lock:
            if self.streaming:
                self.emit_until(self.now_true_s())
                self._flush_held()
            self.streaming = False

    def close(self) -> None:
        """Stop streaming and the sender thread, release the socket. Idempotent."""
        self.stop()
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        with self._lock:
            if self._sock is not None:
                self._sock.close()
                self._sock = None

    def pause(self) -> None:
        """A move starts: simulated time stands for the internal clock until :meth:`move_done`."""
        with self._lock:
            if not self._paused:
                self._T_ref = self.now_true_s()
                self._paused = True

    def move_done(self, T_start_s: float, duration_s: float) -> None:
        """A move of ``duration_s`` simulated seconds that started at ``T_start_s`` is
        over: send every sample up to its end now (the internal clock moves to the end)."""
        with self._lock:
            if self.clock is None:
                self._T_ref, self._wall_ref = T_start_s + duration_s, time.monotonic()
            self._paused = False
            if self.streaming:
                self.emit_until(self.now_true_s())

    def resume(self) -> None:
        """A move was refused: nothing moved, time goes on."""
        with self._lock:
            if self._paused:
                self._wall_ref = time.monotonic()
                self._paused = False

    def _run(self) -> None:
        while not self._stop.wait(max(self._period_true_s, 0.004)):
            with self._lock:
                if self.streaming and not self._paused:
                    self.emit_until(self.now_true_s())

    def emit_until(self, T_true_s: float) -> int:
        """Sample and send every sample due up to true time ``T_true_s``; returns how many."""
        with self._lock:
            if not self.streaming or self._period_true_s <= 0 or T_true_s < self._T_next:
                return 0
            n = int(np.floor((T_true_s - self._T_next) / self._period_true_s + 1e-9)) + 1
            T = self._T_next + self._period_true_s * np.arange(n)
            self._T_next = float(T[-1] + self._period_true_s)
            R, t, q = self.source(T)
            if self.report_frame is not None:
                Rw, tw = self.report_frame.rotation_matrix, self.report_frame.translation
                R, t = Rw @ R, t @ Rw.T + tw
            quat = quat_wxyz_from_matrix(R)
            stamps = self.controller_time_s(T)
            for i in range(n):
                self._send_one(stamps[i], t[i], quat[i], None if q is None else q[i])
            return n

    def _send_one(self, stamp_s: float, t_mm, quat_wxyz, joints) -> None:
        s, f = self.settings, self.faults
        seqno = self._seqno
        self._seqno = (self._seqno + 1) % _U32
        if f.clock_jump_s:
            self._jump_s += f.clock_jump_s
            f.clock_jump_s = 0.0
        stamp = stamp_s + self._jump_s + (self.rng.normal(0.0, s.stamp_jitter_s) if s.stamp_jitter_s > 0 else 0.0)
        if f.stall_after is not None:
            if f.stall_after <= 0:
                self.lost += 1
                return
            f.stall_after -= 1
        if f.drop_next > 0:
            f.drop_next -= 1
            self.lost += 1
            return
        if s.drop_probability > 0 and self.rng.random() < s.drop_probability:
            self.lost += 1
            return
        sec = int(np.floor(stamp))
        usec = int(round((stamp - sec) * 1e6))
        if usec >= 1_000_000:
            sec, usec = sec + 1, usec - 1_000_000
        data = encode_egm_robot(EgmSample(
            seqno=seqno, tm_ms=int(np.floor(stamp * 1e3)) % _U32, mtype=MSGTYPE_DATA,
            translation_mm=tuple(t_mm), quaternion_wxyz=tuple(quat_wxyz),
            joints_deg=None if joints is None else tuple(joints), time_sec=sec, time_usec=usec,
            motor_state=1, mci_state=3, rapid_exec_state=2))
        if f.swap_next > 0 and self._held is None:
            f.swap_next -= 1
            self._held = data
            return
        self._send(data)
        if f.duplicate_next > 0:
            f.duplicate_next -= 1
            self._send(data)
        self._flush_held()

    def _flush_held(self) -> None:
        if self._held is not None:
            data, self._held = self._held, None
            self._send(data)

    def _send(self, data: bytes) -> None:
        if self._sock is None or self.destination is None:
            return
        try:
            self._sock.sendto(data, self.destination)
        except OSError:  # nobody listens (ICMP port unreachable): UDP goes on
            pass
        self.sent += 1
        if self.sent % _BURST == 0:
            time.sleep(_BURST_PAUSE_S)
