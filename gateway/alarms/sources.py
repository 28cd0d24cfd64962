"""Where a machine's active alarm list comes from, and how it is compared with what the gateway knows.

`read_parallel` and `diff` are pure. `ArrayAlarmSource` reads the mapped parallel
arrays from the tree (the simulator's `ActiveAlarms/Ids|Texts|Severities`, and
most PLCs' alarm buffers); a driver that reports alarms its own way adds a class
with the same two members (`nodes`, `read()`) and a `type` in gateway/alarms/config.py.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING, Any, Protocol

from gateway.alarms.config import AlarmsConfig, ArraySource, ConditionSource, condition_variables
from gateway.alarms.records import ActiveAlarm, AlarmRecord
from gateway.codecs.mtconnect.conditions import parse_condition_text

if TYPE_CHECKING:
    from gateway.model.tree import Machine, VariableNode

EMPTY_IDS = frozenset({"", "0"})  # fixed-size PLC alarm buffers fill their unused slots with 0 or ""


@dataclass(frozen=True, slots=True)
class Reading:
    """The controller's active list now. `alarms` is None while it cannot be read (controller away)."""

    alarms: list[ActiveAlarm] | None
    ts: datetime  # the controller's time of the latest change of the list
    consistent: bool = True  # False: the arrays disagree in length (one of them has not arrived yet)
    status: str = "Good"
    reason: str = ""


class AlarmSource(Protocol):
    nodes: frozenset[VariableNode]

    def read(self) -> Reading: ...


def read_parallel(
    ids: Sequence[Any],
    texts: Sequence[Any] | None = None,
    classes: Sequence[Any] | None = None,
    parameters: Mapping[str, Sequence[Any]] | None = None,
) -> list[ActiveAlarm]:
    """Entry i of every array is alarm i. Missing entries are left empty; empty slots are skipped."""
    out = []
    for index, raw in enumerate(ids):
        alarm_id = str(raw).strip()
        if alarm_id in EMPTY_IDS:
            continue
        text = str(texts[index]) if texts is not None and index < len(texts) else ""
        severity_class = None
        if classes is not None and index < len(classes):
            value = classes[index]
            severity_class = value if isinstance(value, int) and not isinstance(value, bool) else None
        params = {name: arr[index] for name, arr in (parameters or {}).items() if index < len(arr)}
        out.append(ActiveAlarm(alarm_id, text or f"Alarm {alarm_id}", severity_class, params))
    return out


def diff(
    active: Mapping[str, AlarmRecord], now: Sequence[ActiveAlarm]
) -> tuple[list[ActiveAlarm], list[AlarmRecord]]:
    """(raised, cleared) between the active occurrences (by alarm id) and the controller's list.

    An id listed twice counts once (the first entry wins). An id that stays
    listed is the same occurrence, whatever its text does meanwhile.
    """
    listed: dict[str, ActiveAlarm] = {}
    for entry in now:
        listed.setdefault(entry.id, entry)
    raised = [entry for alarm_id, entry in listed.items() if alarm_id not in active]
    cleared = [record for alarm_id, record in active.items() if alarm_id not in listed]
    return raised, cleared


class ArrayAlarmSource:
    """Reads the parallel arrays the mapping names."""

    def __init__(self, machine: Machine, config: AlarmsConfig) -> None:
        source = config.source
        assert isinstance(source, ArraySource)
        nodes = machine.nodes
        self.ids = nodes[source.ids]
        self.texts = nodes[source.texts] if source.texts else None
        self.classes = nodes[source.severities] if source.severities else None
        self.parameters = {name: nodes[path] for name, path in source.parameters.items()}
        self.nodes = frozenset(
            n for n in (self.ids, self.texts, self.classes, *self.parameters.values()) if n is not None
        )

    def read(self) -> Reading:
        ids = self.ids.sample
        for node in self.nodes:
            sample = node.sample
            if not sample.good:
                return Reading(None, ids.source_ts, True, sample.status, sample.reason or sample.status)
        arrays = [n.sample.value for n in self.nodes]
        consistent = len({len(a) if isinstance(a, list) else -1 for a in arrays}) == 1
        alarms = read_parallel(
            _list(ids.value),
            _list(self.texts.sample.value) if self.texts is not None else None,
            _list(self.classes.sample.value) if self.classes is not None else None,
            {name: _list(node.sample.value) for name, node in self.parameters.items()},
        )
        ts = max(n.sample.source_ts for n in self.nodes)
        return Reading(alarms, ts, consistent)


def _list(value: Any) -> list[Any]:
    return list(value) if isinstance(value, (list, tuple)) else []


class ConditionAlarmSource:
    """The active Warnings and Faults of MTConnect CONDITION variables (String[] lists, codecs/mtconnect).

    An alarm's id is the condition's id (else its native code); where two data items use the
    same id, the second one's alarm is `<path>:<id>`. Its severity class is the level's
    (`classes`), its text the condition's message, and the native severity, qualifier, level
    and data item go along as parameters.
    """

    def __init__(self, machine: Machine, config: AlarmsConfig, paths: Sequence[str]) -> None:
        source = config.source
        assert isinstance(source, ConditionSource)
        self.classes: dict[str, int] = {str(level): cls for level, cls in source.classes.items()}
        self.items = [machine.nodes[path] for path in paths]
        self.nodes = frozenset(self.items)

    def read(self) -> Reading:
        for node in self.items:
            sample = node.sample
            if not sample.good:
                return Reading(None, sample.source_ts, True, sample.status, sample.reason or sample.status)
        alarms: list[ActiveAlarm] = []
        seen: set[str] = set()
        for node in self.items:
            for text in _list(node.sample.value):
                try:
                    condition = parse_condition_text(str(text))
                except ValueError:
                    continue
                alarm_id = condition.condition_id or condition.native_code or node.path
                if alarm_id in seen:
                    alarm_id = f"{node.path}:{alarm_id}"
                seen.add(alarm_id)
                parameters: dict[str, Any] = {"level": condition.level, "item": node.path}
                if condition.native_severity is not None:
                    parameters["native_severity"] = condition.native_severity
                if condition.qualifier is not None:
                    parameters["qualifier"] = condition.qualifier
                text_out = condition.text or f"{condition.level.capitalize()} {alarm_id}"
                alarms.append(ActiveAlarm(alarm_id, text_out, self.classes.get(condition.level), parameters))
        ts = max(n.sample.source_ts for n in self.items)
        return Reading(alarms, ts)


def source_for(machine: Machine, config: AlarmsConfig, variables: Sequence[Any] = ()) -> AlarmSource:
    """The machine's alarm source; `variables` (the mapping's) resolve a conditions source's default list."""
    if isinstance(config.source, ConditionSource):
        return ConditionAlarmSource(machine, config, condition_variables(config.source, variables))
    return ArrayAlarmSource(machine, config)
