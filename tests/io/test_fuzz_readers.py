"""Bounded hypothesis fuzzing of every reader of outside input: the dataset,
result and configuration readers and both wire parsers (the IRB 2400 line protocol and
the nxSensor-I frame format). Whatever the bytes, a reader returns a valid value or
raises its documented error; never anything else. ``max_examples`` keeps the whole
module to a few seconds."""

import json
import warnings

import numpy as np
import pytest
from reference_sensor import reference_fov

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from spherecal.io import dataset as dataio  # noqa: E402
from spherecal.config import load_config  # noqa: E402
from spherecal.core.errors import ConfigError, DatasetFileError, DeviceError, InputError  # noqa: E402
from spherecal.core.models import Observation, Pose, Profile  # noqa: E402
from spherecal.robots.abb_irb2400 import protocol  # noqa: E402
from spherecal.sensors.nxsensor_i import wire  # noqa: E402

FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

VALID_HEADER = {"format": "spherecal-dataset", "version": 1, "mounting": "eye_in_hand", "sphere_radius_mm": 19.1,
                "provenance": {}, "created": "2024-01-01T00:00:00+00:00", "written_by": "test"}
VALID_OBS = {"kind": "observation", "index": 0, "station": "S1", "timestamp": "2024-01-01T00:00:00+00:00",
             "base_from_flange": {"translation_mm": [1000.0, 0.0, 500.0], "quaternion_wxyz": [0.0, 0.0, 1.0, 0.0]},
             "joints_deg": None, "profile": {"y_mm": [0.0, 1.0, 2.0], "z_mm": [-20.0, -20.1, -20.3]}}

json_scalars = st.one_of(st.none(), st.booleans(), st.integers(min_value=-(10**30), max_value=10**30),
                         st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12))
json_values = st.recursive(json_scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                                 st.dictionaries(st.text(max_size=8), inner, max_size=4)),
                           max_leaves=12)


def _mutated(doc: dict, data) -> dict:
    """``doc`` with one (possibly nested) field replaced by a random JSON value."""
    doc = json.loads(json.dumps(doc))
    target = doc
    while True:
        key = data.draw(st.sampled_from(sorted(target)))
        if isinstance(target[key], dict) and target[key] and data.draw(st.booleans()):
            target = target[key]
            continue
        if isinstance(target[key], list) and target[key] and data.draw(st.booleans()):
            i = data.draw(st.integers(0, len(target[key]) - 1))
            target[key][i] = data.draw(json_values)
        else:
            target[key] = data.draw(json_values)
        return doc


def _read_dataset_expecting_only_its_error(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dataio.TruncatedFileWarning)
        try:
            ds = dataio.read_dataset(path)
        except DatasetFileError as exc:
            assert str(path) in str(exc)
            return None
    for o in ds.observations:  # what is accepted is usable
        assert np.all(np.isfinite(o.profile.y_mm)) and np.all(np.isfinite(o.profile.z_mm))
        assert np.all(np.abs(o.profile.y_mm) <= dataio.MAX_ABS_VALUE)
    return ds


@FUZZ
@given(raw=st.binary(max_size=400))
def test_dataset_reader_on_random_bytes(tmp_path, raw):
    path = tmp_path / "fuzz.jsonl"
    path.write_bytes(raw)
    _read_dataset_expecting_only_its_error(path)


@pytest.mark.slow
@FUZZ
@given(data=st.data())
def test_dataset_reader_on_mutated_lines(tmp_path, data):
    header, obs = VALID_HEADER, VALID_OBS
    if data.draw(st.booleans()):
        header = _mutated(header, data)
    else:
        obs = _mutated(obs, data)
    text = json.dumps(header) + "\n" + json.dumps(obs) + "\n"
    cut = data.draw(st.one_of(st.none(), st.integers(0, len(text))))
    path = tmp_path / "fuzz.jsonl"
    path.write_text(text if cut is None else text[:cut])
    _read_dataset_expecting_only_its_error(path)


@pytest.fixture(scope="module")
def valid_result(tmp_path_factory):
    from spherecal.estimation import calibrate
    from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

    ds = simulate_dataset(standard_cell("eye_in_hand", seed=1, fov=reference_fov(n_columns=64)),
                          SweepPlan(profiles_per_station=5))
    path = tmp_path_factory.mktemp("r") / "result.json"
    dataio.write_result(path, calibrate(ds))
    return json.loads(path.read_text())


