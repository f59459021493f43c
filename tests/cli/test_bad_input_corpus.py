"""The bad-input corpus: generated bad datasets, result files,
configurations and command-line arguments, each run through the CLI's ``main`` in
this process. Every case must give its documented exit code (docs/cli.md) and a
message naming the culprit (the file, the key or the argument); none may crash
(exit 1, an uncaught exception) or run past its time limit.

``test_corpus_tally`` prints the tally (cases, clear errors, crashes, hangs)."""

from __future__ import annotations

import json
import os
import re
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pytest

from spherecal.io import dataset as dataio
from spherecal.cli import EXIT_DATA, EXIT_USAGE, main
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TIME_LIMIT_S = 10.0
DEEP = 1000  # nesting levels that overflowed the parsers' recursion


class Hang(Exception):
    pass


@dataclass
class Case:
    id: str
    code: int
    culprit: str | list[str]  # text the message must hold (any of a list)
    run: Callable[[Path], list[str]]  # writes its files into a folder, returns argv


# --- datasets: solve DATASET ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def base(tmp_path_factory):
    folder = tmp_path_factory.mktemp("base")
    cell = standard_cell("eye_in_hand", seed=7, fov=reference_fov(n_columns=64))
    ds = simulate_dataset(cell, SweepPlan(profiles_per_station=5))
    path = folder / "base.jsonl"
    dataio.write_dataset(path, ds)
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    from spherecal.estimation import calibrate

    result_path = folder / "result.json"
    dataio.write_result(result_path, calibrate(ds))
    return {"lines": lines, "result": json.loads(result_path.read_text())}


BASE: dict = {}  # filled by the fixture before the cases run


def _dumps(obj) -> str:
    return json.dumps(obj, allow_nan=True)


def dataset_bytes(mutate=None, header=None) -> bytes:
    lines = json.loads(json.dumps(BASE["lines"]))
    if header is not None:
        header(lines[0])
    if mutate is not None:
        mutate(lines[1])  # the first observation
    return "".join(_dumps(x) + "\n" for x in lines).encode()


def ds_case(id, data: Callable[[], bytes] | bytes, culprit, code=EXIT_DATA, name="data.jsonl") -> Case:
    def run(folder: Path):
        p = folder / name
        p.write_bytes(data() if callable(data) else data)
        return ["solve", str(p), "--out", str(folder / "res"), "--no-report"]
    return Case(f"dataset-{id}", code, culprit, run)


def obs_set(path: str, value) -> Callable[[], bytes]:
    """The first observation with the (dotted) field set to ``value``."""
    def mutate(obs):
        keys = path.split(".")
        target = obs
        for k in keys[:-1]:
            target = target[int(k)] if isinstance(target, list) else target[k]
        last = keys[-1]
        if isinstance(target, list):
            target[int(last)] = value
        else:
            target[last] = value
    return lambda: dataset_bytes(mutate)


def hdr_set(key: str, value) -> Callable[[], bytes]:
    return lambda: dataset_bytes(header=lambda h: h.__setitem__(key, value))


def nested(depth: int, leaf="1") -> str:
    return "[" * depth + leaf + "]" * depth


class Raw(float):
    """A number written as given (e.g. a 400-digit integer, 1e400)."""


def raw_number(text):
    return ("__RAW__", text)


def with_raw(fn: Callable[[], bytes]) -> Callable[[], bytes]:
    return lambda: re.sub(rb'\["__RAW__", "([^"]*)"\]', rb"\1", fn())


