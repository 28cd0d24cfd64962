"""Noise mode: many extra Double variables that change at a set total rate, for benchmarks.

A benchmark needs a controller whose load it can dial: N variables, R changes a
second in total, however the machine model happens to move. Noise variables are
ordinary entries of the variable table (so the address space and the
controller-like write answers come for free), placed in folders of at most
`per_folder` (asyncua's browse and add costs grow with the square of a flat
folder), under `Objects/PLC/Tasks/Noise/gNNN/vNNNNN`.

They are marked `pushed`: the simulator's per-tick publish leaves them alone,
and `Noise.run` writes them itself with `write_attribute_value` on cached node
ids, yielding to the loop every `CHUNK` writes. Each change carries what a
receiver needs to measure loss and latency:

* the value is the change's sequence number (1, 2, 3 ... across all noise
  variables, as a Double), written round robin, so change k goes to variable
  (k - 1) mod N and a receiver can tell exactly which changes it missed;
* the SourceTimestamp is the wall clock when the value was written.

`rate` may be changed while running (`set_rate`); 0 pauses, `math.inf` writes as
fast as the process can. `stats()` says what was actually achieved, because a
benchmark of the gateway means nothing if the simulator is the bottleneck.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from asyncua import ua

from gateway.shims.asyncua_server import keep_written_values
from gateway.shims.ua import new_data_value, new_node_id
from simulator.variables import NAMESPACE_URI, Variable

CHUNK = 1000  # writes between turns for the rest of the event loop (the gateway's session, FTP)...
SLICE = 0.01  # ...or fewer, when they take longer than this (s)
TICK = 0.005  # s between bursts when keeping to a set rate
MAX_CATCH_UP = 0.25  # s of changes owed at most; beyond that the lag is dropped (and counted), not caught up
NODE_ID_FORMAT = "::Noise:g{group:03d}.v{index:05d}"


@dataclass(frozen=True, slots=True)
class NoiseSpec:
    """How much noise: `variables` Doubles, `rate` changes/s in total (0 paused, inf as fast as possible)."""

    variables: int
    rate: float = 0.0
    per_folder: int = 200

    def __post_init__(self) -> None:
        if self.variables < 1:
            raise ValueError("noise needs at least one variable")
        if self.per_folder < 1:
            raise ValueError("per_folder must be at least 1")
        if not self.rate >= 0:
            raise ValueError("the noise rate must be >= 0 (inf: as fast as possible)")

    def node_id(self, index: int) -> str:
        """The string node id (namespace urn:cnc-simulator:plc) of noise variable `index` (0-based)."""
        return NODE_ID_FORMAT.format(group=index // self.per_folder, index=index)


def _zero(machine: Any) -> float:
    return 0.0


def noise_variables(spec: NoiseSpec) -> list[Variable]:
    """The table entries: read-only Doubles, initially 0, pushed by `Noise.run` rather than polled."""
    return [Variable(spec.node_id(i), "Double", _zero, pushed=True) for i in range(spec.variables)]


@dataclass(frozen=True, slots=True)
class NoiseStats:
    written: int  # changes written since start (the last sequence number)
    lagged: int  # changes owed but dropped because the process could not keep up
    rate: float  # the set rate
    achieved: float  # changes/s since the rate was last set
    since: float  # time.monotonic() when the rate was last set


class Pacer:
    """Keeps a stream of writes to a set total rate: how many are owed now, never a burst of catch-up.

    Shared by the noise below and the benchmark's in-process source
    (bench/agents/injector.py), so that both count `written` and `lagged` alike.
    """

    def __init__(self, rate: float = 0.0) -> None:
        self.written = 0
        self.lagged = 0
        self._rate = rate
        self._since = time.monotonic()
        self._written_at_set = 0
        self._pace = (self._since, 0)  # (when, written then): the origin that pacing counts from
        self._wake = asyncio.Event()

    @property
    def rate(self) -> float:
        return self._rate

    def set_rate(self, rate: float) -> None:
        if not rate >= 0:
            raise ValueError("the noise rate must be >= 0 (inf: as fast as possible)")
        self._rate = rate
        self._since = time.monotonic()
        self._written_at_set = self.written
        self._pace = (self._since, self.written)
        self._wake.set()

    def stats(self) -> NoiseStats:
        elapsed = time.monotonic() - self._since
        done = self.written - self._written_at_set
        achieved = done / elapsed if elapsed > 0 else 0.0
        return NoiseStats(self.written, self.lagged, self._rate, achieved, self._since)

    async def owed(self) -> int:
        """Wait until writes are due (paused at rate 0); how many, at most CHUNK.

        The caller counts what it wrote in `written`."""
        while True:
            rate = self._rate
            if rate <= 0:
                self._wake.clear()
                await self._wake.wait()
                continue
            if math.isinf(rate):
                return CHUNK
            now = time.monotonic()
            since, base = self._pace
            owed = (now - since) * rate - (self.written - base)
            if owed > rate * MAX_CATCH_UP:  # fell behind: say so, and count afresh from now
                self.lagged += int(owed)
                self._pace = (now, self.written)
                owed = 0.0
            if owed < 1:
                await asyncio.sleep(max(TICK, (1 - owed) / rate))
                continue
            return min(int(owed), CHUNK)


class Noise(Pacer):
    """Writes the noise variables of a running PlcServer at the set rate (see the module docstring)."""

    def __init__(self, spec: NoiseSpec) -> None:
        super().__init__(spec.rate)
        self.spec = spec
        self.variables = noise_variables(spec)

    async def run(self, server: Any, ns: int) -> None:
        """Write changes into `server` (an asyncua Server) until cancelled."""
        # Every DataValue below is fresh: no need for asyncua's deep copy per subscriber.
        keep_written_values()
        write = server.write_attribute_value
        node_ids = [new_node_id(v.node_id, ns) for v in self.variables]
        count = len(node_ids)
        double = ua.VariantType.Double
        variant, datavalue = ua.Variant, new_data_value
        while True:
            due = await self.owed()
            stamp = datetime.now(UTC)
            seq = self.written
            deadline = time.monotonic() + SLICE
            for k in range(due):
                seq += 1
                dv = datavalue(variant(float(seq), double), SourceTimestamp=stamp, ServerTimestamp=stamp)
                await write(node_ids[(seq - 1) % count], dv)
                if k % 100 == 99 and time.monotonic() > deadline:
                    break  # the server's publishing must get its turns too
            self.written = seq
            await asyncio.sleep(0)


# --- the gateway's side: mapping files for the noise ---------------------------------------------------


def noise_mapping(
    spec: NoiseSpec,
    endpoint: str,
    *,
    machine: str = "noise",
    first: int = 0,
    count: int | None = None,
    publishing_interval: float = 10.0,
    queue_size: int = 10,
    mqtt: dict[str, Any] | None = None,
    publish_requests: int = 1,
) -> str:
    """A gateway mapping file (YAML text) for noise variables [first, first + count).

    Paths are `Noise/gNNN/vNNNNN`, like the node ids. `publishing_interval` (ms) and
    `queue_size` are the subscription's: the defaults keep every change of a
    benchmark's load (a short interval for latency; a queue so that a variable
    changing twice within one interval is not coalesced at the controller).
    """
    count = spec.variables - first if count is None else count
    if first < 0 or count < 1 or first + count > spec.variables:
        raise ValueError(f"variables {first}..{first + count - 1} are not all among the {spec.variables}")
    lines = [
        (
            f"# Generated by simulator.noise for {spec.variables} noise variables; "
            f"variables {first}..{first + count - 1}."
        ),
        f"machine: {machine}",
        "description: Simulator noise variables (benchmark load)",
        "driver:",
        "  type: opcua",
        f"  endpoint: {endpoint}",
        f"  publishing_interval: {publishing_interval:g}",
        "  timeout: 10",
        *([f"  publish_requests: {publish_requests}"] if publish_requests != 1 else []),
        "defaults:",
        "  sampling_interval: 0",
        f"  queue_size: {queue_size}",
    ]
    if mqtt:
        lines.append("mqtt: {" + ", ".join(f"{k}: {_yaml_scalar(v)}" for k, v in mqtt.items()) + "}")
    lines.append("variables:")
    uri = NAMESPACE_URI
    for i in range(first, first + count):
        node_id = spec.node_id(i)
        path = "Noise/" + node_id.removeprefix("::Noise:").replace(".", "/")
        lines.append(f'  - {{path: {path}, source: "nsu={uri};s={node_id}", type: Double}}')
    return "\n".join(lines) + "\n"


def _yaml_scalar(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def split_machines(spec: NoiseSpec, machines: int) -> Sequence[tuple[int, int]]:
    """(first, count) of each of `machines` equal shares of the noise variables."""
    if machines < 1 or spec.variables % machines:
        raise ValueError(f"{spec.variables} variables do not split into {machines} equal machines")
    per = spec.variables // machines
    return [(k * per, per) for k in range(machines)]
