"""The MTConnect 2.4 vocabulary the codecs need: element names and the values each element may hold.

Most observation elements are the data item type in PascalCase (`PATH_FEEDRATE` ->
`PathFeedrate`); `ELEMENT_EXCEPTIONS` lists the ones the 2.4 schema spells otherwise
(including its own typo `FeaturePersisitentId`). The value sets are copied from
MTConnectStreams_2.4.xsd; tests/unit/codecs/mtconnect/test_vocabulary.py checks them against the file.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime

from gateway.codecs.mtconnect.errors import ValueRejected
from gateway.codecs.mtconnect.timestamps import format_timestamp, parse_timestamp

UNAVAILABLE = "UNAVAILABLE"

ELEMENT_EXCEPTIONS: dict[str, str] = {
    "PH": "PH",
    "AMPERAGE_AC": "AmperageAC",
    "AMPERAGE_DC": "AmperageDC",
    "VOLTAGE_AC": "VoltageAC",
    "VOLTAGE_DC": "VoltageDC",
    "ADAPTER_URI": "AdapterURI",
    "MTCONNECT_VERSION": "MTConnectVersion",
    "FEATURE_PERSISTENT_ID": "FeaturePersisitentId",
}

# Types whose value is three floats ("x y z").
THREE_SPACE: frozenset[str] = frozenset(
    {"ORIENTATION", "PATH_POSITION", "POSITION_CARTESIAN", "ROTATION", "TRANSLATION"}
)
INTEGER_EVENTS: frozenset[str] = frozenset(
    {
        "ACTIVATION_COUNT",
        "ASSET_COUNT",
        "BLOCK_COUNT",
        "CYCLE_COUNT",
        "DEACTIVATION_COUNT",
        "LINE_NUMBER",
        "LOAD_COUNT",
        "MATERIAL_LAYER",
        "NETWORK_PORT",
        "PART_COUNT",
        "PROGRAM_NEST_LEVEL",
        "TRANSFER_COUNT",
        "UNLOAD_COUNT",
    }
)
FLOAT_EVENTS: frozenset[str] = frozenset(
    {
        "AXIS_FEEDRATE_OVERRIDE",
        "HARDNESS",
        "MEASUREMENT_VALUE",
        "PATH_FEEDRATE_OVERRIDE",
        "ROTARY_VELOCITY_OVERRIDE",
        "THICKNESS",
        "TOOL_OFFSET",
        "UNCERTAINTY",
    }
)
DATETIME_EVENTS: frozenset[str] = frozenset({"CLOCK_TIME", "DATE_CODE"})

# EVENT types with a controlled vocabulary (UNAVAILABLE is always allowed besides these).
CONTROLLED: dict[str, frozenset[str]] = {
    "ACTUATOR_STATE": frozenset({"ACTIVE", "INACTIVE"}),
    "AVAILABILITY": frozenset({"AVAILABLE"}),
    "AXIS_COUPLING": frozenset({"TANDEM", "SYNCHRONOUS", "MASTER", "SLAVE"}),
    "AXIS_INTERLOCK": frozenset({"ACTIVE", "INACTIVE"}),
    "AXIS_STATE": frozenset({"HOME", "TRAVEL", "PARKED", "STOPPED"}),
    "CHUCK_INTERLOCK": frozenset({"ACTIVE", "INACTIVE"}),
    "CHUCK_STATE": frozenset({"OPEN", "CLOSED", "UNLATCHED"}),
    "CONTROLLER_MODE": frozenset(
        {"AUTOMATIC", "MANUAL", "MANUAL_DATA_INPUT", "SEMI_AUTOMATIC", "EDIT", "FEED_HOLD"}
    ),
    "CONTROLLER_MODE_OVERRIDE": frozenset({"ON", "OFF"}),
    "DIRECTION": frozenset({"CLOCKWISE", "COUNTER_CLOCKWISE", "POSITIVE", "NEGATIVE"}),
    "DOOR_STATE": frozenset({"OPEN", "CLOSED", "UNLATCHED"}),
    "EMERGENCY_STOP": frozenset({"ARMED", "TRIGGERED"}),
    "END_OF_BAR": frozenset({"YES", "NO"}),
    "EQUIPMENT_MODE": frozenset({"ON", "OFF"}),
    "EXECUTION": frozenset(
        {
            "READY",
            "ACTIVE",
            "INTERRUPTED",
            "FEED_HOLD",
            "STOPPED",
            "OPTIONAL_STOP",
            "PROGRAM_STOPPED",
            "PROGRAM_COMPLETED",
            "WAIT",
            "PROGRAM_OPTIONAL_STOP",
        }
    ),
    "FUNCTIONAL_MODE": frozenset({"PRODUCTION", "SETUP", "TEARDOWN", "MAINTENANCE", "PROCESS_DEVELOPMENT"}),
    "PART_DETECT": frozenset({"PRESENT", "NOT_PRESENT"}),
    "PATH_MODE": frozenset({"INDEPENDENT", "MASTER", "SYNCHRONOUS", "MIRROR"}),
    "POWER_STATE": frozenset({"ON", "OFF"}),
    "POWER_STATUS": frozenset({"ON", "OFF"}),
    "PROGRAM_EDIT": frozenset({"ACTIVE", "READY", "NOT_READY"}),
    "PROGRAM_LOCATION_TYPE": frozenset({"LOCAL", "EXTERNAL"}),
    "ROTARY_MODE": frozenset({"SPINDLE", "INDEX", "CONTOUR"}),
    "SPINDLE_INTERLOCK": frozenset({"ACTIVE", "INACTIVE"}),
    "WAIT_STATE": frozenset(
        {
            "POWERING_UP",
            "POWERING_DOWN",
            "PART_LOAD",
            "PART_UNLOAD",
            "TOOL_LOAD",
            "TOOL_UNLOAD",
            "MATERIAL_LOAD",
            "MATERIAL_UNLOAD",
            "SECONDARY_PROCESS",
            "PAUSING",
            "RESUMING",
        }
    ),
    "PART_STATUS": frozenset({"PASS", "FAIL"}),
    "CONNECTION_STATUS": frozenset({"CLOSED", "LISTEN", "ESTABLISHED"}),
    "PART_PROCESSING_STATE": frozenset(
        {
            "NEEDS_PROCESSING",
            "IN_PROCESS",
            "PROCESSING_ENDED",
            "PROCESSING_ENDED_COMPLETE",
            "PROCESSING_ENDED_STOPPED",
            "PROCESSING_ENDED_ABORTED",
            "PROCESSING_ENDED_LOST",
            "PROCESSING_ENDED_SKIPPED",
            "PROCESSING_ENDED_REJECTED",
            "WAITING_FOR_TRANSIT",
            "IN_TRANSIT",
            "TRANSIT_COMPLETE",
        }
    ),
    "PROCESS_STATE": frozenset({"INITIALIZING", "READY", "ACTIVE", "COMPLETE", "INTERRUPTED", "ABORTED"}),
    "VALVE_STATE": frozenset({"OPEN", "OPENING", "CLOSED", "CLOSING"}),
    "LOCK_STATE": frozenset({"LOCKED", "UNLOCKED"}),
    "OPERATING_MODE": frozenset({"AUTOMATIC", "MANUAL", "SEMI_AUTOMATIC"}),
    "PART_COUNT_TYPE": frozenset({"EACH", "BATCH"}),
    "LEAK_DETECT": frozenset({"DETECTED", "NOT_DETECTED"}),
    "BATTERY_STATE": frozenset({"CHARGED", "CHARGING", "DISCHARGING", "DISCHARGED"}),
    "CHARACTERISTIC_STATUS": frozenset(
        {
            "PASS",
            "FAIL",
            "REWORK",
            "SYSTEM_ERROR",
            "INDETERMINATE",
            "NOT_ANALYZED",
            "BASIC_OR_THEORETIC_EXACT_DIMENSION",
            "UNDEFINED",
        }
    ),
    "UNCERTAINTY_TYPE": frozenset({"COMBINED", "MEAN"}),
    "INTERFACE_STATE": frozenset({"ENABLED", "DISABLED"}),
}

CONDITION_LEVELS: dict[str, str] = {
    "NORMAL": "Normal",
    "WARNING": "Warning",
    "FAULT": "Fault",
    "UNAVAILABLE": "Unavailable",
}

Number = int | float
RawValue = str | int | float | bool | datetime | Sequence[Number] | None


def element_name(data_item_type: str) -> str:
    """The observation element of a SAMPLE or EVENT type: `PATH_FEEDRATE` -> `PathFeedrate`.

    Extension types (`x:MY_TYPE`) keep their prefix: `x:MyType`.
    """
    special = ELEMENT_EXCEPTIONS.get(data_item_type)
    if special is not None:
        return special
    prefix, _, local = data_item_type.rpartition(":")
    pascal = "".join(word[:1] + word[1:].lower() for word in local.split("_"))
    return f"{prefix}:{pascal}" if prefix else pascal


def format_float(value: float) -> str:
    """An xs:float lexical form: Python's shortest repr, with INF/-INF/NaN spelled as XML Schema does."""
    if math.isfinite(value):
        text = repr(value)
        return text.removesuffix(".0")
    if math.isnan(value):
        return "NaN"
    return "INF" if value > 0 else "-INF"


