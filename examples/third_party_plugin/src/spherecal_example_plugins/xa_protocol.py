"""XA/1, the example arm controller's TCP protocol (both ends use this module).

ASCII, one request line and one reply line, each ended by LF, words separated by one
space; the controller answers requests in order. Numbers are decimal; lengths in mm,
angles in degrees, quaternions **(w, x, y, z)**, scalar first; poses are
``base_from_flange`` (tool0 in the robot's base frame); ``t_robot_s`` is the
controller's own clock (s since its power-on).

=====================================  ===================================================
request                                reply
=====================================  ===================================================
``HELLO``                              ``HELLO <manufacturer> <model> <serial> <firmware>``
``JOINTS``                             ``JOINTS <j1> ... <j6>`` (deg)
``POSE``                               ``POSE <t_robot_s> <x> <y> <z> <qw> <qx> <qy> <qz>``
``MOVE <x> <y> <z> <qw> <qx> <qy>      ``DONE <t_robot_s>`` once in position (a straight
<qz> <v_mm_s> <v_deg_s>``              move at ``v_mm_s`` and at most ``v_deg_s``)
``STREAM <period_ms>``                 ``STREAMING <t_robot_s>``: the pose stream is on
``UNSTREAM``                           ``UNSTREAMED <t_robot_s>``: the pose stream is off
=====================================  ===================================================

Any request may be answered ``FAIL <code> <text>``: ``SYNTAX`` (not understood), ``SPEED``
(a speed beyond the controller's own limit), ``REACH`` (the target is out of reach or
beyond a joint limit); nothing moves then.

The pose stream: from ``STREAM`` to ``UNSTREAM`` the controller samples its flange pose
every ``period_ms`` of its clock and sends each sample unasked, in order, on the same
connection, before the reply of the request during which it was taken (a move's samples
come before its ``DONE``): ``SAMPLE <seq> <t_robot_s> <x> <y> <z> <qw> <qx> <qy> <qz>
<j1> ... <j6>``, ``seq`` the sample's tick on the controller's clock (consecutive; a gap
is a lost sample).
"""

from __future__ import annotations

import math

VERBS = {"HELLO": 0, "JOINTS": 0, "POSE": 0, "MOVE": 9, "STREAM": 1, "UNSTREAM": 0}  # request -> count of numbers
REPLIES = {"HELLO": None, "JOINTS": 6, "POSE": 8, "DONE": 1, "STREAMING": 1, "UNSTREAMED": 1,
           "SAMPLE": 15}  # reply -> count of numbers (None: words)
FAIL_CODES = ("SYNTAX", "SPEED", "REACH")


class XaError(ValueError):
    """A line that is not XA/1; the message says what is wrong."""


def line(verb: str, *numbers: float, decimals: int = 6) -> bytes:
    """One line: ``verb`` then the numbers, LF-terminated."""
    words = [verb, *(f"{float(v):.{decimals}f}" for v in numbers)]
    return (" ".join(words) + "\n").encode("ascii")


def words_line(verb: str, *words: str) -> bytes:
    return (" ".join([verb, *words]) + "\n").encode("ascii")


def parse(data: bytes, counts: dict[str, int | None]) -> tuple[str, list]:
    """(verb, numbers) of one line whose verb is in ``counts`` with that many finite
    numbers (``None``: words, returned as text); :class:`XaError` otherwise."""
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        raise XaError(f"not ASCII: {data[:40]!r}") from None
    if not text.endswith("\n"):
        raise XaError(f"line without its LF: {text[:40]!r}")
    verb, *args = text.rstrip("\r\n").split(" ")
    if verb not in counts:
        raise XaError(f"unknown {verb!r} (expected one of {', '.join(counts)})")
    n = counts[verb]
    if n is None:
        return verb, args
    if len(args) != n:
        raise XaError(f"{verb} takes {n} numbers, got {len(args)}")
    try:
        values = [float(a) for a in args]
    except ValueError:
        raise XaError(f"{verb}: not a number among {args}") from None
    if not all(math.isfinite(v) for v in values):
        raise XaError(f"{verb}: numbers must be finite, got {args}")
    return verb, values


def fail(code: str, text: str) -> bytes:
    return words_line("FAIL", code, text.replace("\n", " "))
