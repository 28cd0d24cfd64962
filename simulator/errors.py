"""The simulator's own errors, in the gateway's error hierarchy.

A refused command write is one of gateway.errors' RequestErrors and carries the OPC UA status name the
simulator's server answers with, exactly as a controller would: InvalidState (Start while running,
nothing selected), InvalidArgument (a program not in the store), OutOfRange, TypeMismatch, NotWritable.
"""

from __future__ import annotations

from gateway.errors import GatewayError


class ProgramNotFound(GatewayError, LookupError):
    """No program of that name in the store."""


class SimulatorError(GatewayError):
    """The simulator cannot start (a port in use, an unusable store folder)."""
