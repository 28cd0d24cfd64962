"""The sink seam: what a sink is, how it says it is well, and the spec that registers it.

A sink is an async context manager with a long-running `run()`. It subscribes to
the tree's change hub, drains its own subscription at its own pace, and sends
writes back through `Machine.write`, which answers with a reasoned RequestError.

A sink is a folder `gateway/sinks/<name>/` whose `__init__.py` exports a `SinkSpec` and whose
`config.py` holds its settings; gateway/sinks/registry.py lists the specs (one line each). Nothing in a
sink imports `gateway.config`: the files are assembled from the sinks' models, and a sink reads what it
needs of a mapping through a Protocol of its own (e.g. sinks/mqtt/config.py `MqttMachineEntry`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, Self

from gateway.audit.trail import AuditTrail
from gateway.auth.ratelimit import LoginLimiter
from gateway.model.tree import VariableTree
from gateway.settings.sections import Section
from gateway.sinks.ports import GatewayPort, JobsPort, TrustPort

if TYPE_CHECKING:  # built (and imported) only when some machine has alarms: (gateway/app.py)
    from gateway.alarms.service import AlarmService


@dataclass(frozen=True, slots=True)
class SinkHealth:
    """How a sink is, in one typed record: what /readyz, /metrics and the diagnostics read.

    `ready` is whether the sink does its job now (its link is up, its births are out, its port is
    bound). The figures are those the sink has; None: the sink has no such thing."""

    ready: bool
    state: str | None = None  # its link's state in words: connected, online, connecting (…)
    backlog: int | None = None  # changes stored while the link is down (store and forward)
    dropped: int | None = None  # stored changes dropped at the backlog's limit
    in_flight: int | None = None  # sent, not yet acknowledged
    discarded: int | None = None  # QoS 0 changes not sent while the link was down
    coalesced: int | None = None  # changes replaced by a newer value before they were sent
    socket_queue: int | None = None  # writes the library holds that the socket has not taken
    resent: int | None = None  # messages sent again (DUP) after the link dropped before their acknowledgement
    connects: int | None = None  # successful connections
    online: bool | None = None  # connected and publishing live
    last_error: str = ""  # the latest reason the link went down or was refused ("" none)

    def figures(self) -> dict[str, Any]:
        """The figures the sink has, for gateway/diagnostics.py (in this order)."""
        named = (
            ("backlog", self.backlog),
            ("dropped", self.dropped),
            ("in_flight", self.in_flight),
            ("discarded", self.discarded),
            ("coalesced", self.coalesced),
            ("socket_queue", self.socket_queue),
            ("resent", self.resent),
            ("connects", self.connects),
            ("online", self.online),
            ("state", self.state),
        )
        return {name: value for name, value in named if value is not None}


class Sink(Protocol):
    name: str

    async def __aenter__(self) -> Self: ...

    async def __aexit__(self, *exc_info: object) -> None: ...

    async def run(self) -> None:
        """Mirror changes until cancelled."""
        ...

    def health(self) -> SinkHealth:
        """How the sink is now; cheap (called per /readyz and /metrics request)."""
        ...


@dataclass
class Offered:
    """What sinks offer one another through explicit ports, set while the sinks are built (in the
    registry's order: the sink that offers comes before the one that takes)."""

    trust: TrustPort | None = None  # the OPC UA server's trust list, which the console manages


@dataclass(frozen=True)
class SinkContext:
    """What a sink's factory gets from the core (gateway/app.py builds one for all sinks)."""

    tree: VariableTree
    config: Any  # gateway/config/loader.py `Config`: .gateway (the gateway file), .mappings, .files
    mappings: Mapping[str, Any]  # machine -> its MachineMapping; a sink reads it through its own Protocol
    state_dir: Path
    base_dir: Path  # the gateway file's folder (relative paths in the sections)
    logins: LoginLimiter  # the one failed-login lockout of every door that checks passwords
    host: GatewayPort  # diagnostics and readiness (the console's /readyz, /metrics)
    audit: AuditTrail
    jobs: JobsPort | None = None  # the job queue, when some machine has jobs:
    alarms: AlarmService | None = None  # the alarm managers, when some machine has alarms:
    offered: Offered = field(default_factory=Offered)

    def section(self, section: Section | None) -> Any:
        """The gateway file's value of a sink's `section` (None: absent, or the sink has none)."""
        if section is None:
            return None
        return self.config.gateway.section(section)


@dataclass(frozen=True)
class SinkSpec:
    """One sink, as gateway/sinks/registry.py lists it."""

    name: str  # the sink's name: task sink:<name>, /readyz "sink <name>", diagnostics
    summary: str  # one line: the adapters table of docs/architecture.md is checked against it
    # Builds the sink, or answers None when the configuration does not ask for it (no section). Called
    # in the registry's order, before the gateway starts; import the protocol's library only here.
    create: Callable[[SinkContext], Sink | None]
    section: Section | None = None  # its key in the gateway file
    machine_sections: tuple[Section, ...] = ()  # its keys per machine in mapping files
    variable_sections: tuple[Section, ...] = ()  # its keys per variable
