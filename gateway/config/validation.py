"""Job validation rules: what a machine's controller accepts in a G-code program.

Controllers differ in small ways that decide whether a program runs or stops the
machine halfway through a sheet: `%` markers, the end code, how program names map
to file names, what file names the program store can hold. A `dialect` picks a
preset for all of these; any key the user sets overrides the preset. So
`{dialect: fanuc, max_line_length: 128}` is Fanuc's rules with shorter lines, and
`ValidationRules()` is the `generic` dialect.

The mapping embeds this model as `jobs: {validation: {...}}`.

| key            | generic      | fanuc          | linuxcnc   | sinumerik       | laser-sim  |
|----------------|--------------|----------------|------------|-----------------|------------|
| markers        | optional     | require        | optional   | forbid          | optional   |
| end_codes      | M30, M2      | M30, M2        | M2, M30    | M30, M2, M17    | M30, M2    |
| end_code       | anywhere     | last           | last       | last            | last       |
| program_name   | ignore       | must-match     | ignore     | ignore          | ignore     |
| utf8_comments  | yes          | no             | no         | no              | yes        |
| xon_xoff       | strip        | reject         | reject     | reject          | reject     |
| macros         | warn         | reject         | warn       | reject          | reject     |
| max_line_length| 256          | 256            | 255        | 512             | 256        |
| file names     | plain, 32    | plain, 32, ''  | plain, 255 | PART_1.MPF, 28  | plain, 32  |
| dwell_p        | seconds      | milliseconds   | seconds    | seconds         | seconds    |
| rapid_feed     | 10000        | 10000          | 10000      | 10000           | 30000      |

"plain" names are letters, digits, '_', '-' and '.' (not first), with the common
CAM extensions (.nc .gcode .ngc .mpf .txt .tap .cnc); Fanuc also takes names
without an extension (O1234). max_size is 64 MiB everywhere.
"""

from __future__ import annotations

import re
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from gateway.settings.base import Strict

Dialect = Literal["generic", "fanuc", "linuxcnc", "sinumerik", "laser-sim"]

MIB = 1024 * 1024

#: Extensions that nesting software and CAM posts commonly write.
COMMON_EXTENSIONS = (".nc", ".gcode", ".ngc", ".mpf", ".txt", ".tap", ".cnc")
#: A plain file name: starts with a letter, digit or '_', then letters, digits, '_', '-' and '.'.
PLAIN_NAME = r"[A-Za-z0-9_][A-Za-z0-9_.\-]*"
#: Sinumerik: the first two characters are letters, or '_' and a letter (PART_1.MPF, _N_X.SPF).
SINUMERIK_NAME = r"(?:[A-Za-z]{2}|_[A-Za-z])[A-Za-z0-9_]*\.[A-Za-z]{3}"

#: The presets. Keys not listed take the model's field defaults (which are `generic`).
PRESETS: dict[str, dict[str, Any]] = {
    "generic": {},
    "fanuc": {
        "markers": "require",
        "xon_xoff": "reject",
        "end_code": "last",
        "utf8_comments": False,
        "program_name": "must-match",
        "extensions": ("", ".nc", ".txt", ".tap", ".cnc", ".prg"),
        "dwell_p": "milliseconds",
        "macros": "reject",
    },
    "linuxcnc": {
        "markers": "optional",
        "xon_xoff": "reject",
        "end_code": "last",
        "utf8_comments": False,
        "end_codes": ("M2", "M30"),
        "max_line_length": 255,  # rs274ngc's LINELEN
        "max_name_length": 255,
        "macros": "warn",
    },
    "sinumerik": {
        "markers": "forbid",
        "xon_xoff": "reject",
        "end_code": "last",
        "macros": "reject",
        "utf8_comments": False,
        "end_codes": ("M30", "M2", "M17"),
        "max_line_length": 512,
        "file_name_pattern": SINUMERIK_NAME,
        "max_name_length": 28,
        "extensions": (".mpf", ".spf"),
    },
    "laser-sim": {
        "markers": "optional",
        "xon_xoff": "reject",
        "end_code": "last",
        "macros": "reject",
        "utf8_comments": True,
        "rapid_feed": 30000.0,  # the simulator's RAPID
    },
}

_CODE = re.compile(r"^\s*([GMgm])\s*(\d+(?:\.\d+)?)\s*$")
_EXTENSION = re.compile(r"^(?:|\.[A-Za-z0-9_\-]+)$")


def normalise_code(text: str) -> str:
    """`m02` -> `M2`, `G05.20` -> `G5.2`: the spelling Word.code uses, so codes compare by value."""
    m = _CODE.match(text)
    if not m:
        raise ValueError(f"{text!r} is not a G or M code such as M30 or G5.2")
    value = float(m.group(2))
    number = str(int(value)) if value.is_integer() else repr(value)
    return m.group(1).upper() + number