def dataset_cases() -> list[Case]:
    cases: list[Case] = []
    add = cases.append
    # whole-file problems
    add(ds_case("empty", b"", "data.jsonl"))
    add(ds_case("bom-only", b"\xef\xbb\xbf", "data.jsonl"))
    add(ds_case("bom-newline", b"\xef\xbb\xbf\n", "data.jsonl"))
    add(ds_case("whitespace", b"   \n\n", "data.jsonl"))
    add(ds_case("garbage", os.urandom(64).replace(b"\n", b"x") + b"\n", "data.jsonl"))
    add(ds_case("nul-bytes", b"\x00" * 1000, "data.jsonl"))
    add(ds_case("cr-only", lambda: dataset_bytes().replace(b"\n", b"\r"), ["data.jsonl"]))
    add(ds_case("utf16", lambda: dataset_bytes().decode().encode("utf-16"), ["data.jsonl"]))
    add(ds_case("utf16-le-no-bom", lambda: dataset_bytes().decode().encode("utf-16-le"), ["data.jsonl"]))
    add(ds_case("latin1-station", obs_set("station", "S\u00e9"), None, code=None))  # valid: skipped below
    add(ds_case("deep-header", (nested(DEEP) + "\n").encode(), "data.jsonl"))
    add(ds_case("deep-object-header", ('{"a":' * DEEP + "1" + "}" * DEEP + "\n").encode(), "data.jsonl"))
    add(ds_case("deep-observation", lambda: dataset_bytes().split(b"\n")[0] + b"\n" + nested(DEEP).encode() + b"\n",
                "line 2"))
    add(ds_case("deep-provenance", lambda: dataset_bytes(header=lambda h: h.__setitem__("provenance", "@@")).replace(
        b'"@@"', ('{"a":' * 5 * DEEP + "1" + "}" * 5 * DEEP).encode()), "data.jsonl"))
    add(ds_case("a-result-file", lambda: json.dumps(BASE["result"]).encode(), "it is a calibration result"))
    add(ds_case("header-only", lambda: dataset_bytes().split(b"\n")[0] + b"\n", "data.jsonl"))
    add(ds_case("cut-header", lambda: dataset_bytes()[:40], "data.jsonl"))
    add(ds_case("damaged-middle-line", lambda: dataset_bytes().replace(b'"kind"', b'"ki', 1), "line 2"))
    add(ds_case("two-headers", lambda: dataset_bytes() + dataset_bytes().split(b"\n")[0] + b"\n", "second header"))
    # header fields
    for key, value, culprit in [
        ("format", "spherecal-datasets", "format"), ("format", None, "format"),
        ("version", 0, "version"), ("version", 99, "version"), ("version", "1", "version"),
        ("version", True, "version"), ("version", 1.5, "version"), ("version", float("nan"), "version"),
        ("mounting", "eye_on_hand", "mounting"), ("mounting", 1, "mounting"),
        ("sphere_radius_mm", 0, "sphere_radius_mm"), ("sphere_radius_mm", -19.1, "sphere_radius_mm"),
        ("sphere_radius_mm", float("nan"), "sphere_radius_mm"), ("sphere_radius_mm", float("inf"), "sphere_radius_mm"),
        ("sphere_radius_mm", 1e308, "sphere_radius_mm"), ("sphere_radius_mm", True, "sphere_radius_mm"),
        ("sphere_radius_mm", "19.1", "sphere_radius_mm"), ("sphere_radius_mm", 0.0191, "sphere_radius_mm"),
        ("sphere_radius_mm", None, "sphere_radius_mm"), ("sphere_radius_mm", [19.1], "sphere_radius_mm"),
        ("created", "yesterday", "created"), ("created", "2024-01-01T00:00:00", "created"), ("created", 5, "created"),
        ("extra_key", 1, "extra_key"), ("provenance", [1, 2], "provenance"),
    ]:
        add(ds_case(f"header-{key}-{value!r}"[:60], hdr_set(key, value), culprit))
    add(ds_case("header-radius-400-digits", with_raw(hdr_set("sphere_radius_mm", raw_number("9" * 400))),
                "sphere_radius_mm"))
    add(ds_case("header-radius-1e400", with_raw(hdr_set("sphere_radius_mm", raw_number("1e400"))), "sphere_radius_mm"))
    # observation fields
    for path, value, culprit in [
        ("kind", "obs", "kind"), ("kind", None, "kind"),
        ("index", -1, "index"), ("index", True, "index"), ("index", 1.5, "index"), ("index", "0", "index"),
        ("index", float("nan"), "index"),
        ("station", "", "station"), ("station", 5, "station"), ("station", None, "station"),
        ("station", "S" * 1_000_000, "station"),
        ("timestamp", "2024-01-01T00:00:00", "timestamp"), ("timestamp", "now", "timestamp"), ("timestamp", 0, "timestamp"),
        ("base_from_flange.translation_mm.0", float("nan"), "base_from_flange"),
        ("base_from_flange.translation_mm.1", float("inf"), "base_from_flange"),
        ("base_from_flange.translation_mm.2", -float("inf"), "base_from_flange"),
        ("base_from_flange.translation_mm.0", 1e155, "base_from_flange"),
        ("base_from_flange.translation_mm.0", 1e308, "base_from_flange"),
        ("base_from_flange.translation_mm.0", "1", "base_from_flange"),
        ("base_from_flange.translation_mm.0", True, "base_from_flange"),
        ("base_from_flange.translation_mm", [1, 2], "base_from_flange"),
        ("base_from_flange.quaternion_wxyz", [0, 0, 0, 0], "quaternion"),
        ("base_from_flange.quaternion_wxyz.0", float("nan"), "base_from_flange"),
        ("base_from_flange.quaternion_wxyz.0", 1e308, "base_from_flange"),
        ("base_from_flange.quaternion_wxyz", [1, 0, 0], "base_from_flange"),
        ("base_from_flange", "pose", "base_from_flange"),
        ("base_from_flange", None, ["joints_deg", "base_from_flange"]),
        ("joints_deg", [1, 2, 3], "joints_deg"), ("joints_deg", [float("nan")] * 6, "joints_deg"),
        ("joints_deg", ["a"] * 6, "joints_deg"),
        ("profile.y_mm.0", float("nan"), "profile"), ("profile.y_mm.0", float("inf"), "profile"),
        ("profile.z_mm.0", 1e155, "profile"), ("profile.z_mm.0", 1e300, "profile"),
        ("profile.z_mm.0", -1e200, "profile"),
        ("profile.y_mm.0", "x", "profile"), ("profile.y_mm.0", None, "profile"), ("profile.y_mm.0", [1], "profile"),
        ("profile.y_mm.0", True, "profile"),
        ("profile.y_mm", [1.0], "profile"), ("profile.y_mm", {"a": 1}, "profile"), ("profile", None, "profile"),
        ("profile.extra", 1, "profile"), ("target", -1, "target"), ("target", "3", "target"), ("unknown_field", 1,
                                                                                                  "unknown_field"),
    ]:
        add(ds_case(f"obs-{path}-{str(value)[:20]!r}", obs_set(path, value), culprit))
    add(ds_case("obs-index-400-digits", with_raw(obs_set("index", raw_number("9" * 400))), "index"))
    add(ds_case("obs-profile-1e400", with_raw(obs_set("profile.y_mm.0", raw_number("1e400"))), "profile"))
    add(ds_case("obs-translation-1e400", with_raw(obs_set("base_from_flange.translation_mm.0", raw_number("-1e400"))),
                "base_from_flange"))
    add(ds_case("obs-duplicate-index", lambda: dataset_bytes(lambda o: o.__setitem__("index", 1)), "index"))
    # centre observations (format version 2) in the place of the first profile
    def centre(**fields):
        return lambda: dataset_bytes(lambda o: (o.pop("profile"), o.update(fields)))
    add(ds_case("obs-two-kinds", obs_set("circle", {"centre_yz_mm": [1.0, -20.0], "radius_mm": 10.0}), "circle"))
    add(ds_case("obs-sphere-centre-nan", centre(sphere_centre_mm=[1.0, float("nan"), -20.0]), "sphere_centre_mm"))
    add(ds_case("obs-sphere-centre-1e300", centre(sphere_centre_mm=[1.0, 1e300, -20.0]), "sphere_centre_mm"))
    add(ds_case("obs-covariance-not-psd", centre(sphere_centre_mm=[1.0, 2.0, -20.0], sphere_centre_covariance_mm2=[
        [1e-4, 0, 0], [0, -1e-4, 0], [0, 0, 1e-4]]), "sphere_centre_covariance_mm2"))
    add(ds_case("obs-covariance-2x2", centre(sphere_centre_mm=[1.0, 2.0, -20.0], sphere_centre_covariance_mm2=[
        [1e-4, 0], [0, 1e-4]]), "sphere_centre_covariance_mm2"))
    add(ds_case("obs-circle-radius-nan", centre(circle={"centre_yz_mm": [1.0, -20.0], "radius_mm": float("nan")}),
                "circle.radius_mm"))
    add(ds_case("obs-circle-radius-string", centre(circle={"centre_yz_mm": [1.0, -20.0], "radius_mm": "10"}),
                "circle.radius_mm"))
    cases[:] = [c for c in cases if c.code is not None]
    return cases


