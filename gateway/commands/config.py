"""A machine's `commands:` section: named operations made of writes, a guard and a completion condition.

```yaml
commands:
  select-program:
    description: Select a program from the controller's program store
    arguments: [{name: name, type: String, description: Program file name}]
    allowed: {path: Machine/State, in: [0, 3], names: {0: Idle, 1: Running, 2: Paused, 3: Alarm}}
    writes:
      - {path: Control/SelectProgram, value: "{name}"}    # "{name}": the argument, typed
    done: {path: Program/Name, equals: "{name}"}
    timeout: 5                                             # seconds; no command waits longer
    role: operator                                         # lowest role that may run it
```

A condition is `{path, equals: V}`, `{path, in: [V, ...]}` or `{path, not: V}` (`not`
also takes a list). `names` gives values a label for the reasons users read
("Machine/State is 3 (Alarm)"). A value that is exactly `"{arg}"` stands for the
argument with its type; text around a placeholder (`"/DATA/{name}"`) makes a
String, and `{{`/`}}` are literal braces.

Everything that can be checked without a controller is checked at load by
`command_issues`, which MachineMapping calls so that each error names its key:
paths exist (and are writable, for writes), placeholders name arguments, and
literal values fit the variable's type and range.
"""

from __future__ import annotations

import json
import re
import string
from collections.abc import Mapping, Sequence
from typing import Annotated, Any

from pydantic import AfterValidator, BeforeValidator, Field, field_validator, model_validator

from gateway.errors import RequestError
from gateway.model.types import TypeSpec, coerce
from gateway.settings.access import check_role_name
from gateway.settings.base import Strict, TypeField

NAME_RE = re.compile(r"^[a-z][a-z0-9_\-]{0,62}$")
ARG_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,62}$")
RESERVED_NAMES = frozenset({"set", "result"})  # MQTT: <topic>/set and …/result belong to writes and answers
MAX_TIMEOUT = 3600.0

Scalar = bool | int | float | str
Value = Scalar | list[Scalar]
Loc = tuple[str | int, ...]


def _names(value: Any) -> Any:
    """YAML reads `{0: Idle}` with integer keys; labels are looked up by the value's text."""
    if isinstance(value, Mapping):
        return {str(k).lower() if isinstance(k, bool) else str(k): v for k, v in value.items()}
    return value


class Condition(Strict):
    """A test on one variable's current value."""

    path: str = Field(description="The variable tested, e.g. Machine/State")
    equals: Scalar | None = Field(default=None, description="Holds when the value equals this")
    in_: list[Scalar] | None = Field(
        default=None, alias="in", description="Holds when the value is one of these"
    )
    not_: Value | None = Field(
        default=None, alias="not", description="Holds when the value is not this (or none of these)"
    )
    names: Annotated[dict[str, str], BeforeValidator(_names)] = Field(
        default_factory=dict, description="Labels of values, for reasons: {0: Idle, 3: Alarm}"
    )

    @model_validator(mode="after")
    def _one_test(self) -> Condition:
        given = [
            k for k, v in (("equals", self.equals), ("in", self.in_), ("not", self.not_)) if v is not None
        ]
        if len(given) != 1:
            raise ValueError(
                "a condition needs exactly one of equals, in or not"
                + (f" (got {', '.join(given)})" if given else "")
            )
        if self.in_ is not None and not self.in_:
            raise ValueError("in: must list at least one value")
        return self

    @property
    def values(self) -> list[Scalar]:
        """Every value the condition names, whatever the test."""
        if self.equals is not None:
            return [self.equals]
        if self.in_ is not None:
            return list(self.in_)
        return list(self.not_) if isinstance(self.not_, list) else [self.not_]  # type: ignore[list-item]

    @property
    def negated(self) -> bool:
        return self.not_ is not None


class WriteStep(Strict):
    """One write of a command, through the tree's ordinary write path."""

    path: str = Field(description="A mapped variable with access: readwrite")
    value: Value = Field(description='The value; "{arg}" is an argument, "text {arg}" a String made from one')


class CommandArgument(Strict):
    """A typed input of a command (an OPC UA method argument, a key of an MQTT request)."""

    name: str = Field(description="Letters, digits and '_'; referenced as {name}")
    type: TypeField
    description: str = ""

    @field_validator("name")
    @classmethod
    def _name(cls, name: str) -> str:
        if not ARG_RE.match(name):
            raise ValueError(
                f"argument name {name!r} must be letters, digits and '_', not starting with a digit"
            )
        return name


class CommandSpec(Strict):
    """One command: writes, then wait until `done` holds (or `timeout` passes)."""

    description: str = ""
    arguments: list[CommandArgument] = Field(default_factory=list)
    allowed: Condition | None = Field(
        default=None, description="Guard: the command is refused (BadInvalidState) unless this holds"
    )
    writes: list[WriteStep] = Field(
        min_length=1, description="Carried out in order; the first refusal ends the command"
    )
    done: Condition | None = Field(
        default=None,
        description="Completion: the command succeeds once this holds; "
        "without it, once the writes are accepted",
    )
    timeout: float = Field(default=10.0, gt=0, le=MAX_TIMEOUT, description="Seconds for the whole command")
    role: str = Field(default="operator", description="Lowest role that may run it")

    @field_validator("role")
    @classmethod
    def _role(cls, value: str) -> str:
        return check_role_name(value)

    @field_validator("arguments")
    @classmethod
    def _unique(cls, args: list[CommandArgument]) -> list[CommandArgument]:
        seen: set[str] = set()
        for arg in args:
            if arg.name in seen:
                raise ValueError(f"argument {arg.name!r} is declared twice")
            seen.add(arg.name)
        return args


