"""ValidationRules: dialect presets, overrides on top of them, and errors that name the key."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from gateway.config.validation import PRESETS, ValidationRules


def test_defaults_are_the_generic_dialect() -> None:
    rules = ValidationRules()
    assert rules == ValidationRules.for_dialect("generic")
    assert (rules.markers, rules.end_code, rules.utf8_comments, rules.xon_xoff) == (
        "optional",
        "anywhere",
        True,
        "strip",
    )
    assert rules.end_codes == ("M30", "M2")
    assert ".nc" in rules.extensions and rules.max_name_length == 32


@pytest.mark.parametrize(
    ("dialect", "expected"),
    [
        (
            "fanuc",
            {
                "markers": "require",
                "program_name": "must-match",
                "end_code": "last",
                "dwell_p": "milliseconds",
            },
        ),
        (
            "linuxcnc",
            {"markers": "optional", "program_name": "ignore", "end_codes": ("M2", "M30"), "macros": "warn"},
        ),
        (
            "sinumerik",
            {"markers": "forbid", "end_codes": ("M30", "M2", "M17"), "extensions": (".mpf", ".spf")},
        ),
        (
            "laser-sim",
            {"markers": "optional", "utf8_comments": True, "end_code": "last", "rapid_feed": 30000.0},
        ),
    ],
)
def test_presets(dialect: str, expected: dict[str, object]) -> None:
    rules = ValidationRules.for_dialect(dialect)
    assert rules.dialect == dialect
    for key, value in expected.items():
        assert getattr(rules, key) == value, key


def test_user_keys_override_the_preset_and_the_rest_comes_from_it() -> None:
    rules = ValidationRules.model_validate(
        {"dialect": "fanuc", "markers": "optional", "max_line_length": 128}
    )
    assert rules.markers == "optional" and rules.max_line_length == 128
    assert rules.program_name == "must-match"  # still Fanuc's


def test_every_preset_is_valid() -> None:
    for dialect in PRESETS:
        ValidationRules.for_dialect(dialect)


def test_rules_are_frozen_and_strict() -> None:
    rules = ValidationRules()
    with pytest.raises(ValidationError):
        rules.markers = "forbid"  # type: ignore[misc]
    with pytest.raises(ValidationError) as info:
        ValidationRules.model_validate({"marker": "require"})
    assert info.value.errors()[0]["loc"] == ("marker",)


@pytest.mark.parametrize(
    ("data", "loc", "fragment"),
    [
        ({"dialect": "heidenhain"}, ("dialect",), "generic"),
        ({"end_codes": ["M30", "X1"]}, ("end_codes",), "end_codes: 'X1' is not a G or M code"),
        ({"forbid_codes": ["M9 8"]}, ("forbid_codes",), "forbid_codes: 'M9 8'"),
        ({"extensions": ["nc"]}, ("extensions",), "extensions: 'nc' must be ''"),
        ({"extensions": []}, ("extensions",), "at least one"),
        (
            {"file_name_pattern": "[a-"},
            ("file_name_pattern",),
            "file_name_pattern is not a valid regular expression",
        ),
        ({"max_line_length": 0}, ("max_line_length",), "greater than or equal to 1"),
        ({"rapid_feed": -5}, ("rapid_feed",), "greater than 0"),
        ({"xon_xoff": "drop"}, ("xon_xoff",), "'reject' or 'strip'"),
    ],
)
def test_errors_name_the_key(data: dict[str, object], loc: tuple[str, ...], fragment: str) -> None:
    with pytest.raises(ValidationError) as info:
        ValidationRules.model_validate(data)
    errors = info.value.errors()
    assert errors[0]["loc"] == loc
    assert fragment in errors[0]["msg"]


def test_cross_field_errors() -> None:
    with pytest.raises(ValidationError, match="end_codes must not be empty"):
        ValidationRules(end_codes=[])
    assert ValidationRules(end_codes=[], end_code="optional").end_codes == ()
    with pytest.raises(ValidationError, match="forbid_codes forbids the end code M30"):
        ValidationRules(forbid_codes=["M030"])


def test_codes_are_normalised() -> None:
    rules = ValidationRules(end_codes=["m02", "M2", "M002", "M30"], forbid_codes=["g05.20"])
    assert rules.end_codes == ("M2", "M30")
    assert rules.forbid_codes == ("G5.2",)


def test_json_schema_is_available() -> None:
    schema = ValidationRules.model_json_schema()
    assert "dialect" in schema["properties"] and schema["additionalProperties"] is False
