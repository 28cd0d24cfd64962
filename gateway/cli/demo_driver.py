"""The demo's driver: keeps a program running so that values move, and steps aside for anyone else.

While it has the machine, it selects and starts demo.nc whenever the machine has been
Idle for `settle` seconds (and no job waits for it), and resets alarms.

It steps aside as soon as someone else commands the machine:
- by any door of the gateway: a command (`Commands.*`, OPC UA or MQTT), a write to one of
  the machine's `Control/` variables (a client's, the job queue's auto-start), accepted or
  refused: the write hook sees it before it reaches the controller, the audit trail sees
  the rest (calls refused by their guard or role; requests that arrived before the driver
  took the machine back, such as the reset that ended the program, do not count);
- behind the gateway's back, as the tree shows it: another program selected, or the
  machine leaving Idle without the driver having started it.

Aside, it starts nothing and resets nothing. It takes the machine back when the program
someone else started (seen as the machine leaving Idle while it is aside) has ended, that
is when the machine is Idle again (an alarm the program ended in is theirs to reset); or,
when nobody starts anything, once nobody has commanded the machine for `patience`
seconds and nothing runs. A stop alone therefore leaves the machine idle for whoever sent it.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

from gateway.errors import RequestError
from gateway.model.audit import AuditEntry
from gateway.model.context import WriteContext
from gateway.model.sample import Sample, utcnow
from gateway.model.tree import Machine, VariableNode

log = logging.getLogger("gateway.demo")

DEMO_PROGRAM = "demo.nc"
STATE_IDLE, STATE_RUNNING, STATE_PAUSED, STATE_ALARM = 0, 1, 2, 3
CONTROL = "Control/"  # the machine's command variables: a write there is someone commanding the machine
COMMANDS = "Commands."  # audit targets of the mapping's commands
ORIGIN = "demo"
START_WINDOW = 5.0  # s: a departure from Idle this soon after the driver's Start is taken as its own


class DemoDriver:
    """Keeps `machine` busy with demo.nc, unless someone else is using it (see the module docstring)."""

    def __init__(
        self,
        machine: Machine,
        busy: Callable[[], bool] = lambda: False,
        *,
        settle: float = 1.0,
        patience: float = 300.0,
        tick: float = 0.25,
    ) -> None:
        self.machine = machine
        self.busy = busy  # a job waits for the machine: leave it idle for the job queue's auto-start
        self.settle = settle
        self.patience = patience
        self.tick = tick
        self.ctx = WriteContext(ORIGIN, ORIGIN, role="operator")  # selects and starts, as an operator would
        self.state = machine.nodes["Machine/State"]
        self.program = machine.nodes["Program/Name"]
        self.aside = False  # someone else commands the machine
        self.theirs = False  # aside, the machine left Idle without the driver: their program runs
        self.state_value: Any = None  # Machine/State as last seen (None: unknown)
        self.program_value: Any = None  # Program/Name as last seen (None: unknown)
        self._last_foreign = 0.0  # monotonic time of the latest command by someone else
        self._state_since = time.monotonic()  # when Machine/State took its current value
        self._starting = 0.0  # until then, the next departure from Idle is the driver's own start
        self._selecting: str | None = None  # the program the driver is selecting
        self._resumed_at = utcnow()  # audit entries are stamped with the arrival of their request
        self.cycles = 0  # how many times it has looked at the machine (tests wait on it)

    async def run(self) -> None:
        tree = self.machine.tree
        sub = tree.hub.subscribe(f"demo:driver:{self.machine.name}", every_change=True, limit=10_000)
        tree.write_hooks.append(self._before_write)
        tree.audit_sinks.append(self._audited)
        self.state_value = self._value(self.state.sample)
        self.program_value = self._value(self.program.sample)
        try:
            while True:
                try:
                    async with asyncio.timeout(self.tick):
                        changes = await sub.next_batch()
                except TimeoutError:
                    changes = []
                for node, sample in changes:
                    if node is self.state:
                        self._state_changed(sample)
                    elif node is self.program:
                        self._program_changed(sample)
                await self._act()
                self.cycles += 1
        finally:
            sub.close()
            tree.write_hooks.remove(self._before_write)
            tree.audit_sinks.remove(self._audited)

    # --- noticing someone else --------------------------------------------------------------

    async def _before_write(self, node: VariableNode, value: Any, ctx: WriteContext) -> None:
        if ctx is not self.ctx and node.machine is self.machine and node.path.startswith(CONTROL):
            self.someone_else(f"{ctx.user or 'anonymous'} via {ctx.origin} writes {node.path}")

    def _audited(self, entry: AuditEntry) -> None:
        if entry.machine != self.machine.name or (entry.origin == ORIGIN and entry.user == ORIGIN):
            return
        if (
            entry.time < self._resumed_at
        ):  # arrived before the driver took the machine back: part of what ended
            return
        if (entry.kind == "call" and entry.target.startswith(COMMANDS)) or (
            entry.kind == "write" and entry.target.startswith(CONTROL)
        ):
            self.someone_else(f"{entry.user or 'anonymous'} via {entry.origin}: {entry.kind} {entry.target}")

    @staticmethod
    def _value(sample: Sample) -> Any:
        return sample.value if sample.good else None

    def _program_changed(self, sample: Sample) -> None:
        previous, self.program_value = self.program_value, self._value(sample)
        if previous is None or self.program_value is None or self.program_value == previous:
            return  # unknown before (start-up, a reconnect), or no change
        if self.program_value == self._selecting:
            self._selecting = None
        else:
            self.someone_else(f"program {self.program_value} selected")

    def _state_changed(self, sample: Sample) -> None:
        previous, self.state_value = self.state_value, self._value(sample)
        if self.state_value == previous:
            return
        self._state_since = time.monotonic()
        if previous != STATE_IDLE or self.state_value not in (STATE_RUNNING, STATE_PAUSED, STATE_ALARM):
            return
        if time.monotonic() < self._starting:  # the driver's own start
            self._starting = 0.0
            return
        if not self.aside:
            self.someone_else("the machine started without the driver")
        self.theirs = True

    def someone_else(self, what: str) -> None:
        """Someone else commands the machine: step aside (again), and wait for their program to end."""
        self._last_foreign = time.monotonic()
        if not self.aside:
            self.aside = True
            self.theirs = False
            log.info(
                "demo: %s on %s: the demo driver steps aside until that program has ended",
                what,
                self.machine.name,
            )

    # --- acting ------------------------------------------------------------------------------

    async def _act(self) -> None:
        machine = self.machine
        if not machine.status.is_connected or not self.state.sample.good:
            return
        state, now = self.state_value, time.monotonic()
        if self.aside:
            running = state in (STATE_RUNNING, STATE_PAUSED)
            if self.theirs and state == STATE_IDLE:
                self._resume("their program has ended")
            elif not running and now - self._last_foreign >= self.patience:
                self._resume(f"nobody has commanded it for {self.patience:.0f} s")
            return
        if now - self._state_since < self.settle:
            return
        try:
            if state == STATE_ALARM:
                log.info("demo: machine in alarm, resetting")
                await self._write("Control/Reset", True)
            elif state == STATE_IDLE and not self.busy():
                if self.program.sample.value != DEMO_PROGRAM:
                    self._selecting = DEMO_PROGRAM
                    await self._write("Control/SelectProgram", DEMO_PROGRAM)
                self._starting = time.monotonic() + START_WINDOW
                if await self._write("Control/Start", True):
                    log.info("demo: started %s", DEMO_PROGRAM)
                self._state_since = time.monotonic()  # one attempt per settle period
        except RequestError as exc:
            self._starting = 0.0
            self._selecting = None
            self._state_since = time.monotonic()
            log.info("demo: %s (%s); will retry", exc.reason, exc.status)

    async def _write(self, path: str, value: Any) -> bool:
        """Write unless someone else took the machine meanwhile (an earlier write may have waited)."""
        if self.aside:
            self._starting = 0.0
            return False
        await self.machine.write(path, value, self.ctx)
        return True

    def _resume(self, why: str) -> None:
        self.aside = self.theirs = False
        self._resumed_at = utcnow()
        self._state_since = time.monotonic()
        log.info("demo: %s: the demo driver keeps %s busy again", why, self.machine.name)


async def keep_program_running(machine: Machine, busy: Callable[[], bool] = lambda: False) -> None:
    """Select and start the demo program whenever the machine is idle, unless someone else is using it."""
    await DemoDriver(machine, busy).run()
