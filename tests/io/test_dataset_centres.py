"""Dataset format version 2: centre observations (circle, sphere_centre_mm) beside
profiles; exact round trips, version 1 still read, bad rows named."""

from __future__ import annotations

import json
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from pydantic import ValidationError

from spherecal.io.dataset import DatasetWriter, read_dataset, read_dataset_header, write_dataset
from spherecal.core.errors import DatasetFileError, InputError
from spherecal.core.models import Circle, Dataset, Observation, Pose, Profile

T0 = datetime(2026, 3, 4, 5, 6, 7, tzinfo=timezone.utc)


def obs(index: int, **seen) -> Observation:
    rng = np.random.default_rng(index)
    q = rng.normal(size=4)
    pose = Pose(translation_mm=tuple(rng.uniform(-900, 900, 3)), quaternion_wxyz=tuple(q / np.linalg.norm(q)))
    return Observation(index=index, station=f"S{index % 3}", timestamp=T0 + timedelta(seconds=index),
                       base_from_flange=pose, **seen)


def mixed_dataset() -> Dataset:
    rng = np.random.default_rng(5)
    A = rng.normal(size=(3, 3))
    cov = A @ A.T * 1e-4 + np.eye(3) * 1e-6  # a full, positive definite covariance, mm^2
    return Dataset(mounting="eye_to_hand", sphere_radius_mm=12.7, provenance={"source": "test"}, observations=[
        obs(0, profile=Profile(y_mm=rng.normal(0, 5, 7), z_mm=rng.normal(-20, 5, 7))),
        obs(1, circle=Circle(centre_yz_mm=(1.0 / 3.0, -20.125), radius_mm=11.1)),
        obs(2, circle=Circle(centre_yz_mm=(-2.5, 0.1 + 0.2), radius_mm=3.3, centre_std_mm=0.004, radius_std_mm=0.007)),
        obs(3, sphere_centre_mm=(0.1 + 0.2, -1e-17, 123.456789012345678)),
        obs(4, sphere_centre_mm=(-4.0, 5.0, -30.0), sphere_centre_covariance_mm2=tuple(map(tuple, cov.tolist()))),
    ])


def test_mixed_version_2_file_round_trips_exactly(tmp_path, parser):
    ds = mixed_dataset()
    path = tmp_path / "mixed.dataset.jsonl"
    write_dataset(path, ds)
    assert read_dataset_header(path).version == 2
    back = read_dataset(path)
    assert [o.kind for o in back.observations] == ["profile", "circle", "circle", "sphere_centre", "sphere_centre"]
    for a, b in zip(back.observations, ds.observations):
        assert a.base_from_flange == b.base_from_flange
        assert a.circle == b.circle  # exact: tuples of floats
        assert a.sphere_centre_mm == b.sphere_centre_mm
        assert a.sphere_centre_covariance_mm2 == b.sphere_centre_covariance_mm2
        assert (a.profile is None) == (b.profile is None)
    assert np.array_equal(back.observations[0].profile.y_mm, ds.observations[0].profile.y_mm)
    # only the kind present is written: a reader sees exactly one of the three
    lines = [json.loads(x) for x in path.read_text().splitlines()[1:]]
    assert [sorted(set(x) & {"profile", "circle", "sphere_centre_mm"}) for x in lines] == [
        ["profile"], ["circle"], ["circle"], ["sphere_centre_mm"], ["sphere_centre_mm"]]
    assert "centre_std_mm" not in lines[1]["circle"] and lines[2]["circle"]["radius_std_mm"] == 0.007
    assert "sphere_centre_covariance_mm2" not in lines[3]


def test_writer_appends_centres_and_continues_only_current_version_files(tmp_path):
    path = tmp_path / "w.jsonl"
    with DatasetWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05) as out:
        out.append(obs(0, sphere_centre_mm=(1.0, 2.0, 3.0)))
    with DatasetWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05, resume=True) as out:
        out.append(obs(1, circle=Circle(centre_yz_mm=(0.0, 1.0), radius_mm=2.0)))
    assert [o.kind for o in read_dataset(path).observations] == ["sphere_centre", "circle"]
    # a version 1 file (written by an older spherecal) is read, not continued
    old = tmp_path / "v1.jsonl"
    header = {"format": "spherecal-dataset", "version": 1, "mounting": "eye_in_hand", "sphere_radius_mm": 19.05,
              "created": "2026-01-01T00:00:00Z"}
    old.write_text(json.dumps(header) + "\n")
    with pytest.raises(DatasetFileError, match=r"v1\.jsonl is in dataset format version 1; only version 2 files can "
                                               r"be continued"):
        DatasetWriter(old, mounting="eye_in_hand", sphere_radius_mm=19.05, resume=True)
    assert read_dataset(old).observations == []


