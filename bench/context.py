"""What every scenario gets: the settings of this run, a work directory, the results so far."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from bench.report import Results

T = TypeVar("T")
MAX = math.inf  # "as fast as possible"


@dataclass
class Settings:
    quick: bool
    warmup: float  # s of load before a window starts counting
    window: float  # s a throughput window counts
    repeats: int  # short windows whose median a baseline reports
    mirror_sizes: list[int]
    mirror_rates: list[float]
    mirror_qos: list[int]
    mirror_sources: list[str]
    naive_rates: list[float]
    peer_rates: list[float]  # the peer scenario's steps (the gateway and Node-RED, same load)
    scale_machines: int
    scale_per_machine: int
    scale_phase: float  # s per CPU phase (idle, 1 Hz, 10 Hz)
    jobs_small: int  # number of 100 KB jobs
    jobs_small_size: int
    jobs_large_size: int
    profile: bool = False
    #: The dnc scenario's runs: (label, checkout whose gateway/ the gateway agent imports; None: this one).
    dnc_gateways: list[tuple[str, str | None]] = field(default_factory=lambda: [("", None)])
    #: The dnc scenario's parts to run (load, after_dc3, single, fleet, restart); empty: all of them.
    dnc_parts: list[str] = field(default_factory=list)

    @classmethod
    def full(cls) -> Settings:
        return cls(
            quick=False, warmup=2.0, window=6.0, repeats=3,
            mirror_sizes=[1000, 10000], mirror_rates=[1000, 5000, 10000, 15000, 17500, 20000, MAX],
            mirror_qos=[0, 1], mirror_sources=["opcua", "inproc"], naive_rates=[1000, 5000, MAX],
            peer_rates=[5000, 15000, MAX],
            scale_machines=20, scale_per_machine=500, scale_phase=5.0,
            jobs_small=50, jobs_small_size=100_000, jobs_large_size=50_000_000,
        )  # fmt: skip

    @classmethod
    def quick_run(cls) -> Settings:
        return cls(
            quick=True, warmup=1.0, window=3.0, repeats=1,
            mirror_sizes=[1000], mirror_rates=[5000, MAX], mirror_qos=[0],
            mirror_sources=["opcua", "inproc"], naive_rates=[MAX],
            peer_rates=[5000, 15000, MAX],
            scale_machines=20, scale_per_machine=100, scale_phase=2.0,
            jobs_small=10, jobs_small_size=100_000, jobs_large_size=5_000_000,
        )  # fmt: skip


@dataclass
class Context:
    settings: Settings
    workdir: Path
    results: Results
    ceilings: dict[str, float] = field(default_factory=dict)
    profiles: dict[str, Any] = field(default_factory=dict)

    def log(self, text: str) -> None:
        print(f"  {text}", flush=True)


async def poll(
    check: Callable[[], Awaitable[T | None]],
    *,
    timeout: float,
    interval: float = 0.2,
    what: str = "condition",
) -> T:
    """Call `check` until it returns something other than None (or a falsy value); raise on the deadline."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    last: Any = None
    while True:
        last = await check()
        if last:
            return last
        if loop.time() > deadline:
            raise TimeoutError(f"timed out after {timeout:g} s waiting for {what} (last: {last!r})")
        await asyncio.sleep(interval)


def rate_label(rate: float) -> str:
    return "max" if math.isinf(rate) else f"{rate:,.0f}/s"


def rate_key(rate: float) -> str:
    return "max" if math.isinf(rate) else f"r{rate:.0f}"
