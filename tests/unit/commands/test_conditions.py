"""Command conditions: placeholders, binding, testing values, and the words users read."""

from __future__ import annotations

import pytest

from gateway.commands.conditions import bind, same
from gateway.commands.config import Condition, placeholders, render, whole_reference

STATES = {0: "Idle", 1: "Running", 2: "Paused", 3: "Alarm"}


def cond(**kwargs: object) -> Condition:
    return Condition.model_validate({"path": "Machine/State", "names": STATES, **kwargs})


@pytest.mark.parametrize(
    ("condition", "value", "holds"),
    [
        (cond(equals=1), 1, True),
        (cond(equals=1), 1.0, True),
        (cond(equals=1), 2, False),
        (cond(**{"in": [0, 2]}), 2, True),
        (cond(**{"in": [0, 2]}), 3, False),
        (cond(**{"not": 0}), 3, True),
        (cond(**{"not": 0}), 0, False),
        (cond(**{"not": [0, 3]}), 3, False),
        (cond(**{"not": [0, 3]}), 1, True),
    ],
)
def test_a_condition_holds_by_value(condition: Condition, value: object, holds: bool) -> None:
    assert bind(condition, {}).holds(value) is holds


def test_booleans_equal_only_booleans() -> None:
    assert same(True, True) and not same(True, 1) and not same(1, True) and not same(0, False)
    assert same("a", "a") and not same("1", 1)


def test_reasons_name_the_state() -> None:
    check = bind(cond(**{"in": [0, 2]}), {})
    assert check.label(3) == "3 (Alarm)"
    assert str(check) == "Machine/State in 0 (Idle), 2 (Paused)"
    assert bind(cond(**{"not": 0}), {}).expected() == "≠ 0 (Idle)"
    assert bind(cond(equals=1), {}).expected() == "= 1 (Running)"
    assert bind(cond(**{"in": [1]}), {}).expected() == "= 1 (Running)"
    assert (
        bind(Condition.model_validate({"path": "Program/Name", "equals": "x"}), {}).label("a.nc") == "'a.nc'"
    )


def test_arguments_are_put_in_typed_or_as_text() -> None:
    args = {"name": "part.nc", "count": 3}
    assert render("{name}", args) == "part.nc"
    assert render("{count}", args) == 3  # the typed argument itself
    assert render("/DATA/{name} x{count}", args) == "/DATA/part.nc x3"
    assert render("{{literal}}", args) == "{literal}"
    assert render(["{count}", 1], args) == [3, 1]
    assert bind(Condition.model_validate({"path": "Program/Name", "equals": "{name}"}), args).holds("part.nc")


def test_placeholders_are_plain_argument_names() -> None:
    assert placeholders("a {x} b {y_2}") == ["x", "y_2"]
    assert placeholders("{{not}} one") == []
    assert (
        whole_reference("{x}") == "x" and whole_reference("{x} ") is None and whole_reference("{{x}}") is None
    )
    for bad in ("{x.attr}", "{x[0]}", "{x!r}", "{x:>3}", "{", "}"):
        with pytest.raises(ValueError):
            placeholders(bad)