# --- non-regular files: as dataset, result and configuration -------------------------------------------
def special_cases() -> list[Case]:
    cases = []
    for what in ["dataset", "config", "result", "robot-config"]:
        for special in ["/dev/zero", "/dev/null", "fifo", "directory", "missing"]:
            def run(folder, what=what, special=special):
                if special == "fifo":
                    p = folder / "pipe"
                    os.mkfifo(p)
                elif special == "directory":
                    p = folder / "adir"
                    p.mkdir()
                elif special == "missing":
                    p = folder / "no-such-file"
                else:
                    p = Path(special)
                if what == "dataset":
                    return ["solve", str(p), "--out", str(folder / "res")]
                if what == "config":
                    return ["calibrate", str(p), "--dry-run"]
                if what == "robot-config":
                    ds = folder / "data.jsonl"
                    ds.write_bytes(dataset_bytes())
                    return ["solve", str(ds), "--robot-config", str(p), "--pose-from", "joints", "--out",
                            str(folder / "res")]
                cfg = config_text(folder, {r"^\[validation\]$": f"[validation]\nresult = '{p}'"})
                return ["validate", str(cfg)]
            culprit = {"fifo": "pipe", "directory": "adir", "missing": "no-such-file"}.get(special, special)
            code = EXIT_USAGE if what in ("config", "robot-config") else EXIT_DATA
            cases.append(Case(f"special-{what}-{special}", code, culprit, run))
    return cases


