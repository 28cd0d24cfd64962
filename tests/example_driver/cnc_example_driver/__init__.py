"""An example driver, as small as a driver can be: a counter that counts and a memory that keeps what is
written. It shows a driver's whole contract with the gateway: its `driver:` settings (config.py), its
source (source.py) and this spec, which names them.

It lives outside the gateway's tree and plugs in through the entry point group `cnc_gateway.drivers`
(cnc_example_driver-0.1.dist-info/entry_points.txt, which `pip install` of pyproject.toml would write);
tests/integration/test_example_driver.py runs it through the whole gateway. A driver inside the tree is
the same folder under gateway/sources/<type>/ plus its line in gateway/sources/registry.py.
"""

from __future__ import annotations

from cnc_example_driver.config import ExampleDriver
from gateway.model.tree import Machine
from gateway.sources.base import DriverMapping, DriverSpec, Source

ADDRESSES = ("counter", "memory")


def check_address(source: str) -> None:
    """`counter`, or `memory` or `memory:<anything>`: the loader says file:line of anything else."""
    if source != "counter" and source.split(":", 1)[0] != "memory":
        raise ValueError(f"{source!r} is not an example address: counter, memory or memory:<name>")


def _create(machine: Machine, mapping: DriverMapping) -> Source:
    from cnc_example_driver.source import ExampleSource  # a real driver's library loads only here

    return ExampleSource(machine, mapping)


SPEC = DriverSpec(
    type="example",
    settings=ExampleDriver,
    create=_create,
    summary="an example: a counter and a memory, no controller",
    check_address=check_address,
    commands=(("example-addresses", "cnc_example_driver.cli"),),
)
