"""Reading a configuration file: the TOML text, the checks pydantic leaves out (numbers
that are finite and plausible, booleans and strings never read as numbers), validation
against :class:`~spherecal.config.sections.RunConfig`, and the paths relative to the file.

Unknown keys are errors and every error names its dotted path and the file. Relative
paths in the file (``output_dir``, ``replay``) are relative to the file's folder.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any, Literal, get_origin

from pydantic import BaseModel, ValidationError

from spherecal.config.sections import RunConfig
from spherecal.core.errors import ConfigError
from spherecal.core.validation_errors import field_annotation, location_text, validation_error_lines
from spherecal.io.files import read_input, text_encoding_problem

#: Largest magnitude of any number in a configuration file: beyond it the value is a
#: typing or units error (and would overflow the computations).
MAX_ABS_NUMBER = 1e9
#: Largest configuration file read, bytes.
MAX_CONFIG_BYTES = 1 << 20


class LoadedConfig:
    """A validated configuration and where it came from."""

    def __init__(self, config: RunConfig, path: Path):
        self.config = config
        self.path = path

    def resolve(self, relative: str) -> Path:
        p = Path(relative).expanduser()
        return p if p.is_absolute() else (self.path.parent / p).resolve()

    @property
    def output_dir(self) -> Path:
        return self.resolve(self.config.output_dir)


def _number_problems(value: Any, path: str, out: list[str]) -> None:
    """Every NaN, infinity or implausibly large number in parsed TOML, by dotted path."""
    if isinstance(value, bool):
        return
    if isinstance(value, float):
        if not math.isfinite(value):
            out.append(f"{path}: {value} is not allowed: give a finite number")
        elif abs(value) > MAX_ABS_NUMBER:
            out.append(f"{path}: {value:g} is implausibly large (at most {MAX_ABS_NUMBER:g} in magnitude)")
    elif isinstance(value, int):
        if abs(value) > 2**63:
            out.append(f"{path}: an integer of {len(str(abs(value)))} digits is too large")
        elif abs(value) > MAX_ABS_NUMBER and path.rsplit(".", 1)[-1] != "seed":
            out.append(f"{path}: {value} is implausibly large (at most {MAX_ABS_NUMBER:g} in magnitude)")
    elif isinstance(value, dict):
        for k, v in value.items():
            _number_problems(v, f"{path}.{k}" if path else str(k), out)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _number_problems(v, f"{path}[{i}]", out)


def _bool_problems(value: Any, keys: list, out: list[str], root: type[BaseModel] = RunConfig,
                   prefix: str = "") -> None:
    """true/false or a string where the model wants a number: TOML booleans and strings
    are never numbers here (pydantic would read true as 1.0 and "19.1" as 19.1). ``root``
    is the model ``value`` is checked against; ``prefix`` leads every path in messages."""
    if isinstance(value, (bool, str)):
        ann = field_annotation(root, keys)
        path = location_text(prefix.removesuffix("."), keys)
        if ann in (float, int):
            shown = str(value).lower() if isinstance(value, bool) else repr(value)
            out.append(f"{path}: {shown:.40} is a {'boolean' if isinstance(value, bool) else 'string'}; "
                       "give a number")
        elif isinstance(value, bool) and ann is not None and ann is not bool and get_origin(ann) is not Literal \
                and ann is not Any:
            out.append(f"{path}: {str(value).lower()} is a boolean; expected {getattr(ann, '__name__', ann)}")
    elif isinstance(value, dict):
        for k, v in value.items():
            _bool_problems(v, [*keys, k], out, root, prefix)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _bool_problems(v, [*keys, i], out, root, prefix)


def not_numbers(table: Any, model: type[BaseModel], path: str) -> list[str]:
    """Every boolean or string in ``table`` (parsed TOML) where ``model`` wants a number,
    by dotted path under ``path``: pydantic would take them (true as 1.0, "2" as 2.0), a
    hand-written file must not. For plugin-owned sections (``[export.<name>]``)."""
    out: list[str] = []
    _bool_problems(table, [], out, model, f"{path}.")
    return out


def read_toml(path, what: str = "configuration") -> dict:
    """The TOML file at ``path`` as a dict, read with the input checks (a regular file of
    bounded size, a text encoding TOML allows); :class:`ConfigError` naming the file and
    ``what`` it should have been otherwise."""
    raw = read_input(path, ConfigError, f"the {what}", MAX_CONFIG_BYTES)
    problem = text_encoding_problem(raw)
    if problem:
        raise ConfigError(f"{path}: not a {what} as written: {problem}")
    try:
        return tomllib.loads(raw.decode("utf-8").removeprefix("\ufeff"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        hint = ""
        if raw.lstrip().startswith(b"{") and what == "configuration":  # a dataset (JSON Lines) given for a configuration
            hint = "; it looks like a dataset (JSON Lines): solve it with `spherecal solve FILE`"
        raise ConfigError(f"{path}: not valid TOML: {exc}{hint}") from None
    except RecursionError:
        raise ConfigError(f"{path}: not a {what}: nested too deeply") from None


def load_config(path: str | Path) -> LoadedConfig:
    """Read and validate a configuration file; :class:`ConfigError` names the file and
    every bad key by its dotted path. Numbers must be finite and at most
    :data:`MAX_ABS_NUMBER` in magnitude; a boolean is never read as a number."""
    path = Path(path)
    data = read_toml(path, "configuration")
    if not data:
        raise ConfigError(f"{path}: the configuration is empty; see docs/configuration.md and examples/")
    problems: list[str] = []
    _number_problems(data, "", problems)
    _bool_problems(data, [], problems)
    if problems:
        raise ConfigError(f"{path}: invalid configuration:\n" + "\n".join(f"  {path}: {p}" for p in problems))
    try:
        cfg = RunConfig.model_validate(data)
    except ValidationError as exc:
        lines = validation_error_lines(exc, model=RunConfig)
        raise ConfigError(f"{path}: invalid configuration:\n" + "\n".join(f"  {path}: {line}" for line in lines)) from None
    _check_home_folders(cfg, path)
    return LoadedConfig(cfg, path.resolve())


#: The configuration's path fields, by dotted name.
PATH_FIELDS = ("output_dir", "replay", "validation.result", "scan.result", "scan.ply")


def _check_home_folders(cfg: RunConfig, path: Path) -> None:
    """A path starting ``~user`` must name a user this machine knows: the file is wrong
    otherwise, and is refused here, naming the key, before anything runs."""
    for name in PATH_FIELDS:
        value: Any = cfg
        for part in name.split("."):
            value = getattr(value, part, None) if value is not None else None
        if isinstance(value, str) and value.startswith("~"):
            try:
                Path(value).expanduser()
            except RuntimeError:
                user = value[1:].split("/", 1)[0] or "the current user"
                raise ConfigError(f"{path}: invalid configuration:\n  {path}: {name}: {value!r}: no home folder "
                                  f"for {user!r} on this machine to expand '~' into; give the folder "
                                  "itself") from None