# --- result files: validate CONFIG with [validation] result = file --------------------------------------
def config_text(folder: Path, replace: dict[str, str], name="sim-eye-in-hand.toml", raw: bytes | None = None) -> Path:
    text = (EXAMPLES / name).read_text()
    text = re.sub(r"(?m)^output_dir = .*$", 'output_dir = "out"', text)
    for pattern, repl in replace.items():
        text, n = re.subn(pattern, repl, text, flags=re.M)
        assert n, pattern
    p = folder / "cfg.toml"
    p.write_bytes(raw if raw is not None else text.encode())
    return p


def result_case(id, data: Callable[[], bytes], culprit) -> Case:
    def run(folder: Path):
        p = folder / "bad-result.json"
        p.write_bytes(data())
        cfg = config_text(folder, {r"^\[validation\]$": f"[validation]\nresult = '{p}'"})
        return ["validate", str(cfg), "--no-report"]
    return Case(f"result-{id}", EXIT_DATA, culprit, run)


def result_bytes(path: str | None = None, value=None, delete=False) -> Callable[[], bytes]:
    def make():
        doc = json.loads(json.dumps(BASE["result"]))
        if path is not None:
            keys = path.split(".")
            target = doc
            for k in keys[:-1]:
                target = target[int(k)] if isinstance(target, list) else target[k]
            last = int(keys[-1]) if isinstance(target, list) else keys[-1]
            if delete:
                del target[last]
            else:
                target[last] = value
        return _dumps(doc).encode()
    return make


def result_cases() -> list[Case]:
    cases = [
        result_case("empty", lambda: b"", "bad-result.json"),
        result_case("bom-only", lambda: b"\xef\xbb\xbf", "bad-result.json"),
        result_case("deep", lambda: nested(DEEP).encode(), "bad-result.json"),
        result_case("deep-object", lambda: ('{"a":' * DEEP + "1" + "}" * DEEP).encode(), "bad-result.json"),
        result_case("utf16", lambda: result_bytes()().decode().encode("utf-16"), "bad-result.json"),
        result_case("a-dataset", dataset_bytes, "bad-result.json"),
        result_case("truncated", lambda: result_bytes()()[:100], "bad-result.json"),
        result_case("400-digit-version", with_raw(result_bytes("version", raw_number("9" * 400))), "version"),
        result_case("radius-1e400", with_raw(result_bytes("sphere_radius_mm", raw_number("1e400"))), "sphere_radius_mm"),
    ]
    for path, value, culprit in [
        ("format", "spherecal-dataset", "format"), ("version", 4, "version"), ("version", "1", "version"),
        ("mounting", "eye_on_hand", "mounting"), ("transform_name", "a_from_b", "transform_name"),
        ("std_rotation_deg.0", float("nan"), "std_rotation_deg"), ("std_rotation_deg.1", float("inf"), "std_rotation_deg"),
        ("std_rotation_deg.0", -1.0, "std_rotation_deg"),
        ("std_translation_mm.2", float("nan"), "std_translation_mm"),
        ("covariance.0.0", float("nan"), "covariance"), ("covariance.1.2", float("inf"), "covariance"),
        ("covariance", [[1.0]], "covariance"),
        ("sphere_radius_mm", float("nan"), "sphere_radius_mm"), ("sphere_radius_mm", float("inf"), "sphere_radius_mm"),
        ("sphere_radius_mm", -1.0, "sphere_radius_mm"), ("sphere_radius_mm", True, "sphere_radius_mm"),
        ("sphere_radius_mm", 1e308, "sphere_radius_mm"),
        ("transform.translation_mm.0", float("nan"), "transform"), ("transform.translation_mm.0", 1e300, "transform"),
        ("transform.quaternion_wxyz", [0, 0, 0, 0], "transform"),
        ("transform.quaternion_wxyz.1", float("inf"), "transform"),
        ("sphere_centre_mm.0", float("nan"), "sphere_centre_mm"),
        ("variance_factor", float("nan"), "variance_factor"),
        ("transform", None, "transform"), ("residuals", "x", "residuals"),
    ]:
        cases.append(result_case(f"{path}-{value!r}"[:50], result_bytes(path, value), culprit))
    cases.append(result_case("missing-transform", result_bytes("transform", delete=True), "transform"))
    return cases


