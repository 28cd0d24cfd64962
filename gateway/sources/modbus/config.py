"""The Modbus TCP driver's settings, and the checks of a Modbus mapping's variables at load time.

```yaml
driver:
  type: modbus
  host: 10.0.0.21
  port: 502
  unit: 1
  order: CDAB            # the device's word/byte order; a variable's source may give its own
  timeout: 2             # seconds per request
  max_gap: 16            # registers read and dropped to save a request (0: only contiguous reads)
variables:
  - {path: Chiller/Supply, source: "input:0:float32", type: Float, sampling_interval: 500}
  - {path: Chiller/Setpoint, source: "40001", type: Float, access: readwrite}
```

Polling groups are the variables' `sampling_interval`s (default `defaults.sampling_interval`). Every
`source` is parsed and resolved against its variable's type here, so that a wrong address, a type the
register cannot hold, a write to a read-only table or two variables on the same register are
`file:line` errors before anything starts: `variable_issues`, which MachineMapping calls on a driver's
settings that have it (the driver spec's `check_address` sees one source at a time, without its type
or its neighbours). `describe_plan` is what `cnc-gateway check` prints for a driver that has it.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable, Sequence
from typing import Literal, Protocol, TypeVar

from pydantic import Field as PydanticField

from gateway.codecs.modbus.address import (
    MAX_BITS,
    MAX_REGISTERS,
    Field,
    ModbusAddressError,
    Order,
    overlaps,
    parse_address,
    resolve,
)
from gateway.codecs.modbus.planner import Limits, plan
from gateway.model.types import TypeSpec
from gateway.settings.base import Backoff, Strict

DEFAULT_PORT = 502
MIN_INTERVAL = 10.0  # ms: faster is a busy loop against a device, not polling

Loc = tuple[int | str, ...]


class MappedVariable(Protocol):
    """What the checks read of a mapped variable (gateway.config.mapping.VariableSpec has it)."""

    @property
    def source(self) -> str: ...

    @property
    def raw_type(self) -> TypeSpec: ...

    @property
    def writable(self) -> bool: ...

    @property
    def sampling_interval(self) -> float | None: ...


V = TypeVar("V", bound=MappedVariable)
K = TypeVar("K", bound=Hashable)


class ModbusDriver(Strict):
    """A Modbus TCP device: a laser source's controller, a chiller, an extractor, a loader, a meter."""

    type: Literal["modbus"]
    host: str = PydanticField(min_length=1, description="The device's address (or its Modbus TCP gateway's)")
    port: int = PydanticField(default=DEFAULT_PORT, ge=1, le=65535)
    unit: int = PydanticField(
        default=1, ge=0, le=255, description="Unit id (the device behind a serial gateway; 1 or 255 on most)"
    )
    timeout: float = PydanticField(default=2.0, gt=0, description="Seconds to connect, and per request")
    order: Order = PydanticField(
        default=Order.ABCD,
        description="Word/byte order of multi-register values: ABCD (big-endian), CDAB (words swapped), "
        "BADC (bytes swapped), DCBA (little-endian); a variable's source may name its own",
    )
    max_registers: int = PydanticField(
        default=MAX_REGISTERS, ge=1, le=MAX_REGISTERS, description="Registers per read request at most"
    )
    max_bits: int = PydanticField(
        default=MAX_BITS, ge=1, le=MAX_BITS, description="Coils or discrete inputs per read request at most"
    )
    max_gap: int = PydanticField(
        default=16,
        ge=0,
        le=MAX_REGISTERS,
        description="Unmapped registers a read may span to save a request (0: contiguous reads only)",
    )
    max_bit_gap: int = PydanticField(
        default=256, ge=0, le=MAX_BITS, description="Unmapped coils or discrete inputs a read may span"
    )
    write_multiple: bool = PydanticField(
        default=False,
        description="Write with FC 15/16 even a single coil or register (for devices without FC 5/6)",
    )
    reconnect: Backoff = Backoff()

    @property
    def endpoint(self) -> str:
        return f"modbus://{self.host}:{self.port}/{self.unit}"

    @property
    def limits(self) -> Limits:
        return Limits(self.max_registers, self.max_bits, self.max_gap, self.max_bit_gap)

    def field(self, source: str, raw_type: TypeSpec) -> Field:
        """A variable's field on the device (ModbusAddressError if its source does not fit its type)."""
        return resolve(parse_address(source), str(raw_type), self.order)

    def variable_issues(self, variables: Sequence[MappedVariable]) -> list[tuple[Loc, str]]:
        """Located problems of a mapping's variables for this device (MachineMapping raises them)."""
        issues: list[tuple[Loc, str]] = []
        fields: list[Field] = []
        where: list[int] = []
        for index, variable in enumerate(variables):
            try:
                address = parse_address(variable.source)
            except ModbusAddressError:
                continue  # the loader reports it (the driver spec's check_address)
            try:
                field = resolve(address, str(variable.raw_type), self.order)
            except ModbusAddressError as exc:
                issues.append(((index, "source"), str(exc)))
                continue
            size = self.limits.size(field.table)
            if field.count > size:
                key = "max_bits" if field.table.bits else "max_registers"
                message = f"{field.describe()} is larger than one read may be ({key}: {size})"
                issues.append(((index, "source"), message))
            if variable.writable and not field.table.writable:
                message = (
                    f"{field.table.value} tables are read-only in Modbus: write coils or holding registers"
                )
                issues.append(((index, "access"), message))
            interval = variable.sampling_interval
            if interval is not None and interval < MIN_INTERVAL:
                message = f"a Modbus device is polled: give at least {MIN_INTERVAL:g} ms, not {interval:g}"
                issues.append(((index, "sampling_interval"), message))
            fields.append(field)
            where.append(index)
        for later, earlier in overlaps(fields):
            a, b = fields[later], fields[earlier]
            hint = " (a float32 or int32 takes two registers)" if abs(a.start - b.start) == 1 else ""
            message = f"{a.describe()} overlaps variables[{where[earlier]}], {b.describe()}{hint}"
            issues.append(((where[later], "source"), message))
        return sorted(issues, key=lambda issue: (int(issue[0][0]), str(issue[0][1])))

    def polling_groups(
        self, variables: Iterable[tuple[K, str, TypeSpec, float]]
    ) -> dict[float, list[tuple[K, Field]]]:
        """The polling groups, fastest first: interval (ms) -> (key, field), from (key, source, raw type,
        interval in ms) per variable. The mapping has been checked (variable_issues): every field resolves."""
        groups: dict[float, list[tuple[K, Field]]] = {}
        for key, source, raw_type, interval in variables:
            groups.setdefault(max(MIN_INTERVAL, interval), []).append((key, self.field(source, raw_type)))
        return dict(sorted(groups.items()))

    def describe_plan(self, variables: Sequence[V], interval_of: Callable[[V], float]) -> list[str]:
        """What `cnc-gateway check` prints: each polling group's requests."""
        head = (
            f"  polling plan ({self.max_registers} registers / {self.max_bits} bits a request at most, "
            f"gaps up to {self.max_gap} registers / {self.max_bit_gap} bits read through):"
        )
        lines = [head]
        entries = [(i, v.source, v.raw_type, interval_of(v)) for i, v in enumerate(variables)]
        for interval, fields in self.polling_groups(entries).items():
            requests = plan(fields, self.limits)
            count = len(fields)
            lines.append(
                f"    every {interval:g} ms: {len(requests)} request{'s' if len(requests) != 1 else ''} for "
                f"{count} variable{'s' if count != 1 else ''} ({len(requests) / count:.2f} per variable)"
            )
            lines.extend(f"      {r.describe()}" for r in requests)
        return lines