@FUZZ
@given(data=st.data())
def test_result_reader_on_mutated_documents(tmp_path, valid_result, data):
    doc = _mutated(valid_result, data)
    path = tmp_path / "result.json"
    path.write_text(json.dumps(doc, allow_nan=True))
    try:
        result = dataio.read_result(path)
    except DatasetFileError as exc:
        assert str(path) in str(exc)
        return
    assert np.all(np.isfinite(result.covariance)) and np.isfinite(result.sphere_radius_mm)
    assert all(s >= 0 for s in result.std_rotation_deg + result.std_translation_mm)


@FUZZ
@given(raw=st.binary(max_size=300))
def test_result_reader_on_random_bytes(tmp_path, raw):
    path = tmp_path / "result.json"
    path.write_bytes(raw)
    with pytest.raises(DatasetFileError):
        dataio.read_result(path)


EXAMPLE = (__import__("pathlib").Path(__file__).resolve().parents[2] / "examples" / "sim-eye-in-hand.toml").read_text()
toml_values = st.one_of(
    st.sampled_from(["nan", "inf", "-inf", "true", "false", '"x"', "[]", "{}", "1e308", "-1", "0", "9" * 30,
                     "[1, 2]", "[nan, 0, 0]", '"19.1"', "1979-05-27", "[[1]]"]),
    st.integers(-10**12, 10**12).map(str),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
)


@FUZZ
@given(data=st.data())
def test_configuration_reader_on_mutated_examples(tmp_path, data):
    lines = EXAMPLE.splitlines()
    assignments = [i for i, line in enumerate(lines) if " = " in line and not line.startswith("#")]
    i = data.draw(st.sampled_from(assignments))
    key = lines[i].split(" = ")[0]
    lines[i] = f"{key} = {data.draw(toml_values)}"
    path = tmp_path / "cfg.toml"
    path.write_text("\n".join(lines) + "\n")
    try:
        load_config(path)
    except ConfigError as exc:
        assert str(path) in str(exc)


@FUZZ
@given(raw=st.binary(max_size=300))
def test_configuration_reader_on_random_bytes(tmp_path, raw):
    path = tmp_path / "cfg.toml"
    path.write_bytes(raw)
    with pytest.raises(ConfigError):
        load_config(path)


# --- wire parsers ----------------------------------------------------------------------------------
PARSERS = [protocol.parse_target_request, protocol.parse_movl_request, protocol.parse_joints_reply,
           protocol.parse_pose_reply, protocol.parse_error_reply]
protocol_words = st.sampled_from(["P", "J", "OK", "ERR", "PONG", "GETP", "GETJ", "MOVL", "TGT", "PING", "1", "-",
                                  "0.5", "nan", "inf", "1e400", "-0", "x", "", "  ", "*", "1.0", "0.0", "999999"])


@FUZZ
@given(line=st.one_of(st.binary(max_size=120),
                      st.lists(protocol_words, max_size=10).map(lambda w: " ".join(w))
                      .map(lambda body: protocol.frame(body) if protocol_body_ok(body) else body.encode())))
def test_robot_line_parser(line):
    for decode in (protocol.decode_request, protocol.decode_reply):
        try:
            msg = decode(line)
        except DeviceError:
            continue
        for parse in PARSERS:
            try:
                value = parse(msg)
            except DeviceError:
                continue
            if isinstance(value, Pose):
                assert np.all(np.isfinite(value.translation))
            elif isinstance(value, np.ndarray):
                assert np.all(np.isfinite(value))


def protocol_body_ok(body: str) -> bool:
    try:
        protocol.frame(body)
    except DeviceError:
        return False
    return True


@pytest.fixture(scope="module")
def wire_cfg():
    return wire.WireConfig()


@FUZZ
@given(data=st.data())
def test_sensor_frame_parser(wire_cfg, data):
    if data.draw(st.booleans()):
        raw = data.draw(st.binary(max_size=600))
    else:  # a valid frame with some bytes changed, cut or extended
        n = data.draw(st.integers(1, 50))
        pts = np.column_stack([np.linspace(-10, 10, n), np.full(n, -20.0)])
        good = bytearray(wire.encode_frame(pts, wire_cfg, frame_counter=data.draw(st.integers(0, 1000))))
        for _ in range(data.draw(st.integers(0, 4))):
            good[data.draw(st.integers(0, len(good) - 1))] = data.draw(st.integers(0, 255))
        raw = bytes(good[: data.draw(st.integers(0, len(good)))]) + data.draw(st.binary(max_size=8))
    try:
        frame = wire.decode_frame(raw, wire_cfg)
    except (DeviceError, InputError):
        return
    assert frame is not None