# --- configurations: calibrate CONFIG --dry-run ------------------------------------------------------------
def cfg_case(id, replace: dict[str, str], culprit, code=EXIT_USAGE, raw: Callable[[], bytes] | None = None,
             command="calibrate") -> Case:
    def run(folder: Path):
        p = config_text(folder, replace, raw=raw() if raw else None)
        return {"calibrate": ["calibrate", str(p), "--dry-run"], "scan": ["scan", str(p)],
                "simulate": ["simulate", str(folder / "sim.jsonl"), "--config", str(p)]}[command]
    return Case(f"config-{id}", code, culprit, run)


def config_cases() -> list[Case]:
    example = (EXAMPLES / "sim-eye-in-hand.toml").read_bytes()
    cases = [
        cfg_case("empty", {}, "cfg.toml", raw=lambda: b""),
        cfg_case("bom-only", {}, "cfg.toml", raw=lambda: b"\xef\xbb\xbf"),
        cfg_case("utf16", {}, "cfg.toml", raw=lambda: example.decode().encode("utf-16")),
        cfg_case("cr-only", {}, "cfg.toml", raw=lambda: example.replace(b"\n", b"\r")),
        cfg_case("deep-array", {}, "cfg.toml", raw=lambda: b"x = " + nested(DEEP).encode() + b"\n"),
        cfg_case("deep-inline-table", {}, "cfg.toml", raw=lambda: b"x = " + b"{a=" * DEEP + b"1" + b"}" * DEEP + b"\n"),
        cfg_case("binary", {}, "cfg.toml", raw=lambda: b"\x00\xff" * 100),
        cfg_case("one-station", {r"^profiles_per_station = 10$": "profiles_per_station = 10\ntilts_deg = [[0, 0, 0]]"},
                 ["tilts_deg", "station"], code=EXIT_DATA),
        cfg_case("two-stations-one-axis", {r"^profiles_per_station = 10$":
                                           "profiles_per_station = 10\ntilts_deg = [[0, 0, 0], [20, 0, 0]]"},
                 ["tilts_deg", "station"], code=EXIT_DATA),
    ]
    values = {
        "nan": "nan", "inf": "inf", "-inf": "-inf", "huge": "1e308", "400-digits": "9" * 400,
    }
    for key, pattern, repl_fmt, culprit in [
        ("radius", r"^radius_mm = 19.1$", "radius_mm = {}", "radius_mm"),
        ("nominal-t", r"^translation_mm = \[44.5, -19.8, 166.2\]$", "translation_mm = [{}, -19.8, 166.2]",
         "translation_mm"),
        ("nominal-q", r"^quaternion_wxyz = \[0.02714, -0.96565, 0.25663, 0.03026\]$",
         "quaternion_wxyz = [{}, -0.96565, 0.25663, 0.03026]", "quaternion_wxyz"),
        ("sphere-centre", r"^sphere_centre_mm = \[1100.0, 150.0, 400.0\]", "sphere_centre_mm = [{}, 150.0, 400.0]",
         "sphere_centre_mm"),
        ("speed", r"^speed_mm_s = 20.0", "speed_mm_s = {}", "speed_mm_s"),
        ("profiles", r"^profiles_per_station = 10$", "profiles_per_station = {}", "profiles_per_station"),
        ("workspace", r"^max_mm = \[1600.0, 800.0, 1400.0\]", "max_mm = [{}, 800.0, 1400.0]", "max_mm"),
        ("point-noise", r"^point_noise_mm = 0.01$", "point_noise_mm = {}", "point_noise_mm"),
        ("cal-pose-noise", r"^pose_translation_noise_mm = 0.02\n\n\[simulation\]",
         "pose_translation_noise_mm = {}\n\n[simulation]", "pose_translation_noise_mm"),
        ("robot-speed", r"^max_speed_mm_s = 250.0$", "max_speed_mm_s = {}", "max_speed_mm_s"),
        ("seed", r"^seed = 1$", "seed = {}", "seed"),
    ]:
        for vname, v in values.items():
            if key == "seed" and vname in ("nan", "inf", "-inf", "huge"):
                continue
            cases.append(cfg_case(f"{key}-{vname}", {pattern: repl_fmt.format(v)}, culprit))
    sweep = r"^profiles_per_station = 10$"
    for id, repl, culprit in [
        ("radius-true", {r"^radius_mm = 19.1$": "radius_mm = true"}, "radius_mm"),
        ("radius-string", {r"^radius_mm = 19.1$": 'radius_mm = "19.1"'}, "radius_mm"),
        ("seed-negative", {r"^seed = 1$": "seed = -1"}, "seed"),
        ("seed-float", {r"^seed = 1$": "seed = 1.5"}, "seed"),
        ("profiles-1e307", {sweep: "profiles_per_station = 1e307"}, "profiles_per_station"),
        ("profiles-1e9", {sweep: "profiles_per_station = 1000000000"}, "profiles_per_station"),
        ("profiles-true", {sweep: "profiles_per_station = true"}, "profiles_per_station"),
        ("settle-inf", {r"^approach_speed_mm_s = 100.0$": "approach_speed_mm_s = 100.0\nsettle_s = inf"}, "settle_s"),
        ("settle-1e308", {r"^approach_speed_mm_s = 100.0$": "approach_speed_mm_s = 100.0\nsettle_s = 1e308"},
         "settle_s"),
        ("retries-huge", {r"^approach_speed_mm_s = 100.0$": "approach_speed_mm_s = 100.0\nretries_per_target = 1e9"},
         "retries_per_target"),
        ("retries-many", {r"^approach_speed_mm_s = 100.0$":
                          "approach_speed_mm_s = 100.0\nretries_per_target = 1000000000"}, "retries_per_target"),
        ("robot-timeout-inf", {r"^max_speed_mm_s = 250.0$": "max_speed_mm_s = 250.0\ntimeout_s = inf"}, "timeout_s"),
        ("robot-timeout-1e308", {r"^max_speed_mm_s = 250.0$": "max_speed_mm_s = 250.0\ntimeout_s = 1e308"},
         "timeout_s"),
        ("sensor-timeout-inf", {r'^type = "nxsensor_i"$': 'type = "nxsensor_i"\ntimeout_s = inf'}, "timeout_s"),
        ("scan-step-tiny", {r"^step_mm = 1.0$": "step_mm = 1e-9"}, "step_mm"),
        ("scan-passes-huge", {r"^passes = 2$": "passes = 1000000000"}, "passes"),
        ("scan-length-inf", {r"^length_mm = 80.0$": "length_mm = inf"}, "length_mm"),
        ("validation-profiles-huge", {r"^profiles_per_sweep = 24$": "profiles_per_sweep = 1000000000"},
         "profiles_per_sweep"),
        ("ballbar-distance-nan", {r"^certified_distance_mm = 206.155$": "certified_distance_mm = nan"},
         "certified_distance_mm"),
        ("flat-centre-inf", {r"^centre_mm = \[1250.0, -100.0, 380.0\]$": "centre_mm = [inf, -100.0, 380.0]"},
         "centre_mm"),
        ("robot-error-nan", {r"^joint_zero_offset_deg = \[0.02, 0.05\]$": "joint_zero_offset_deg = [nan, 0.05]"},
         "joint_zero_offset_deg"),
        ("stray-fraction-2", {r"^stray_profile_fraction = 0.1$": "stray_profile_fraction = 2"}, "stray_profile_fraction"),
        ("unknown-key", {r"^radius_mm = 19.1$": "radius_mm = 19.1\nradius_in = 1"}, "radius_in"),
        ("robot-type-missing", {r'^type = "abb_irb2400"$': ""}, "robot"),
        ("robot-type-unknown", {r'^type = "abb_irb2400"$': 'type = "abb_irb9999"'}, "abb_irb9999"),
        ("robot-port-number", {r"^max_speed_mm_s = 250.0$": "max_speed_mm_s = 250.0\nport = 5"}, "port"),
        ("mounting-bad", {r'^mounting = "eye_in_hand"$': 'mounting = "eye_on_hand"'}, "mounting"),
        ("output-dir-number", {r'^output_dir = "out"$': "output_dir = 5"}, "output_dir"),
        ("station-offsets-huge", {sweep: "profiles_per_station = 10\nstation_offsets_mm = [[1e308, 0]]"},
         "station_offsets_mm"),
        ("sweep-fraction-nan", {sweep: "profiles_per_station = 10\nsweep_fraction = nan"}, "sweep_fraction"),
        ("tilts-nan", {sweep: "profiles_per_station = 10\ntilts_deg = [[nan, 0, 0], [30, 0, 0], [0, 30, 0]]"},
         "tilts_deg"),
        ("fov-columns-huge", {r"^scan_object = .*$": 'scan_object = "car_door_panel"\nfov = { n_columns = 1000000000 }'},
         "n_columns"),
    ]:
        cases.append(cfg_case(id, repl, culprit))
    mounting = r'^mounting = "eye_in_hand"$'
    for id, export, culprit in [  # [export]: the core's keys and the exporters' own settings
        ("export-mass-nan", "{ abb_rapid = { mass_kg = nan } }", "export.abb_rapid.mass_kg"),
        ("export-mass-huge", "{ abb_rapid = { mass_kg = 1e308 } }", "export.abb_rapid.mass_kg"),
        ("export-mass-string", '{ abb_rapid = { mass_kg = "2" } }', "export.abb_rapid.mass_kg"),
        ("export-cog-inf", "{ abb_rapid = { cog_mm = [0, 0, inf] } }", "export.abb_rapid.cog_mm"),
        ("export-tool-name", '{ abb_rapid = { tool_name = "tool0" } }', "export.abb_rapid.tool_name"),
        ("export-frame-space", '{ ros2 = { frame_id = "tool 0" } }', "export.ros2.frame_id"),
        ("export-frame-long", '{ ros2 = { child_frame_id = "' + "f" * 300 + '" } }', "export.ros2.child_frame_id"),
        ("export-run-string", '{ run = "ros2" }', "export.run"),
        ("export-run-unknown", '{ run = ["ros"] }', "export.run[0]"),
        ("export-unknown-table", "{ rapid = {} }", "export.rapid"),
        ("export-table-number", "{ ros2 = 5 }", "export.ros2"),
    ]:
        cases.append(cfg_case(id, {mounting: f'mounting = "eye_in_hand"\nexport = {export}'}, culprit))
    # the scan's own numbers are checked where scan reads them too
    cases.append(cfg_case("scan-ply-escape", {r"^passes = 2$": "passes = 2\nply = '../../x.ply'"}, "scan.ply",
                          command="scan"))
    return cases