def _number(value: RawValue, what: str) -> float:
    if isinstance(value, bool) or value is None:
        raise ValueRejected(f"{what} needs a number, not {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            raise ValueRejected(f"{what} needs a number, not {value!r}") from None
    raise ValueRejected(f"{what} needs a number, not {type(value).__name__}")


def _floats(value: RawValue, what: str, count: int | None) -> str:
    if isinstance(value, str):
        parts: list[RawValue] = list(value.split())
    elif isinstance(value, Sequence):
        parts = list(value)
    else:
        raise ValueRejected(f"{what} needs a list of numbers, not {value!r}")
    if count is not None and len(parts) != count:
        raise ValueRejected(f"{what} needs {count} numbers, got {len(parts)}")
    if not parts:
        raise ValueRejected(f"{what} needs at least one number")
    return " ".join(format_float(_number(p, what)) for p in parts)


def render_value(category: str, data_item_type: str, value: RawValue, *, time_series: bool = False) -> str:
    """The text of an observation element for `value`, checked against what 2.4 allows.

    None and "UNAVAILABLE" (any case) give UNAVAILABLE. Raises ValueRejected for a
    value the element cannot hold: a word for a SAMPLE, 2 numbers for a PATH_POSITION,
    a word outside an EVENT's controlled vocabulary. CONDITION text is free.
    """
    if value is None or (isinstance(value, str) and value.upper() == UNAVAILABLE):
        return UNAVAILABLE
    what = f"{data_item_type} {category}"
    if category == "SAMPLE":
        if time_series:
            return _floats(value, what, None)
        if data_item_type in THREE_SPACE:
            return _floats(value, what, 3)
        return format_float(_number(value, what))
    if category == "EVENT":
        if data_item_type in THREE_SPACE:
            return _floats(value, what, 3)
        if data_item_type in INTEGER_EVENTS:
            number = _number(value, what)
            if not number.is_integer():
                raise ValueRejected(f"{what} needs an integer, not {value!r}")
            return str(int(number))
        if data_item_type in FLOAT_EVENTS:
            return format_float(_number(value, what))
        if data_item_type in DATETIME_EVENTS:
            if isinstance(value, datetime):
                return format_timestamp(value)
            if isinstance(value, str) and parse_timestamp(value) is not None:
                return value
            raise ValueRejected(f"{what} needs an ISO 8601 date-time, not {value!r}")
        allowed = CONTROLLED.get(data_item_type)
        if allowed is not None:
            word = str(value).upper()
            if word not in allowed:
                raise ValueRejected(f"{what} must be one of {', '.join(sorted(allowed))}, not {value!r}")
            return word
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return format_float(value)
    if isinstance(value, datetime):
        return format_timestamp(value)
    if isinstance(value, (str, int)):
        return str(value)
    return " ".join(str(v) for v in value)
