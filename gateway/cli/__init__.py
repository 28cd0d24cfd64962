"""The `cnc-gateway` command line. Each command group lives in its own module."""

from gateway.cli.main import main

__all__ = ["main"]