class ValidationRules(Strict):
    """Per-machine rules for programs arriving in the job inbox. See PRESETS for the dialects."""

    dialect: Dialect = Field(default="generic", description="Preset for every key not set here")
    markers: Literal["require", "forbid", "optional"] = Field(
        default="optional",
        description="'%' start/end marker lines. optional: none, or both a start and an end marker",
    )
    utf8_comments: bool = Field(default=True, description="Allow UTF-8 (non-ASCII) text inside comments")
    xon_xoff: Literal["reject", "strip"] = Field(
        default="strip", description="DC1-DC4 bytes (serial handshake): reject the program, or strip them"
    )
    end_codes: tuple[str, ...] = Field(
        default=("M30", "M2"), description="Codes that end a program (M02 = M2)"
    )
    end_code: Literal["last", "anywhere", "optional"] = Field(
        default="anywhere",
        description="last: an end code is required and no block with codes may follow it; "
        "anywhere: an end code is required somewhere; optional: not checked",
    )
    max_line_length: int = Field(default=256, ge=1, description="Bytes per line, without the line end")
    max_size: int = Field(default=64 * MIB, ge=1, description="Bytes per program")
    program_name: Literal["require", "must-match", "ignore"] = Field(
        default="ignore",
        description="must-match: an O-number or %-header name in the program must match the file name; "
        "require: and the program must carry one",
    )
    file_name_pattern: str = Field(
        default=PLAIN_NAME, description="Regular expression a whole file name must match"
    )
    max_name_length: int = Field(default=32, ge=1, le=255, description="Characters per file name")
    extensions: tuple[str, ...] = Field(
        default=COMMON_EXTENSIONS,
        description="Allowed file extensions, lower-case; '' allows names without one",
    )
    macros: Literal["reject", "warn"] = Field(
        default="warn",
        description="Parameters (#1), expressions and O-word control flow: reject, or accept with a warning",
    )
    forbid_codes: tuple[str, ...] = Field(
        default=(), description="G/M codes this controller must never receive"
    )
    dwell_p: Literal["seconds", "milliseconds"] = Field(
        default="seconds", description="Unit of G4 P (LinuxCNC: seconds; Fanuc: milliseconds)"
    )
    rapid_feed: float = Field(
        default=10000.0, gt=0, description="Machine rapid (G0) speed for estimates, mm/min"
    )
    default_feed: float | None = Field(
        default=None,
        gt=0,
        description="Feed assumed for moves before any F word, mm/min; none: not estimated",
    )

    @model_validator(mode="before")
    @classmethod
    def _apply_preset(cls, data: Any) -> Any:
        """The dialect's preset fills every key the user did not set."""
        if isinstance(data, dict):
            preset = PRESETS.get(data.get("dialect", "generic"))
            if isinstance(preset, dict):
                return {**preset, **data}
        return data

    @classmethod
    def for_dialect(cls, dialect: str, **overrides: Any) -> ValidationRules:
        """The preset for `dialect`, with `overrides` on top (as a mapping file would set them)."""
        return cls.model_validate({"dialect": dialect, **overrides})

    @field_validator("end_codes", "forbid_codes")
    @classmethod
    def _codes(cls, codes: tuple[str, ...], info: Any) -> tuple[str, ...]:
        out: list[str] = []
        for code in codes:
            try:
                normal = normalise_code(code)
            except ValueError as exc:
                raise ValueError(f"{info.field_name}: {exc}") from None
            if normal not in out:
                out.append(normal)
        return tuple(out)

    @field_validator("extensions")
    @classmethod
    def _extensions(cls, extensions: tuple[str, ...]) -> tuple[str, ...]:
        out: list[str] = []
        for ext in extensions:
            if not _EXTENSION.match(ext):
                raise ValueError(f"extensions: {ext!r} must be '' or a dot and letters/digits, e.g. '.nc'")
            if ext.lower() not in out:
                out.append(ext.lower())
        if not out:
            raise ValueError("extensions must list at least one extension ('' allows names without one)")
        return tuple(out)

    @field_validator("file_name_pattern")
    @classmethod
    def _pattern(cls, pattern: str) -> str:
        try:
            re.compile(pattern)
        except re.error as exc:
            raise ValueError(f"file_name_pattern is not a valid regular expression: {exc}") from None
        return pattern

    @model_validator(mode="after")
    def _end_codes_present(self) -> ValidationRules:
        if self.end_code != "optional" and not self.end_codes:
            raise ValueError("end_codes must not be empty unless end_code is 'optional'")
        overlap = set(self.end_codes) & set(self.forbid_codes)
        if overlap and self.end_code != "optional":
            raise ValueError(f"forbid_codes forbids the end code {min(overlap)} that end_codes requires")
        return self

    @property
    def file_name_re(self) -> re.Pattern[str]:
        return re.compile(self.file_name_pattern)
