"""Run a mapped command: guard, writes through the tree, then wait for its completion within the deadline.

Each command of a machine's `commands:` section becomes a `Method` on the
machine's `Commands` object (OPC UA shows it as a Method node, MQTT answers
requests for it). One call:

1. the guard (`allowed`): refused with BadInvalidState, naming the state, unless it holds;
2. the writes, in order, through `Machine.write_node` (the same checks, roles and
   audit as every other write; the first refusal ends the command with its status);
3. the completion (`done`): the variable is followed through the change hub (every
   change, so that a state passed through quickly still counts) until the condition
   holds. A controller that drops meanwhile ends the command with its Bad status.

The whole call has the command's `timeout`; when it passes the command fails with
BadTimeout and says what it was waiting for. No command waits forever.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

from gateway.commands.conditions import Check, bind
from gateway.commands.config import CommandSpec, render
from gateway.errors import CallError, ConfirmTimeout, InvalidState
from gateway.model.context import WriteContext
from gateway.model.hub import Subscription
from gateway.model.methods import Argument, Method
from gateway.model.types import TypeSpec

if TYPE_CHECKING:
    from gateway.model.tree import Machine, VariableNode, VariableTree

log = logging.getLogger("gateway.commands")

OBJECT = "Commands"
OUTPUTS = (
    Argument("Result", TypeSpec.parse("String"), "What confirmed the command"),
    Argument("Duration", TypeSpec.parse("Double"), "How long the command took, in milliseconds"),
)


class CommandRunner:
    """One command of one machine."""

    def __init__(self, machine: Machine, name: str, spec: CommandSpec) -> None:
        self.machine = machine
        self.name = name
        self.spec = spec

    def method(self) -> Method:
        spec = self.spec
        return Method(
            object=OBJECT,
            name=self.name,
            description=spec.description,
            inputs=tuple(Argument(a.name, a.type, a.description) for a in spec.arguments),
            outputs=OUTPUTS,
            handler=self.run,
            role=spec.role,
        )

    async def run(self, ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
        """The Method handler: `args` are already counted and typed. Returns (result text, duration ms)."""
        spec = self.spec
        started = time.monotonic()
        values = {a.name: v for a, v in zip(spec.arguments, args, strict=True)}
        phase = "checking the guard"
        sub: Subscription[VariableNode] | None = None
        done = bind(spec.done, values) if spec.done is not None else None
        try:
            async with asyncio.timeout(spec.timeout) as deadline:
                try:
                    if spec.allowed is not None:
                        self._guard(bind(spec.allowed, values))
                    if done is not None:  # before the writes, so that no change falls between
                        sub = self.machine.tree.hub.subscribe(
                            f"command:{self.machine.name}:{self.name}", every_change=True, limit=1000
                        )
                    for step in spec.writes:
                        phase = f"writing {step.path}"
                        node = self.machine.nodes[step.path]
                        await self.machine.write_node(node, render(step.value, values), ctx)
                    if done is None or sub is None:
                        result = "written: " + ", ".join(s.path for s in spec.writes)
                    else:
                        phase = f"waiting for {done}"
                        result = await self._wait(done, self.machine.nodes[done.path], sub)
                except TimeoutError:
                    if deadline.expired():
                        raise
                    raise CallError(
                        f"{self.name}: the controller did not answer ({phase})", status="BadTimeout"
                    ) from None
        except TimeoutError:
            raise ConfirmTimeout(self._timeout_reason(phase, done)) from None
        finally:
            if sub is not None:
                sub.close()
        duration = round((time.monotonic() - started) * 1000.0, 1)
        log.info("%s: command %s done in %.0f ms: %s", self.machine.name, self.name, duration, result)
        return [result, duration]

    def _guard(self, check: Check) -> None:
        node = self.machine.nodes[check.path]
        sample = node.sample
        if not sample.good:
            raise CallError(
                f"{self.name}: {check.path} is not known ({sample.reason or sample.status})",
                status=sample.status,
            )
        if not check.holds(sample.value):
            raise InvalidState(
                f"{self.name} is not allowed while {check.path} is {check.label(sample.value)}; "
                f"it needs {check.path} {check.expected()}"
            )

    async def _wait(self, check: Check, node: VariableNode, sub: Subscription[VariableNode]) -> str:
        """Until `check` holds for `node`: now, or in any change that comes (in order)."""
        sample = node.sample
        self._usable(check, sample)
        if check.holds(sample.value):
            return f"{check.path} is {check.label(sample.value)}"
        while True:
            for changed, sample in await sub.next_batch():
                if changed is not node:
                    continue
                self._usable(check, sample)
                if check.holds(sample.value):
                    return f"{check.path} is {check.label(sample.value)}"

    def _usable(self, check: Check, sample: Any) -> None:
        if not sample.good:
            raise CallError(
                f"{self.name}: lost {check.path} while waiting for it ({sample.reason or sample.status})",
                status=sample.status,
            )

    def _timeout_reason(self, phase: str, done: Check | None) -> str:
        text = f"{self.name}: no completion within {self.spec.timeout:g} s ({phase})"
        if done is not None and phase.startswith("waiting"):
            sample = self.machine.nodes[done.path].sample
            text += f"; {done.path} is {done.label(sample.value)}"
        return text


class CommandsMapping(Protocol):
    """What the commands read of a machine's mapping (gateway/config/mapping.py MachineMapping fits)."""

    @property
    def commands(self) -> Mapping[str, CommandSpec] | None: ...


def command_methods(machine: Machine, mapping: CommandsMapping) -> list[Method]:
    commands = mapping.commands or {}
    return [CommandRunner(machine, name, spec).method() for name, spec in commands.items()]


def install_commands(tree: VariableTree, mappings: Mapping[str, CommandsMapping]) -> int:
    """Register every machine's commands (before the sinks start, which expose them). Returns how many."""
    count = 0
    for name, mapping in mappings.items():
        machine = tree.machines[name]
        for method in command_methods(machine, mapping):
            machine.add_method(method)
            count += 1
    return count
