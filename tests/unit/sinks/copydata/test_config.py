"""COPYDATA settings: defaults, per-transport keys, encodings, and the shipped laser-sim mapping."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from pydantic import ValidationError

from gateway.config.loader import load_mapping
from gateway.errors import SinkError
from gateway.sinks.copydata.config import CopydataTarget, check_encoding
from tests.unit.sinks.copydata.helpers import copydata_sink, mapping

ROOT = Path(__file__).resolve().parents[4]


def test_tcp_server_defaults_to_port_5020_on_every_address() -> None:
    target = CopydataTarget(name="nest", transport="tcp-server")
    assert (target.listen_address, target.listen_port) == ("0.0.0.0", 5020)
    assert (target.id_width, target.len_width, target.encoding, target.mode) == (2, 2, "utf-8", "batch")
    assert target.accept_writes is False and target.snapshot_every is None
    assert target.describe() == "tcp-server 0.0.0.0:5020"


def test_udp_sends_periodic_snapshots_unless_told_otherwise() -> None:
    assert CopydataTarget(name="u", transport="udp", host="h", port=1).snapshot_every == 5.0
    assert (
        CopydataTarget(name="u", transport="udp", host="h", port=1, snapshot_interval=0.5).snapshot_every
        == 0.5
    )


@pytest.mark.parametrize(
    ("settings", "fragment"),
    [
        ({"transport": "tcp-client", "port": 1}, "transport tcp-client needs host"),
        ({"transport": "udp", "host": "h"}, "transport udp needs port"),
        ({"transport": "tcp-server", "host": "h"}, "host is not used by transport tcp-server"),
        (
            {"transport": "udp", "host": "h", "port": 1, "window_title": "x"},
            "window_title is not used by transport udp",
        ),
        ({"transport": "win32"}, "needs window_class or window_title"),
        ({"transport": "tcp-client", "host": "h", "port": 0}, "port 0 (any free port) is only meaningful"),
        ({"transport": "tcp-server", "name": "bad name"}, "target name 'bad name'"),
    ],
)
def test_each_transport_takes_its_own_keys(settings: dict[str, object], fragment: str) -> None:
    with pytest.raises(ValidationError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        CopydataTarget.model_validate({"name": "t", **settings})


@pytest.mark.parametrize("name", ["utf-8", "utf-16-le", "gbk", "cp1252", "latin-1", "shift_jis"])
def test_text_encodings_python_knows_are_accepted(name: str) -> None:
    assert check_encoding(name) == name


@pytest.mark.parametrize(
    ("name", "fragment"),
    [("utf-16", "byte-order mark"), ("utf-8-sig", "byte-order mark"), ("klingon", "unknown text encoding"),
     ("base64", "cannot encode text")],
)  # fmt: skip
def test_encodings_a_receiver_cannot_read_item_by_item_are_refused(name: str, fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        check_encoding(name)


def test_laser_sim_serves_what_nesting_software_follows() -> None:
    m = load_mapping(ROOT / "mappings" / "laser-sim.yaml", environ={})
    ids = {v.path: v.copydata.id for v in m.variables if v.copydata is not None}
    for path in ("Program/Name", "Program/Block", "Axes/X/Position", "Axes/Y/Position", "Axes/Z/Position",
                 "Laser/On", "Feed/Rate", "Machine/State", "ActiveAlarms/Count"):  # fmt: skip
        assert path in ids, path
    # the worked example of docs/copydata.md uses the same ids
    assert (ids["Axes/X/Position"], ids["Program/Block"], ids["Laser/On"], ids["Program/Name"]) == (
        1,
        5,
        7,
        9,
    )
    assert m.copydata is not None
    (target,) = m.copydata.targets
    assert (target.transport, target.listen_port, target.listen_address) == ("tcp-server", 5020, "127.0.0.1")


def test_win32_loads_everywhere_but_starts_only_on_windows() -> None:
    """A mapping is checked where it is edited (CI, a laptop): the platform matters only at start."""
    m = mapping({"name": "nest", "transport": "win32", "window_class": "NestWnd", "timeout": 0.5})
    sink = copydata_sink(m)
    if sys.platform == "win32":
        pytest.skip("this is Windows: win32 targets start here")
    emitter = sink.emitters[0]

    async def start() -> None:
        async with sink:
            pass

    import asyncio

    with pytest.raises(SinkError, match=r"m1/nest uses transport win32 .* needs Windows"):
        asyncio.run(start())
    assert emitter.transport is None
