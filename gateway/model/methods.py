"""Callable operations on a machine: program management, commands.

A component (the job queue, the command runner) registers a `Method` on a
machine under an object name ("Programs", "Commands"). Sinks expose them in
their own way: the OPC UA sink as Method nodes with typed arguments on the
machine's object of that name; MQTT as request topics. The handler receives
checked, typed arguments and the caller's context, and answers with a tuple of
outputs or raises a RequestError (a CallError, or a refusal calls share with
writes) whose `.status` names the OPC UA code (BadInvalidState, BadTimeout,
BadUserAccessDenied, ...).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import Any

from gateway.errors import ArgumentsMissing, RequestError, TooManyArguments, TypeMismatch
from gateway.model.context import WriteContext
from gateway.model.types import TypeSpec, coerce

Handler = Callable[[WriteContext, Sequence[Any]], Awaitable[Sequence[Any]]]


@dataclass(frozen=True, slots=True)
class Argument:
    name: str
    type: TypeSpec
    description: str = ""


@dataclass(frozen=True, slots=True)
class Method:
    object: str  # the machine-level object that holds it: "Programs", "Commands"
    name: str
    description: str
    inputs: tuple[Argument, ...]
    outputs: tuple[Argument, ...]
    handler: Handler
    role: str | None = None  # lowest role that may call it (enforced by the access-control layer)

    def check_arguments(self, args: Sequence[Any]) -> list[Any]:
        """Count and type-check the inputs, the same way for every sink."""
        if len(args) < len(self.inputs):
            missing = ", ".join(a.name for a in self.inputs[len(args) :])
            raise ArgumentsMissing(f"{self.name} needs {missing}")
        if len(args) > len(self.inputs):
            raise TooManyArguments(f"{self.name} takes {len(self.inputs)} argument(s), got {len(args)}")
        out = []
        for arg, value in zip(self.inputs, args, strict=True):
            try:
                out.append(coerce(arg.type, value))
            except RequestError as exc:  # TypeMismatch or OutOfRange: both a wrong argument here
                raise TypeMismatch(f"{self.name}: argument {arg.name}: {exc.reason}") from None
        return out

    async def call(self, ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
        return await self.handler(ctx, self.check_arguments(args))