# --- command-line arguments -----------------------------------------------------------------------------------
def cli_case(id, argv: Callable[[Path], list[str]], culprit, code=EXIT_USAGE) -> Case:
    return Case(f"cli-{id}", code, culprit, argv)


def cli_cases() -> list[Case]:
    def solve_with(*extra):
        def run(folder):
            p = folder / "data.jsonl"
            p.write_bytes(dataset_bytes())
            return ["solve", str(p), "--out", str(folder / "res"), "--no-report", *extra]
        return run

    def simulate_with(*extra):
        return lambda folder: ["simulate", str(folder / "sim.jsonl"), *extra]

    cases = []
    for v in ["1,2,x", "1,2,3", "1,2,3,1,0,0,0,0", "nan,0,0,1,0,0,0", "0,0,0,nan,0,0,0", "0,0,0,2,0,0,0",
              "0,0,0,0,0,0,0", "inf,0,0,1,0,0,0", "1e400,0,0,1,0,0,0", "", ",,,,,,", "0,0,0,1,0,0,0,"]:
        cases.append(cli_case(f"nominal-{v}", solve_with("--nominal", v), "--nominal"))
    for v in ["nan", "inf", "-1", "0", "x", "1e400"]:
        cases.append(cli_case(f"rotation-tolerance-{v}", solve_with("--station-rotation-tolerance-deg", v),
                              "--station-rotation-tolerance-deg"))
    cases.append(cli_case("robot-unknown", solve_with("--robot", "abb_irb9999", "--pose-from", "joints"), "abb_irb9999"))
    cases.append(cli_case("pose-from-bad", solve_with("--pose-from", "both"), "--pose-from"))
    for v in ["0", "-1", "3", "x", "1e9", "100000000"]:
        cases.append(cli_case(f"simulate-profiles-{v}", simulate_with("--profiles", v), "--profiles"))
    for opt in ["--point-noise-mm", "--pose-noise-mm", "--stray-fraction"]:
        for v in ["nan", "inf", "-1", "x"]:
            cases.append(cli_case(f"simulate{opt}-{v}", simulate_with(opt, v), opt))
    cases.append(cli_case("simulate-stray-2", simulate_with("--stray-fraction", "2"), "--stray-fraction"))
    for v in ["-1", "x", "1.5", "9" * 400]:
        cases.append(cli_case(f"simulate-seed-{v[:10]}", simulate_with("--seed", v), "--seed"))
    cases.append(cli_case("simulate-mounting", simulate_with("--mounting", "eye_on_hand"), "--mounting"))
    cases.append(cli_case("unknown-command", lambda f: ["calibrat"], "calibrat"))
    cases.append(cli_case("unknown-option", lambda f: ["solve", "x.jsonl", "--fast"], "--fast"))
    return cases


