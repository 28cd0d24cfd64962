"""The S7 driver's settings, and the checks of an S7 mapping's variables at load time.

```yaml
driver:
  type: s7
  host: 10.0.0.31
  rack: 0
  slot: 1            # S7-1200/1500: 1 (or 0); S7-300: 2; S7-400: as configured in the rack
  pdu_size: 480      # asked for at connect; the CPU answers what it takes (S7-1200: 240)
variables:
  - {path: Laser/Power, source: DB10.DBD4, type: Float}
  - {path: Laser/On, source: DB10.DBX2.3, type: Boolean}
  - {path: Program/Name, source: "DB10.DBB20:STRING[30]", type: String}
```

As for Modbus, every `source` is resolved against its variable's type at load time (`variable_issues`:
wrong addresses, a type its bytes cannot hold, a field no response of `pdu_size` can carry, two
variables on the same bytes, a write to the inputs), and `cnc-gateway check` prints the plan for the
`pdu_size` asked for; the driver plans again with the size the CPU negotiates.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable, Sequence
from typing import Literal, Protocol, TypeVar

from pydantic import Field as PydanticField

from gateway.codecs.s7.address import Area, Field, S7AddressError, overlaps, parse_address, resolve
from gateway.codecs.s7.pdu import max_item, plan
from gateway.model.types import TypeSpec
from gateway.settings.base import Backoff, Strict

DEFAULT_PORT = 102
MIN_INTERVAL = 10.0  # ms

Loc = tuple[int | str, ...]


class MappedVariable(Protocol):
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


class S7Driver(Strict):
    """A Siemens S7 PLC over S7comm (ISO-on-TCP): S7-300/400/1200/1500, the PLC of a SINUMERIK 840D."""

    type: Literal["s7"]
    host: str = PydanticField(min_length=1, description="The PLC's address (or its CP's)")
    port: int = PydanticField(default=DEFAULT_PORT, ge=1, le=65535, description="ISO-on-TCP port (102)")
    rack: int = PydanticField(default=0, ge=0, le=7, description="The CPU's rack (0 on most)")
    slot: int = PydanticField(
        default=1, ge=0, le=31, description="The CPU's slot: 1 (or 0) on S7-1200/1500, 2 on S7-300"
    )
    timeout: float = PydanticField(default=2.0, gt=0, description="Seconds to connect, and per request")
    pdu_size: int = PydanticField(
        default=480, ge=240, le=960, description="PDU size asked for at connect; the CPU may answer less"
    )
    max_gap: int = PydanticField(
        default=8, ge=0, le=200, description="Unmapped bytes an item may span to save an item"
    )
    reconnect: Backoff = Backoff()

    @property
    def endpoint(self) -> str:
        return f"s7://{self.host}:{self.port}/{self.rack}/{self.slot}"

    def field(self, source: str, raw_type: TypeSpec) -> Field:
        return resolve(parse_address(source), str(raw_type))

    def variable_issues(self, variables: Sequence[MappedVariable]) -> list[tuple[Loc, str]]:
        """Located problems of a mapping's variables for this PLC (MachineMapping raises them)."""
        issues: list[tuple[Loc, str]] = []
        fields: list[Field] = []
        where: list[int] = []
        for index, variable in enumerate(variables):
            try:
                address = parse_address(variable.source)
            except S7AddressError:
                continue  # the loader reports it (the driver spec's check_address)
            try:
                field = resolve(address, str(variable.raw_type))
            except S7AddressError as exc:
                issues.append(((index, "source"), str(exc)))
                continue
            if field.size > max_item(self.pdu_size):
                message = (
                    f"{field.describe()} is larger than a response of pdu_size {self.pdu_size} can carry"
                )
                issues.append(((index, "source"), message))
            if variable.writable and field.area is Area.INPUTS:
                message = (
                    "the inputs are the PLC's process image of its inputs, rewritten every cycle: "
                    "write a DB, flags (M) or outputs (Q)"
                )
                issues.append(((index, "access"), message))
            interval = variable.sampling_interval
            if interval is not None and interval < MIN_INTERVAL:
                message = f"an S7 PLC is polled: give at least {MIN_INTERVAL:g} ms, not {interval:g}"
                issues.append(((index, "sampling_interval"), message))
            fields.append(field)
            where.append(index)
        for later, earlier in overlaps(fields):
            a, b = fields[later], fields[earlier]
            message = f"{a.describe()} overlaps variables[{where[earlier]}], {b.describe()}"
            issues.append(((where[later], "source"), message))
        return sorted(issues, key=lambda issue: (int(issue[0][0]), str(issue[0][1])))

    def polling_groups(
        self, variables: Iterable[tuple[K, str, TypeSpec, float]]
    ) -> dict[float, list[tuple[K, Field]]]:
        """Interval (ms) -> (key, field), fastest first, from (key, source, raw type, interval in ms)."""
        groups: dict[float, list[tuple[K, Field]]] = {}
        for key, source, raw_type, interval in variables:
            groups.setdefault(max(MIN_INTERVAL, interval), []).append((key, self.field(source, raw_type)))
        return dict(sorted(groups.items()))

    def describe_plan(self, variables: Sequence[V], interval_of: Callable[[V], float]) -> list[str]:
        """What `cnc-gateway check` prints: each polling group's requests at the pdu_size asked for."""
        head = (
            f"  polling plan (PDU {self.pdu_size} bytes as asked; planned again for what the CPU "
            f"negotiates; gaps up to {self.max_gap} bytes read through):"
        )
        lines = [head]
        entries = [(i, v.source, v.raw_type, interval_of(v)) for i, v in enumerate(variables)]
        for interval, fields in self.polling_groups(entries).items():
            requests = plan(fields, self.pdu_size, max_gap=self.max_gap).requests
            items = sum(len(r.items) for r in requests)
            plural = "s" if len(requests) != 1 else ""
            lines.append(f"    every {interval:g} ms: {len(requests)} request{plural}, {items} items, "
                         f"for {len(fields)} variables")  # fmt: skip
            for request in requests:
                items_text = "; ".join(i.describe() for i in request.items)
                head = f"      Read Var, {len(request.items)} items, {request.response_size} bytes back: "
                lines.append(head + items_text)
        return lines
