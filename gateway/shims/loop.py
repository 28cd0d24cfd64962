"""The event loop the gateway runs on: asyncio's own, or uvloop on request (the `fast` extra).

uvloop is a maintained drop-in for asyncio's loop, written on libuv, and paho's
socket hooks (`add_reader`/`add_writer`) work the same on it. Measured for issue 13
(bench/profiles/issue-13-after.md), it did not measurably lower the gateway's CPU
per change on the 2-core bench machine (the time goes to asyncua's decoding and
encoding, not to the loop), so it is not the default: `cnc-gateway run --loop uvloop`
or `CNC_GATEWAY_LOOP=uvloop` choose it, `auto` takes it when it is installed.
"""

from __future__ import annotations

import asyncio
import importlib
import os
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar, cast

T = TypeVar("T")
LOOPS = ("auto", "asyncio", "uvloop")
ENV = "CNC_GATEWAY_LOOP"

LoopFactory = Callable[[], asyncio.AbstractEventLoop]


def uvloop_factory() -> LoopFactory | None:
    """uvloop's `new_event_loop`, or None when it is not installed."""
    try:
        module = importlib.import_module("uvloop")
    except ImportError:
        return None
    return cast(LoopFactory, module.new_event_loop)


def loop_factory(choice: str | None = None) -> LoopFactory | None:
    """The factory for `choice` (auto, asyncio, uvloop; default: $CNC_GATEWAY_LOOP, else asyncio); None
    means asyncio's own loop. Raises ValueError for an unknown choice, or uvloop asked for but missing."""
    choice = choice or os.environ.get(ENV) or "asyncio"
    if choice not in LOOPS:
        raise ValueError(f"event loop {choice!r}: choose one of {', '.join(LOOPS)}")
    if choice == "asyncio":
        return None
    factory = uvloop_factory()
    if factory is None and choice == "uvloop":
        raise ValueError("event loop uvloop: it is not installed (pip install 'cnc-gateway[fast]')")
    return factory


def loop_name(factory: LoopFactory | None) -> str:
    return "asyncio" if factory is None else "uvloop"


def run(main: Coroutine[Any, Any, T], factory: LoopFactory | None) -> T:
    """`asyncio.run(main)` on the loop `factory` makes (None: asyncio's own)."""
    with asyncio.Runner(loop_factory=factory) as runner:
        return runner.run(main)