def write_lines(path, observations, version=2):
    header = {"format": "spherecal-dataset", "version": version, "mounting": "eye_in_hand",
              "sphere_radius_mm": 19.05, "created": "2026-01-01T00:00:00Z"}
    path.write_text("\n".join([json.dumps(header)] + [json.dumps(o) for o in observations]) + "\n")


def line(index, **fields):
    d = {"kind": "observation", "index": index, "station": "S1", "timestamp": "2026-01-01T00:00:01Z",
         "base_from_flange": {"translation_mm": [1000.0, 2.0, 3.0], "quaternion_wxyz": [1.0, 0.0, 0.0, 0.0]}}
    d.update({k: v for k, v in fields.items() if v is not ...})
    for k, v in fields.items():
        if v is ...:
            d.pop(k, None)
    return d


SPHERE = {"sphere_centre_mm": [1.0, 2.0, -20.0]}
CIRCLE = {"circle": {"centre_yz_mm": [2.0, -20.0], "radius_mm": 15.0}}
PROFILE = {"profile": {"y_mm": [1.0, 2.0, 3.0], "z_mm": [-20.0, -21.0, -22.0]}}


@pytest.mark.parametrize(
    "fields, message",
    [
        ({**PROFILE, **CIRCLE}, r"needs exactly one of profile, circle and sphere_centre_mm \(got profile and circle\)"),
        ({**SPHERE, **CIRCLE}, r"\(got circle and sphere_centre_mm\)"),
        ({}, r"needs exactly one of profile, circle and sphere_centre_mm \(none given\)"),
        ({"sphere_centre_mm": [1.0, float("nan"), 3.0]}, r"sphere_centre_mm: item 1 is nan: not a finite number"),
        ({"sphere_centre_mm": [1.0, 2.0]}, r"sphere_centre_mm: needs 3 numbers \(x, y, z\), got 2$"),
        ({"sphere_centre_mm": [1.0]}, r"sphere_centre_mm: needs 3 numbers \(x, y, z\), got 1$"),
        ({"sphere_centre_mm": [1.0, 2.0, 3.0, 4.0]}, r"sphere_centre_mm: needs 3 numbers \(x, y, z\), got 4$"),
        ({"circle": {"centre_yz_mm": [2.0], "radius_mm": 15.0}}, r"circle\.centre_yz_mm: needs 2 numbers \(y, z\), got 1$"),
        ({"sphere_centre_mm": [1.0, "2", 3.0]}, r'sphere_centre_mm: must hold only numbers; item 1 is "2"'),
        ({**SPHERE, "sphere_centre_covariance_mm2": [[1e-4, 0, 0], [0, -1e-4, 0], [0, 0, 1e-4]]},
         r"sphere_centre_covariance_mm2: not positive semi-definite \(eigenvalue -0\.0001 mm\^2\)"),
        ({**SPHERE, "sphere_centre_covariance_mm2": [[1e-4, 2e-5, 0], [0, 1e-4, 0], [0, 0, 1e-4]]},
         r"sphere_centre_covariance_mm2: not symmetric \(row 0 column 1 is 2e-05, row 1 column 0 is 0\.0\)$"),
        ({**SPHERE, "sphere_centre_covariance_mm2": [[1e-4, 1e-4, 0], [1e-4, 1e-4, 0], [0, 0, 1e-4]]},
         r"sphere_centre_covariance_mm2: singular"),
        ({**SPHERE, "sphere_centre_covariance_mm2": [[1e-4, 0, 0], [0, float("nan"), 0], [0, 0, 1e-4]]},
         r"sphere_centre_covariance_mm2\[1\]: item 1 is nan"),
        ({**SPHERE, "sphere_centre_covariance_mm2": [1e-4, 1e-4, 1e-4]},
         r"sphere_centre_covariance_mm2: expected a 3x3 matrix"),
        ({**CIRCLE, "sphere_centre_covariance_mm2": [[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-4]]},
         r"sphere_centre_covariance_mm2 is given without sphere_centre_mm"),
        ({"circle": {"centre_yz_mm": [2.0, -20.0], "radius_mm": float("nan")}}, r"circle\.radius_mm: nan is not a finite"),
        ({"circle": {"centre_yz_mm": [2.0, -20.0], "radius_mm": -1.0}}, r"circle\.radius_mm: Input should be greater than 0"),
        ({"circle": {"centre_yz_mm": [2.0, -20.0], "radius_mm": "15"}}, r'circle\.radius_mm: must be a number, got "15"'),
        ({"circle": {"centre_yz_mm": [2.0, -20.0], "radius_mm": 15.0, "radius_std_mm": -0.01}},
         r"circle\.radius_std_mm: Input should be greater than 0"),
        ({"circle": {"centre_yz_mm": [2.0, -20.0], "radius_mm": 15.0, "centre_std_mm": 0.0, "radius_std_mm": 0.01}},
         r"circle\.centre_std_mm: Input should be greater than 0"),
        ({"circle": {"centre_yz_mm": [2.0, -20.0], "radius": 15.0}}, r"circle\.radius: unknown key \(allowed here: .*did you mean 'radius_mm'\?\)"),
        ({**SPHERE, "base_from_flange": {"translation_mm": [1000.0, 2.0, 3.0], "quaternion_wxyz": [0.96, 0.0, 0.0, 0.0]}},
         r"base_from_flange\.quaternion_wxyz: .*has norm 0\.960000; expected a unit quaternion"),
    ],
)
def test_bad_centre_rows_name_line_observation_and_field(tmp_path, fields, message, parser):
    path = tmp_path / "table.jsonl"
    write_lines(path, [line(0, **SPHERE), line(1, **fields), line(2, **SPHERE)])
    with pytest.raises(DatasetFileError, match=r"table\.jsonl line 3 \(observation 1\): .*" + message):
        read_dataset(path)