ALL_CASES: list[Case] = []


def _all_cases() -> list[Case]:
    if not ALL_CASES:
        ALL_CASES.extend(dataset_cases() + special_cases() + result_cases() + config_cases() + cli_cases())
    return ALL_CASES


TALLY: dict[str, list[str]] = {"clear": [], "wrong code": [], "culprit not named": [], "crash": [], "hang": []}


def run_case(case: Case, folder: Path, capsys) -> tuple[str, int | None, str]:
    def alarm(signum, frame):
        raise Hang(case.id)

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, TIME_LIMIT_S)
    code, crash = None, None
    try:
        argv = case.run(folder)
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code
    except Hang:
        return "hang", None, ""
    except Exception as exc:  # noqa: BLE001 - a crash of main itself
        crash = f"{type(exc).__name__}: {exc}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    cap = capsys.readouterr()
    text = cap.err + cap.out
    if crash or code == 1 or "internal error" in text or "Traceback" in text:
        return "crash", code, crash or text
    if code != case.code:
        return "wrong code", code, text
    culprits = case.culprit if isinstance(case.culprit, list) else [case.culprit]
    if not any(c in text for c in culprits):
        return "culprit not named", code, text
    return "clear", code, text


@pytest.fixture(scope="module", autouse=True)
def _base(base):
    BASE.update(base)
    yield


