"""The driver seam: what a source is, what it may read of its mapping, and the spec that registers it.

A source is an async context manager with a long-running `run()`. It pushes
values into the tree with `Machine.ingest`, turns them bad with
`Machine.invalidate` when the controller is unreachable, reports its connection
through `Machine.status`, and carries out writes the tree has already checked.
It never raises out of `run()` for a controller problem: it retries with backoff.

A driver is a folder `gateway/sources/<type>/` whose `__init__.py` exports a `DriverSpec` and whose
`config.py` holds its settings model; gateway/sources/registry.py lists the specs (one line each).
Nothing here or in a driver imports `gateway.config`: the configuration files are assembled from the
drivers' models (gateway/config/mapping.py builds `driver:` from the registry), and a driver reads its
machine's mapping through `DriverMapping`, which the assembled `MachineMapping` fits.
"""

from __future__ import annotations

import builtins
from collections.abc import Callable, Coroutine, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, Self, TypeVar, runtime_checkable

from gateway.model.sample import ReadBack
from gateway.model.tree import Machine, VariableNode
from gateway.settings.base import Strict
from gateway.settings.mtconnect import VariableMTConnect


class Source(Protocol):
    machine: Machine

    async def __aenter__(self) -> Self: ...

    async def __aexit__(self, *exc_info: object) -> None: ...

    async def run(self) -> None:
        """Connect, subscribe, and reconnect with backoff, until cancelled. It may be started again after a
        cancellation (a lease-served machine, gateway/sources/leased.py): close what it opened on the way
        out."""
        ...

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        """Write a raw (already checked and unscaled) value. Raises ControllerRefused/ControllerUnavailable.

        Answers with the value read back from the controller after the write (None if it
        could not be read), which the tree takes in before the write is answered.
        """
        ...


class DriverSettings(Protocol):
    """What the core reads of any driver's settings (the mapping's `driver:` section)."""

    @property
    def type(self) -> str: ...

    @property
    def endpoint(self) -> str:
        """The controller's address as users know it (`Status/Endpoint`, log lines)."""
        ...


@runtime_checkable
class ChecksVariables(Protocol):
    """Driver settings that check a mapping's variables together (addresses against types, overlaps,
    sizes): MachineMapping raises what it answers as `file:line: variables[i].<key>` errors."""

    def variable_issues(self, variables: Sequence[Any]) -> list[tuple[tuple[str | int, ...], str]]: ...


@runtime_checkable
class PlansPolls(Protocol):
    """Driver settings of a polled device (Modbus, S7): `cnc-gateway check` prints the requests it plans."""

    def describe_plan(self, variables: Sequence[Any], interval_of: Callable[[Any], float]) -> list[str]: ...


class VariableSettings(Protocol):
    """What a driver may read of one variable's mapping entry beyond the tree's own definition
    (`node.definition`: path, source address, types, scaling)."""

    @property
    def path(self) -> str: ...

    @property
    def sampling_interval(self) -> float | None: ...

    @property
    def queue_size(self) -> int | None: ...

    @property
    def mtconnect(self) -> VariableMTConnect | None:
        """The variable's MTConnect words (the SHDR driver reads conditions and time series from them)."""
        ...


class DriverMapping(Protocol):
    """What a driver reads of its machine's mapping file; gateway/config/mapping.py `MachineMapping`
    fits it (mypy checks that where gateway/app.py hands one over)."""

    @property
    def machine(self) -> str: ...

    @property
    def driver(self) -> DriverSettings: ...

    @property
    def variables(self) -> Sequence[VariableSettings]: ...

    def sampling_interval(self, var: VariableSettings) -> float:
        """Milliseconds: the variable's own `sampling_interval`, else the mapping's default."""
        ...

    def queue_size(self, var: VariableSettings) -> int: ...


@dataclass(frozen=True, slots=True)
class DiscoverRequest:
    """What `cnc-gateway discover ENDPOINT` was asked; each driver reads the options it has."""

    endpoint: str
    machine: str  # the name the mapping file it writes gives the machine
    timeout: float
    device: str | None = None  # MTConnect: the device's name or uuid, when the agent has several
    user: str | None = None
    password: str | None = None
    security: str = "None"  # OPC UA: asyncua's security string
    start: str | None = None  # OPC UA: the node id to browse from
    max_depth: int = 12
    max_variables: int = 5000


#: A starting mapping file (YAML text) from a controller; raises SourceError or ValueError saying why not.
Discover = Callable[[DiscoverRequest], Coroutine[Any, Any, str]]


@dataclass(frozen=True)
class DriverSpec:
    """One driver, as gateway/sources/registry.py lists it.

    `create` is called once per machine whose `driver.type` is `type`, before the gateway starts; it
    should import the protocol's library only then (a function-level import), so that loading a
    configuration does not load every driver's library.
    """

    type: str  # `driver: {type: ...}` in a mapping file
    settings: builtins.type[
        Strict
    ]  # the `driver:` model (its folder's config.py), with `type: Literal["<type>"]`
    create: Callable[[Machine, DriverMapping], Source]
    summary: str  # one line: the adapters table of docs/architecture.md is checked against it
    # Run by the loader on every variable's `source` when the file is loaded: raises ValueError (or
    # gateway.errors.AddressError) naming what is wrong, which becomes a `file:line: variables[i].source`
    # error. None: the driver takes any non-empty string.
    check_address: Callable[[str], object] | None = None
    # Why the driver cannot write, if it cannot ("MTConnect has no writes"): the loader then refuses
    # `access: readwrite` on its variables.
    read_only: str | None = None
    # `cnc-gateway` verbs this driver adds, as (verb, module): the module (in the driver's folder) has
    # `register(sub)` as those of gateway/cli/ do, and is imported only when its verb is given (or --help).
    commands: tuple[tuple[str, str], ...] = ()
    # `cnc-gateway discover ENDPOINT` for endpoints that start with one of `discovers` (`focas://`): it
    # writes a starting mapping file. The default driver's `discover` takes any other endpoint.
    discovers: tuple[str, ...] = ()
    discover: Discover | None = None


M = TypeVar("M")


def settings_of(mapping: DriverMapping, model: type[M]) -> M:
    """The machine's `driver:` section as the driver's own model (the registry picked the driver by its
    type, so anything else is a programming error)."""
    driver = mapping.driver
    if not isinstance(driver, model):
        raise TypeError(f"{mapping.machine}: a {driver.type} driver, not {model.__name__}")
    return driver
