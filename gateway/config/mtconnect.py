"""MTConnect settings: the agent the gateway serves, how a variable appears in it, and the two drivers.

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

and the drivers, `driver: {type: mtconnect, url: http://agent:5000, device: haas-1}` (another
agent) or `driver: {type: shdr, host: 10.0.0.7, port: 7878}` (an adapter). Both are read-only.
"""

from __future__ import annotations

import re
from typing import Annotated, Literal
from urllib.parse import urlsplit

from pydantic import Field, field_validator

from gateway.config.base import Backoff, Strict
from gateway.config.http import ConnectionLimits

DEFAULT_AGENT_PORT = 5000
DEFAULT_SHDR_PORT = 7878
DEFAULT_BUFFER = 131_072

_TYPE = re.compile(r"^(?:[a-z][a-z0-9]*:)?[A-Z][A-Z0-9_]*$")
_STEP = re.compile(r"^(?:[a-z][a-z0-9]*:)?[A-Z][A-Za-z0-9]*(?:\[[A-Za-z0-9_.\- ]+\])?$")
_ID = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")


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


Category = Literal["SAMPLE", "EVENT", "CONDITION"]


class VariableMTConnect(Strict):
    """How one variable appears in the MTConnect agent, in the standard's own words."""

    category: Category
    type: str = Field(description="The data item type: POSITION, PATH_FEEDRATE, EXECUTION, SYSTEM, ...")
    sub_type: str | None = Field(default=None, alias="subType", description="ACTUAL, COMMANDED, ...")
    component: str | None = Field(
        default=None,
        description="Where it sits below the Device: steps of ComponentType[name], e.g. Axes/Linear[X] or "
        "Controller/Path; default: on the Device itself",
    )
    name: str | None = Field(default=None, description="The data item's name (default: none)")
    id: str | None = Field(default=None, description="The data item id (default: <machine>.<path>)")
    units: str | None = Field(
        default=None, description="MTConnect units; default: the standard's for the variable's unit"
    )
    native_units: str | None = Field(
        default=None, alias="nativeUnits", description="What the controller uses; default: from `unit`"
    )
    significant_digits: int | None = Field(default=None, alias="significantDigits", ge=0, le=30)
    coordinate_system: Literal["MACHINE", "WORK"] | None = Field(default=None, alias="coordinateSystem")
    discrete: bool = False
    representation: Literal["VALUE", "TIME_SERIES"] = Field(
        default="VALUE", description="TIME_SERIES: a SAMPLE of several readings per observation (Double[])"
    )
    values: dict[str, str] | None = Field(
        default=None,
        description="The variable's values as MTConnect words, e.g. {0: READY, 1: ACTIVE} or {true: ON}",
    )

    @field_validator("type")
    @classmethod
    def _type(cls, value: str) -> str:
        if not _TYPE.match(value):
            raise ValueError(
                f"{value!r} is not an MTConnect type (upper case words joined by _, e.g. POSITION)"
            )
        return value

    @field_validator("sub_type")
    @classmethod
    def _sub_type(cls, value: str | None) -> str | None:
        if value is not None and not _TYPE.match(value):
            raise ValueError(f"{value!r} is not an MTConnect subType (e.g. ACTUAL, COMMANDED)")
        return value

    @field_validator("component")
    @classmethod
    def _component(cls, value: str | None) -> str | None:
        if value is None:
            return None
        for step in value.split("/"):
            if not _STEP.match(step):
                raise ValueError(
                    f"component step {step!r} must be a component type, optionally with a name: Axes, "
                    "Linear[X], Path[path1]"
                )
        return value

    @field_validator("id")
    @classmethod
    def _id(cls, value: str | None) -> str | None:
        if value is not None and not _ID.match(value):
            raise ValueError(f"{value!r} is not an XML id (a letter or _ first; letters, digits, _ . -)")
        return value

    @field_validator("values", mode="before")
    @classmethod
    def _value_keys(cls, value: object) -> object:
        """YAML keys may be numbers or booleans: compare them as the text the sink makes of a value."""
        if isinstance(value, dict):
            return {_written_key(k): v for k, v in value.items()}
        return value


def value_key(value: object) -> str:
    """The text a value is looked up by in `values`: true/false for booleans, 3 for 3.0."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def _written_key(key: object) -> str:
    """A `values` key as written (the loader hands YAML keys over as text: "True", "0")."""
    if isinstance(key, str):
        if key.lower() in ("true", "false"):
            return key.lower()
        try:
            number = float(key)
        except ValueError:
            return key
        return value_key(number) if number.is_integer() else key
    return value_key(key)


def check_url(url: str) -> str:
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https"):
        raise ValueError(f"url {url!r} must start with http:// or https://")
    if not parts.hostname:
        raise ValueError(f"url {url!r} has no host")
    try:
        parts.port  # noqa: B018 - a bad port raises here
    except ValueError:
        raise ValueError(f"url {url!r} has an invalid port") from None
    if parts.query or parts.fragment:
        raise ValueError(f"url {url!r} must be the agent's base address, without ?query or #fragment")
    return url.rstrip("/")


class MTConnectDriver(Strict):
    """Another MTConnect agent: /probe, then /sample?interval=… as a stream. Read-only."""

    type: Literal["mtconnect"]
    url: str = Field(description="The agent's base address, e.g. http://10.0.0.9:5000")
    device: str | None = Field(
        default=None, description="The device's name or uuid at the agent (needed when it has several)"
    )
    interval: int = Field(default=100, ge=0, le=60_000, description="ms between stream chunks")
    heartbeat: int = Field(default=2000, ge=100, le=600_000, description="ms of silence before a heartbeat")
    count: int = Field(default=10_000, ge=1, le=1_000_000, description="Observations per chunk at most")
    timeout: float = Field(default=5.0, gt=0, description="Seconds to wait for a response")
    reconnect: Backoff = Backoff()

    @field_validator("url")
    @classmethod
    def _url(cls, url: str) -> str:
        return check_url(url)

    @property
    def endpoint(self) -> str:
        return self.url if self.device is None else f"{self.url}/{self.device}"


class ShdrDriver(Strict):
    """An MTConnect adapter, straight over TCP (SHDR). Read-only."""

    type: Literal["shdr"]
    host: str
    port: int = Field(default=DEFAULT_SHDR_PORT, ge=1, le=65535)
    timeout: float = Field(default=5.0, gt=0, description="Seconds to connect")
    legacy_timeout: float = Field(
        default=600.0, gt=0, description="Seconds of silence from an adapter that does not answer PING"
    )
    reconnect: Backoff = Backoff()

    @property
    def endpoint(self) -> str:
        return f"shdr://{self.host}:{self.port}"


MTConnectDrivers = Annotated[MTConnectDriver | ShdrDriver, Field(discriminator="type")]
READ_ONLY_DRIVERS = ("mtconnect", "shdr")