def test_the_corpus_is_large_enough():
    _all_cases_ids = [c.id for c in _all_cases_lazy()]
    assert len(_all_cases_ids) >= 150
    assert len(set(_all_cases_ids)) == len(_all_cases_ids)


def _all_cases_lazy():
    return _all_cases()


@pytest.mark.parametrize("case", _all_cases_lazy(), ids=lambda c: c.id)
def test_bad_input(case, tmp_path, capsys):
    t0 = time.monotonic()
    outcome, code, text = run_case(case, tmp_path, capsys)
    TALLY[outcome].append(case.id)
    assert outcome == "clear", f"{case.id}: {outcome} (exit {code}, expected {case.code}; culprit {case.culprit!r}):\n{text[-1500:]}"
    assert time.monotonic() - t0 < TIME_LIMIT_S


def test_corpus_tally():
    """Runs last in this module: the tally of the cases run above."""
    n = sum(len(v) for v in TALLY.values())
    summary = ", ".join(f"{k}: {len(v)}" for k, v in TALLY.items())
    print(f"\nbad-input corpus: {n} cases; {summary}")
    assert not TALLY["crash"] and not TALLY["hang"]


def test_a_line_longer_than_the_bound_is_refused_unread(tmp_path, monkeypatch):
    path = tmp_path / "long.jsonl"
    path.write_bytes(dataset_bytes() + b'{"kind": "observation", "x": "' + b"a" * 5000 + b'"}\n')
    monkeypatch.setattr(dataio, "MAX_LINE_BYTES", 4096)
    with pytest.raises(dataio.DatasetFileError, match=r"long.jsonl line 22 .*longer than 4096 bytes"):
        dataio.read_dataset(path)
    head = tmp_path / "head.jsonl"
    head.write_bytes(b"x" * 5000)
    with pytest.raises(dataio.DatasetFileError, match="longer than 4096"):
        dataio.read_dataset_header(head)


@pytest.mark.slow
def test_station_names_that_look_like_mathtext_do_not_break_the_report(tmp_path, capsys):
    """'$...$' in a station name would crash matplotlib's mathtext parser; the report shows
    names as they are. A name longer than the bound is refused when read (corpus)."""
    from spherecal.sim import simulate_dataset

    cell = standard_cell("eye_in_hand", seed=7, fov=reference_fov(n_columns=64))
    ds = simulate_dataset(cell, SweepPlan(profiles_per_station=5))
    names = {"S1": "$x^$", "S2": "a_{b}$\\frac", "S3": "$$", "S4": "S" * 200}
    ds = ds.model_copy(update={"observations": [o.model_copy(update={"station": names[o.station]})
                                                for o in ds.observations]})
    path = tmp_path / "math.jsonl"
    dataio.write_dataset(path, ds)
    assert main(["solve", str(path), "--out", str(tmp_path / "res")]) in (0, 7)
    html = (tmp_path / "res" / "report.html").read_text()
    assert "$x^$" in html