def test_version_1_files_load_and_refuse_version_2_fields(tmp_path, parser):
    path = tmp_path / "old.jsonl"
    write_lines(path, [line(0, **PROFILE)], version=1)
    assert read_dataset(path).observations[0].kind == "profile"
    write_lines(path, [line(0, **PROFILE), line(1, **CIRCLE)], version=1)
    with pytest.raises(DatasetFileError, match=r"old\.jsonl line 3 \(observation 1\): circle: needs dataset format "
                                               r"version 2 \(the header says version 1\)"):
        read_dataset(path)
    write_lines(path, [line(0)], version=1)
    with pytest.raises(DatasetFileError, match=r"line 2 \(observation 0\): profile: missing \(required in version 1"):
        read_dataset(path)


def test_model_refuses_two_kinds_and_a_bad_covariance(tmp_path):
    with pytest.raises(ValidationError, match="needs exactly one of profile, circle and sphere_centre_mm"):
        obs(0, sphere_centre_mm=(1.0, 2.0, 3.0), circle=Circle(centre_yz_mm=(0.0, 1.0), radius_mm=2.0))
    with pytest.raises(ValidationError, match="not positive semi-definite"):
        obs(0, sphere_centre_mm=(1.0, 2.0, 3.0), sphere_centre_covariance_mm2=((1.0, 2.0, 0.0), (2.0, 1.0, 0.0),
                                                                              (0.0, 0.0, 1.0)))
    with pytest.raises(InputError, match=r"observation 0: sphere_centre contains NaN"):
        write_dataset(tmp_path / "nan.jsonl", Dataset.model_construct(mounting="eye_in_hand", sphere_radius_mm=10.0,
                                                                      provenance={}, observations=[
            Observation.model_construct(**obs(0, sphere_centre_mm=(1.0, 2.0, 3.0)).__dict__
                                        | {"sphere_centre_mm": (float("nan"), 0.0, 0.0)})]))


def test_the_documented_version_2_example_reads(tmp_path):
    """docs/file-formats.md's centre example (its lines joined again) is a valid file."""
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "file-formats.md").read_text(encoding="utf-8")
    block = doc.split("### Example: centre observations (version 2)")[1].split("```json\n")[1].split("```")[0]
    lines: list[str] = []
    for text in block.splitlines():
        if text.startswith(" ") and lines:
            lines[-1] += text.strip()
        else:
            lines.append(text)
    path = tmp_path / "doc.jsonl"
    path.write_text("\n".join(lines) + "\n")
    ds = read_dataset(path)
    assert [o.kind for o in ds.observations] == ["sphere_centre", "sphere_centre", "circle", "circle"]
    assert ds.observations[0].sphere_centre_covariance_mm2 is not None and ds.observations[2].circle.radius_std_mm == 0.006


@pytest.mark.parametrize("known", ["centre_std_mm", "radius_std_mm"])
def test_a_circle_with_one_standard_deviation_round_trips(tmp_path, known):
    obs = [line(0, **SPHERE), line(1, circle={"centre_yz_mm": [2.0, -20.0], "radius_mm": 15.0, known: 0.02})]
    path = tmp_path / "one_sd.jsonl"
    write_lines(path, obs)
    ds = read_dataset(path)
    circle = ds.observations[1].circle
    other = "radius_std_mm" if known == "centre_std_mm" else "centre_std_mm"
    assert getattr(circle, known) == 0.02 and getattr(circle, other) is None
    again = tmp_path / "again.jsonl"
    write_dataset(again, ds)
    assert read_dataset(again).observations[1].circle == circle
