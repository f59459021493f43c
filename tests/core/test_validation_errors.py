"""The one formatter of pydantic validation errors: a line per problem, by dotted path,
the refused value shown, unknown keys answered with the keys allowed, a list of the wrong
length said once with its components."""

from __future__ import annotations

import pytest
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from spherecal.core.validation_errors import field_annotation, location_text, validation_error_lines


class Inner(BaseModel):
    model_config = ConfigDict(extra="forbid")

    speed_mm_s: float = Field(gt=0)
    centre_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)


class Outer(BaseModel):
    model_config = ConfigDict(extra="forbid")

    inner: Inner | None = None
    items: list[Inner] = []
    name: str = "x"

    @field_validator("name")
    @classmethod
    def _short(cls, v):
        if len(v) > 3:
            raise ValueError(f"name {v!r} is longer than 3 characters")
        return v


def lines(data, **kwargs) -> list[str]:
    with pytest.raises(ValidationError) as exc:
        Outer.model_validate(data)
    return validation_error_lines(exc.value, **kwargs)


def test_each_problem_is_one_line_by_dotted_path_with_the_value_refused():
    assert lines({"inner": {"speed_mm_s": -1}, "items": [{"speed_mm_s": 1}, {"speed_mm_s": 0}]}, path="cell") == [
        "cell.inner.speed_mm_s: Input should be greater than 0 (got -1)",
        "cell.items[1].speed_mm_s: Input should be greater than 0 (got 0)",
    ]


def test_a_validator_message_is_given_as_written():
    assert lines({"name": "abcdef"}) == ["name: name 'abcdef' is longer than 3 characters"]


def test_a_missing_key_is_said_so():
    assert lines({"inner": {}}) == ["inner.speed_mm_s: missing (required)"]


def test_an_unknown_key_names_the_keys_allowed_and_the_one_meant():
    assert lines({"inner": {"speed_mm_s": 1, "sped_mm_s": 2}}, model=Outer) == [
        "inner.sped_mm_s: unknown key (allowed here: speed_mm_s, centre_mm; did you mean 'speed_mm_s'?)"]
    assert lines({"colour": 1}, model=Outer) == ["colour: unknown key (allowed here: inner, items, name)"]
    assert lines({"colour": 1}) == ["colour: unknown key (a typo?)"]


def test_a_list_of_the_wrong_length_is_one_line_naming_its_components():
    assert lines({"inner": {"speed_mm_s": 1, "centre_mm": [1.0]}}) == [
        "inner.centre_mm: needs 3 numbers (x, y, z), got 1"]
    assert lines({"inner": {"speed_mm_s": 1, "centre_mm": [1.0, 2.0, 3.0, 4.0]}}) == [
        "inner.centre_mm: needs 3 numbers (x, y, z), got 4"]


def test_a_long_value_is_cut_short():
    (line,) = lines({"inner": {"speed_mm_s": "x" * 200}})
    assert line.endswith("...)") and "x" * 56 in line and "x" * 57 not in line


def test_locations_and_annotations():
    assert location_text("", ["a", 0, "b"]) == "a[0].b"
    assert location_text("export.x", [2]) == "export.x[2]"
    assert field_annotation(Outer, ["items", 0, "speed_mm_s"]) is float
    assert field_annotation(Outer, ["inner"]) is Inner
    assert field_annotation(Outer, ["nothing"]) is None
