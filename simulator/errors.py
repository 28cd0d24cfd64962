"""The simulator's refusals, in the gateway's error hierarchy.

A refused command write carries the OPC UA status name the simulator's server
answers with, exactly as a controller would (gateway.errors gives the rest:
OutOfRange, TypeMismatch, NotWritable).
"""

from __future__ import annotations

from gateway.errors import GatewayError, WriteError


class InvalidState(WriteError):
    """The command does not fit the machine's state (Start while running, nothing selected, ...)."""

    status = "BadInvalidState"


class InvalidArgument(WriteError):
    """The command's argument names nothing the machine knows (a program not in the store)."""

    status = "BadInvalidArgument"


class SimulatorError(GatewayError):
    """The simulator cannot start (a port in use, an unusable store folder)."""
