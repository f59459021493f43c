"""Stopping a profile stream waits for its reader as long as the reader still takes frames
(many frames in flight, a busy machine), and gives up on one that takes none."""

import threading
import time

from spherecal.sensors.nxsensor_i.driver import _join_while_draining


class _Reader(threading.Thread):
    def __init__(self, frames: int, period_s: float, hang: bool = False):
        super().__init__(daemon=True)
        self.frames: list[int] = []
        self.n, self.period_s, self.hang = frames, period_s, hang

    def run(self):
        for i in range(self.n):
            time.sleep(self.period_s)
            self.frames.append(i)
        while self.hang:
            time.sleep(0.01)


def test_a_reader_still_taking_frames_is_waited_for_beyond_the_quiet_limit():
    reader = _Reader(frames=40, period_s=0.01)  # 0.4 s of draining, quiet limit 0.1 s
    reader.start()
    _join_while_draining(reader, quiet_s=0.1)
    assert not reader.is_alive() and len(reader.frames) == 40


def test_a_reader_that_takes_nothing_is_given_up_after_the_quiet_limit():
    reader = _Reader(frames=0, period_s=0.0, hang=True)
    reader.start()
    t = time.monotonic()
    _join_while_draining(reader, quiet_s=0.2)
    assert reader.is_alive() and 0.2 <= time.monotonic() - t < 1.0
    reader.hang = False
