"""Pydantic validation errors as the lines a user reads: one per error, by dotted path.

Every reader of hand-written or recorded input (the configuration, plugin sections, the
dataset and result files) reports a refused value the same way::

    <path>.<key>[<index>]: <what is wrong> (got <the value>)

An unknown key names the keys allowed there and the likeliest one meant; a fixed-length
list of the wrong length says how many numbers it needs and which ones.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping, Sequence
from types import UnionType
from typing import TYPE_CHECKING, Annotated, Any, Union, get_args, get_origin

from pydantic import BaseModel

if TYPE_CHECKING:  # pragma: no cover
    from pydantic import ValidationError

#: The components of the fixed-length number lists of the formats and the configuration,
#: by field name: a list of the wrong length is reported as "needs 3 numbers (x, y, z), got 2".
COMPONENTS = {
    "translation_mm": "x, y, z",
    "quaternion_wxyz": "w, x, y, z",
    "reference_flange_quaternion_wxyz": "w, x, y, z",
    "sphere_centre_mm": "x, y, z",
    "centre_yz_mm": "y, z",
    "min_mm": "x, y, z",
    "max_mm": "x, y, z",
    "centre_mm": "x, y, z",
    "centre_a_mm": "x, y, z",
    "centre_b_mm": "x, y, z",
    "object_centre_mm": "x, y, z",
    "tilt_deg": "x, y, z",
    "offset_mm": "y, z",
    "offset_percent": "y, z",
}
#: An unknown key names the keys allowed beside it when there are at most this many.
_MAX_KEYS_LISTED = 16
#: Longest rendering of a refused value.
_SHOWN_CHARS = 60
#: Prefixes pydantic puts before a validator's own message.
_PREFIXES = ("Value error, ", "Assertion failed, ")


def location_text(path: str, loc: Sequence[Any]) -> str:
    """``path`` followed by a pydantic location: keys joined by dots, list indices in
    brackets (``acquisition.sweep.tilts_deg[2]``)."""
    text = path
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text


def unwrap_annotation(ann: Any) -> Any:
    """``ann`` without ``Annotated`` metadata and without ``None`` in an optional."""
    while True:
        origin = get_origin(ann)
        if origin is Annotated:
            ann = get_args(ann)[0]
        elif origin in (Union, UnionType):
            args = [a for a in get_args(ann) if a is not type(None)]
            if len(args) != 1:
                return ann
            ann = args[0]
        else:
            return ann


def field_annotation(model: type, keys: Sequence[Any]) -> Any:
    """The annotation of the field a location (keys and list indices) reaches in
    ``model``, through nested models and lists of models; None when it leaves the models."""
    ann: Any = model
    for key in keys:
        ann = unwrap_annotation(ann)
        if isinstance(key, int):
            args = get_args(ann)
            if get_origin(ann) in (list, tuple) and args:
                ann = args[0] if get_origin(ann) is list or len(args) == 1 or args[-1] is Ellipsis else (
                    args[key] if key < len(args) else None)
                continue
            return None
        if isinstance(ann, type) and issubclass(ann, BaseModel) and key in ann.model_fields:
            ann = ann.model_fields[key].annotation
            continue
        return None
    return unwrap_annotation(ann)


def _keys_allowed(model: type[BaseModel] | None, loc: Sequence[Any]) -> list[str] | None:
    """The field names of the model at ``loc`` inside ``model``, or None."""
    if model is None:
        return None
    ann = field_annotation(model, loc)
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return list(ann.model_fields)
    return None


def _unknown_key(model: type[BaseModel] | None, loc: Sequence[Any]) -> str:
    allowed = _keys_allowed(model, loc[:-1])
    if not allowed:
        return "unknown key (a typo?)"
    close = difflib.get_close_matches(str(loc[-1]), allowed, n=1)
    meant = f"did you mean '{close[0]}'?" if close else ""
    if len(allowed) > _MAX_KEYS_LISTED:
        return f"unknown key ({meant or 'a typo?'})"
    return f"unknown key (allowed here: {', '.join(allowed)}" + (f"; {meant})" if meant else ")")


def _wrong_length(loc: Sequence[Any], given: Any, needed: int | None) -> str | None:
    """"needs N numbers (names), got M" for a fixed-length list of the wrong length, else None."""
    name = next((x for x in reversed(loc) if isinstance(x, str)), "")
    if not isinstance(given, (list, tuple)):
        return None
    parts = COMPONENTS.get(name)
    n = len(parts.split(", ")) if parts else needed
    if n is None:
        return None
    names = f" ({parts})" if parts else ""
    return f"needs {n} numbers{names}, got {len(given)}"


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= _SHOWN_CHARS else text[: _SHOWN_CHARS - 3] + "..."


def validation_error_lines(error: ValidationError, path: str = "", model: type[BaseModel] | None = None) -> list[str]:
    """One line per problem in ``error``: ``<path><location>: <message>``.

    ``path`` leads every location (the section the validated data came from); ``model``,
    the model that was validated, lets an unknown key name the keys allowed beside it.
    A list one or more values short is one line, not one per missing value; a refused
    value is shown after the message unless the message states it (a validator's own
    message) or it is a whole table."""
    errors = error.errors(include_url=False)
    short: dict[tuple, int] = {}  # a list too short: its location -> how many items the errors ask for
    for err in errors:
        loc = err["loc"]
        if err["type"] == "missing" and loc and isinstance(loc[-1], int) and isinstance(err.get("input"), (list, tuple)):
            short[tuple(loc[:-1])] = max(short.get(tuple(loc[:-1]), 0), loc[-1] + 1)
    lines: list[str] = []
    done: set[tuple] = set()
    for err in errors:
        loc, kind, given = tuple(err["loc"]), err["type"], err.get("input")
        msg = err["msg"]
        for prefix in _PREFIXES:
            msg = msg.removeprefix(prefix)
        show = "input" in err and not isinstance(given, Mapping)
        if kind == "extra_forbidden":
            msg, show = _unknown_key(model, loc), False
        elif kind == "missing" and loc[:-1] in short:
            loc = loc[:-1]
            if loc in done:
                continue
            done.add(loc)
            msg, show = _wrong_length(loc, given, short[loc]) or "missing (required)", False
        elif kind == "missing":
            msg, show = "missing (required)", False
        elif kind == "too_long" and (ctx := err.get("ctx")) and ctx.get("field_type") == "Tuple":
            wrong = _wrong_length(loc, given, ctx.get("max_length"))
            msg, show = (wrong, False) if wrong else (msg, show)
        elif kind in ("value_error", "assertion_error"):
            show = False
        text = location_text(path, loc)
        line = f"{text}: {msg}" if text else msg
        lines.append(f"{line} (got {_shown(given)})" if show else line)
    return lines