def check_command_name(name: str) -> str:
    if not NAME_RE.match(name):
        raise ValueError(
            f"command name {name!r} must be 1-63 lower-case letters, digits, '-' or '_', "
            "starting with a letter"
        )
    if name in RESERVED_NAMES:
        raise ValueError(f"{name!r} is reserved for MQTT write requests and answers")
    return name


# A command's name: the OPC UA method's browse name and the last level of its MQTT topic.
CommandName = Annotated[str, AfterValidator(check_command_name)]


# --- placeholders ---------------------------------------------------------------------------------


def placeholders(text: str) -> list[str]:
    """The argument names a text refers to. Raises ValueError for unbalanced braces or fancy fields."""
    names = []
    for _, field, spec, conversion in string.Formatter().parse(text):
        if field is None:
            continue
        if not ARG_RE.match(field) or spec or conversion:
            raise ValueError(
                f"{{{field}{'!' + conversion if conversion else ''}{':' + spec if spec else ''}}} "
                "is not a plain {argument} reference"
            )
        names.append(field)
    return names


def whole_reference(value: Any) -> str | None:
    """The argument name when `value` is exactly "{name}" (the typed argument itself), else None."""
    if (
        isinstance(value, str)
        and value.startswith("{")
        and value.endswith("}")
        and not value.startswith("{{")
    ):
        inner = value[1:-1]
        if ARG_RE.match(inner):
            return inner
    return None


def render(value: Any, args: Mapping[str, Any]) -> Any:
    """A configured value with the arguments put in (checked at load, so this cannot fail on names)."""
    if isinstance(value, list):
        return [render(v, args) for v in value]
    if not isinstance(value, str):
        return value
    ref = whole_reference(value)
    if ref is not None:
        return args[ref]
    if "{" in value or "}" in value:
        return value.format_map(dict(args))
    return value


# --- cross-checks ---------------------------------------------------------------------------------


def command_issues(commands: Mapping[str, CommandSpec], variables: Sequence[Any]) -> list[tuple[Loc, str]]:
    """(location below `commands`, message) for each reference that does not resolve or value that misfits."""
    by_path = {v.path: v for v in variables}
    issues: list[tuple[Loc, str]] = []
    for name, spec in commands.items():
        args = {a.name: a.type for a in spec.arguments}
        for index, step in enumerate(spec.writes):
            loc: Loc = (name, "writes", index)
            var = by_path.get(step.path)
            if var is None:
                issues.append(((*loc, "path"), f"{step.path!r} is not a variable of this mapping"))
                continue
            if not var.writable:
                issues.append(((*loc, "path"), f"{step.path} must have access: readwrite to be written"))
                continue
            issues += [((*loc, "value"), m) for m in _value_issues(step.value, var, args)]
        for key in ("allowed", "done"):
            cond = getattr(spec, key)
            if cond is None:
                continue
            var = by_path.get(cond.path)
            if var is None:
                issues.append(((name, key, "path"), f"{cond.path!r} is not a variable of this mapping"))
                continue
            test = "equals" if cond.equals is not None else "in" if cond.in_ is not None else "not"
            for value in cond.values:
                issues += [((name, key, test), m) for m in _value_issues(value, var, args, scalar=True)]
    return issues


def _value_issues(value: Any, var: Any, args: Mapping[str, TypeSpec], *, scalar: bool = False) -> list[str]:
    target: TypeSpec = var.type
    if scalar and target.array:
        return [f"{var.path} is an array ({target}); conditions test scalar variables"]
    ref = whole_reference(value)
    if ref is not None:
        arg_type = args.get(ref)
        if arg_type is None:
            return [_unknown(ref, args)]
        if arg_type != target and not (arg_type.is_numeric and target.is_numeric and not target.array):
            return [f"argument {ref} is {arg_type}, but {var.path} is {target}"]
        return []
    texts = [v for v in (value if isinstance(value, list) else [value]) if isinstance(v, str)]
    templated = False
    for text in texts:
        try:
            refs = placeholders(text)
        except ValueError as exc:
            return [f"{text!r}: {exc}"]
        for ref in refs:
            if ref not in args:
                return [_unknown(ref, args)]
        templated = templated or bool(refs)
    if templated:
        if target.base.value != "String":
            return [f"text with {{arguments}} makes a String, but {var.path} is {target}"]
        return []
    try:
        literal = value if not isinstance(value, str) else value.replace("{{", "{").replace("}}", "}")
        if isinstance(literal, list):
            literal = [v.replace("{{", "{").replace("}}", "}") if isinstance(v, str) else v for v in literal]
        checked = coerce(target, literal)
        if var.range is not None:
            for v in checked if isinstance(checked, list) else [checked]:
                if not var.range.min <= v <= var.range.max:
                    return [f"{v} is outside the range {var.range.min:g}..{var.range.max:g} of {var.path}"]
    except RequestError as exc:  # TypeMismatch, OutOfRange
        return [f"{json.dumps(value, ensure_ascii=False)} does not fit {var.path}: {exc.reason}"]
    return []


def _unknown(ref: str, args: Mapping[str, TypeSpec]) -> str:
    known = ", ".join(args) if args else "none"
    return f"{{{ref}}} names no argument of this command (arguments: {known})"
