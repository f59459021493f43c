"""Frames as an ABB controller stores them: a RAPID ``tooldata`` or ``wobjdata`` value,
read for ``spherecal compare --tooldata`` and ``spherecal validate --tooldata``.

Accepted text: the value alone, as the FlexPendant or a program shows it
(``[TRUE,[[x,y,z],[q1,q2,q3,q4]],[mass,[cx,cy,cz],[1,0,0,0],0,0,0]]``), or a whole
declaration (``PERS tooldata tSensor := [...];``, ``TASK PERS``, ``CONST`` and ``VAR`` too,
``!`` comments allowed). RAPID's ``orient`` is a quaternion **w first** ([q1, q2, q3, q4] =
(w, x, y, z)), positions are mm: both as spherecal's conventions.

What the frame is (docs/robot-abb-irb2400.md):

- ``tooldata`` with ``robhold`` TRUE: ``tframe`` is the tool in the wrist frame (tool0),
  ``flange_from_sensor``; with ``robhold`` FALSE (a stationary tool) it is in the world
  frame, taken as the base: ``base_from_sensor``. The load (``tload``) may be left out;
  when given it must be well formed, and it is not used.
- ``wobjdata``: ``uframe`` then ``oframe`` (``uframe @ oframe``); fixed (``robhold`` FALSE,
  ``ufprog`` TRUE) it is ``base_from_sensor`` (world taken as base), robot-held
  (``robhold`` TRUE) ``flange_from_sensor``. A user frame moved by a mechanical unit
  (``ufprog`` FALSE) is refused: it is not one fixed frame.
"""

from __future__ import annotations

import math
import re

from spherecal.plugins import ControllerFrame, InputError, Pose

#: Longest text read (a module with a few declarations fits).
MAX_TEXT = 100_000

_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_WORD = re.compile(r"[A-Za-z_]\w*")
_DECLARATION = re.compile(r"\b(tooldata|wobjdata)\s+([A-Za-z]\w*)\s*:=", re.IGNORECASE)
_TOOL_SHAPE = "[robhold, [[x, y, z], [q1, q2, q3, q4]], [mass, [cx, cy, cz], [1, 0, 0, 0], ix, iy, iz]]"
_WOBJ_SHAPE = ("[robhold, ufprog, \"ufmec\", [[x, y, z], [q1, q2, q3, q4]], "
               "[[x, y, z], [q1, q2, q3, q4]]]")


def _strip_comments(text: str) -> str:
    """RAPID comments run from ``!`` to the end of the line (outside strings)."""
    out = []
    for line in text.splitlines():
        in_string = False
        for k, ch in enumerate(line):
            if ch == '"':
                in_string = not in_string
            elif ch == "!" and not in_string:
                line = line[:k]
                break
        out.append(line)
    return "\n".join(out)


class _Parser:
    """A RAPID aggregate value: ``[`` items ``]`` of numbers, TRUE/FALSE, strings and
    aggregates."""

    def __init__(self, text: str):
        self.text = text
        self.pos = 0

    def fail(self, what: str) -> InputError:
        shown = self.text[self.pos:self.pos + 20]
        where = f"at character {self.pos + 1} ({shown!r})" if shown else "at the end of the text"
        return InputError(f"{what} {where}")

    def skip(self) -> None:
        while self.pos < len(self.text) and self.text[self.pos].isspace():
            self.pos += 1

    def value(self):
        self.skip()
        if self.pos >= len(self.text):
            raise self.fail("a value is missing")
        ch = self.text[self.pos]
        if ch == "[":
            return self.aggregate()
        if ch == '"':
            end = self.text.find('"', self.pos + 1)
            if end < 0:
                raise self.fail("a string is not closed (no ending '\"')")
            s = self.text[self.pos + 1:end]
            self.pos = end + 1
            return s
        m = _NUMBER.match(self.text, self.pos)
        if m:
            self.pos = m.end()
            return float(m.group())
        m = _WORD.match(self.text, self.pos)
        if m and m.group().upper() in ("TRUE", "FALSE"):
            self.pos = m.end()
            return m.group().upper() == "TRUE"
        if m:
            raise self.fail(f"{m.group()!r} is not a value (a number, TRUE, FALSE or a string)")
        raise self.fail(f"unexpected character {ch!r}")

    def aggregate(self) -> list:
        self.pos += 1  # '['
        items = []
        self.skip()
        if self.text[self.pos:self.pos + 1] == "]":
            self.pos += 1
            return items
        while True:
            items.append(self.value())
            self.skip()
            ch = self.text[self.pos:self.pos + 1]
            if ch == ",":
                self.pos += 1
            elif ch == "]":
                self.pos += 1
                return items
            elif not ch:
                raise self.fail("a ']' is missing")
            else:
                raise self.fail(f"expected ',' or ']', found {ch!r}")


def _value_text(text: str) -> tuple[str | None, str | None, str]:
    """(declared type, declared name, the value's text) of ``text``."""
    code = _strip_comments(text)
    found = list(_DECLARATION.finditer(code))
    if len(found) > 1:
        names = ", ".join(m.group(2) for m in found)
        raise InputError(f"the text declares {len(found)} frames ({names}): give one")
    if not found:
        return None, None, code.strip()
    m = found[0]
    end = code.find(";", m.end())
    value = code[m.end():end if end >= 0 else len(code)]
    return m.group(1).lower(), m.group(2), value.strip()


