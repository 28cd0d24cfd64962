"""`cnc-gateway example-addresses`: the verb the example driver adds (DriverSpec.commands)."""

from __future__ import annotations

import argparse

from cnc_example_driver import ADDRESSES


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("example-addresses", help="list the example driver's addresses")
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    print("\n".join(ADDRESSES))
    return 0
