"""MTConnect settings: the agent the gateway serves.

Gateway file (`mtconnect:`; absent, no agent):

```yaml
mtconnect:
  port: 5000                 # the agent's HTTP port (0: any free one)
  buffer_size: 131072        # observations kept for /sample (the reference agent's default)
  persist: true              # keep the buffer in <state_dir>/mtconnect.sqlite3 across restarts
  connections: {per_address: 32, header_timeout: 10, keepalive: 30}   # as http.connections
```

Mapping file, per variable (the standard's own attribute names):

```yaml
  - path: Feed/Rate
    source: ...
    type: Double
    unit: mm/min
    mtconnect: {category: SAMPLE, type: PATH_FEEDRATE, subType: ACTUAL, component: Controller/Path}
```

A variable's `mtconnect:` model is gateway/settings/mtconnect.py; the drivers' are in
gateway/sources/mtconnect/config.py.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, Protocol

from pydantic import Field

from gateway.alarms.config import AlarmsConfig
from gateway.settings.base import Strict
from gateway.settings.mtconnect import VariableMTConnect
from gateway.sinks.http_limits import ConnectionLimits

DEFAULT_AGENT_PORT = 5000
DEFAULT_BUFFER = 131_072


class AgentConfig(Strict):
    """The MTConnect agent the gateway serves (gateway file, `mtconnect:`)."""

    host: str = Field(default="0.0.0.0", description="Address to listen on")
    port: int = Field(default=DEFAULT_AGENT_PORT, ge=0, le=65535, description="HTTP port (0: any free one)")
    buffer_size: int = Field(
        default=DEFAULT_BUFFER, ge=16, le=1 << 24, description="Observations kept for /sample"
    )
    persist: bool = Field(
        default=False,
        description="Keep the buffer in <state_dir>/mtconnect.sqlite3, so that a restart keeps the sequence "
        "and the instanceId",
    )
    asset_buffer_size: int = Field(default=1024, ge=1, le=1 << 20, description="Assets kept")
    sender: str | None = Field(default=None, description="The Header's sender; default: this host's name")
    max_streams: int = Field(
        default=64, ge=1, le=10_000, description="Streaming clients (interval=) served at once"
    )
    connections: ConnectionLimits = Field(
        default_factory=ConnectionLimits,
        description="Connection caps and timeouts of the agent's port (as http.connections)",
    )
    fault_severity: int = Field(
        default=500,
        ge=1,
        le=1000,
        description="Alarms of this OPC UA severity or above are Faults; the others Warnings",
    )
    unmapped: Literal["variables", "omit"] = Field(
        default="variables",
        description="Variables without an mtconnect key: served as EVENT VARIABLE items, or left out",
    )


class AgentVariableEntry(Protocol):
    """What the agent reads of a variable's mapping entry: its MTConnect words."""

    @property
    def path(self) -> str: ...

    @property
    def mtconnect(self) -> VariableMTConnect | None: ...


class AgentMachineEntry(Protocol):
    """What the agent reads of a machine's mapping file (gateway/config/mapping.py `MachineMapping` fits)."""

    @property
    def description(self) -> str: ...

    @property
    def variables(self) -> Sequence[AgentVariableEntry]: ...

    @property
    def jobs(self) -> object | None:
        """Present: the machine takes jobs, whose programs the agent serves as assets."""
        ...

    @property
    def alarms(self) -> AlarmsConfig | None: ...