def _numbers(value, n: int, field: str) -> list[float]:
    if not isinstance(value, list):
        raise InputError(f"{field}: expected [{n} numbers], got {_show(value)}")
    if len(value) != n:
        raise InputError(f"{field}: expected {n} numbers, got {len(value)}: {_show(value)}")
    for k, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, float):
            raise InputError(f"{field}[{k + 1}]: {_show(v)} is not a number")
        if not math.isfinite(v) or abs(v) > 1e9:
            raise InputError(f"{field}[{k + 1}]: {v:g} is not a plausible value")
    return list(value)


def _show(value) -> str:
    if isinstance(value, bool):
        return "TRUE" if value else "FALSE"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, str):
        return f'"{value}"'
    return "[" + ", ".join(_show(v) for v in value) + "]"


def _bool(value, field: str) -> bool:
    if not isinstance(value, bool):
        raise InputError(f"{field}: expected TRUE or FALSE, got {_show(value)}")
    return value


def _pose(value, field: str) -> Pose:
    """A RAPID ``pose`` [[x, y, z], [q1, q2, q3, q4]] (mm, quaternion w first)."""
    if not isinstance(value, list) or len(value) != 2:
        raise InputError(f"{field}: expected [[x, y, z], [q1, q2, q3, q4]], got {_show(value)}")
    xyz = _numbers(value[0], 3, f"{field}.trans")
    q = _numbers(value[1], 4, f"{field}.rot")
    norm = math.sqrt(sum(c * c for c in q))
    if abs(norm - 1.0) > 1e-3:
        raise InputError(f"{field}.rot: the quaternion {_show(value[1])} has norm {norm:.6f}; a RAPID orient "
                         "[q1, q2, q3, q4] (w first) must be a unit quaternion")
    return Pose.from_xyz_quat_wxyz(xyz, q)


def _tooldata(items: list, name: str | None) -> ControllerFrame:
    if len(items) not in (2, 3):
        raise InputError(f"tooldata: expected {_TOOL_SHAPE} (the load may be left out), got {len(items)} components")
    robhold = _bool(items[0], "tooldata robhold")
    pose = _pose(items[1], "tooldata tframe")
    if len(items) == 3:
        load = items[2]
        if not isinstance(load, list) or len(load) != 6:
            raise InputError(f"tooldata tload: expected [mass, [cx, cy, cz], [1, 0, 0, 0], ix, iy, iz], got "
                             f"{_show(load)}")
        _numbers([load[0]], 1, "tooldata tload.mass")
        _numbers(load[1], 3, "tooldata tload.cog")
        _numbers(load[2], 4, "tooldata tload.aom")
        _numbers(load[3:], 3, "tooldata tload.ix, iy, iz")
    if robhold:
        return ControllerFrame("flange_from_sensor", pose, "tooldata", name)
    return ControllerFrame("base_from_sensor", pose, "tooldata", name,
                           "a stationary tool (robhold FALSE): tframe is in the world frame, taken as the base")


def _wobjdata(items: list, name: str | None) -> ControllerFrame:
    if len(items) != 5:
        raise InputError(f"wobjdata: expected {_WOBJ_SHAPE}, got {len(items)} components")
    robhold = _bool(items[0], "wobjdata robhold")
    ufprog = _bool(items[1], "wobjdata ufprog")
    if not isinstance(items[2], str):
        raise InputError(f"wobjdata ufmec: expected a string (\"\" for none), got {_show(items[2])}")
    if not ufprog:
        raise InputError(f"wobjdata ufprog is FALSE: the user frame moves with the mechanical unit "
                         f"{items[2]!r}, so it is not one fixed frame; spherecal compares fixed frames only")
    pose = _pose(items[3], "wobjdata uframe") @ _pose(items[4], "wobjdata oframe")
    if robhold:
        return ControllerFrame("flange_from_sensor", pose, "wobjdata", name,
                               "a robot-held work object: uframe @ oframe is in the wrist frame (tool0)")
    return ControllerFrame("base_from_sensor", pose, "wobjdata", name,
                           "uframe @ oframe, read in the world frame, taken as the base")


def read_frame(text: str) -> ControllerFrame | None:
    """The frame in ``text``, a RAPID ``tooldata`` or ``wobjdata`` value or declaration
    (module docstring); None when the text is neither (it does not start with ``[`` and
    declares no tooldata or wobjdata). Raises :class:`InputError` naming the component at
    fault (``tooldata tframe.rot``...) when it is one but malformed."""
    if not isinstance(text, str):
        return None
    if len(text) > MAX_TEXT:
        raise InputError(f"the text is {len(text)} characters long; a RAPID frame fits in {MAX_TEXT}")
    declared, name, value = _value_text(text)
    if declared is None and not value.startswith("["):
        return None
    if not value.startswith("["):
        raise InputError(f"{declared} {name}: the value after ':=' must start with '[', found {value[:20]!r}")
    parser = _Parser(value)
    items = parser.value()
    parser.skip()
    rest = value[parser.pos:].strip()
    if rest and rest != ";":
        raise InputError(f"unexpected text after the closing ']': {rest[:20]!r}")
    kind = declared
    if kind is None:  # by its shape: wobjdata starts with two booleans
        kind = "wobjdata" if len(items) == 5 and isinstance(items[1], bool) else "tooldata"
    what = f"{kind} {name}" if name else kind
    try:
        return _tooldata(items, name) if kind == "tooldata" else _wobjdata(items, name)
    except InputError as exc:
        msg = str(exc)
        if not name or not msg.startswith(kind):
            raise
        raise InputError(what + msg[len(kind):]) from None
