"""The example driver (tests/example_driver/) through the whole gateway, plugged in by its own folder only.

The folder is put on PYTHONPATH, as `pip install` of its pyproject.toml would put it on the path: its
entry point adds `driver: {type: example}` to the mapping file's schema, to the loader (its address check
gives file:line errors) and to the running gateway (its values reach OPC UA, writes come back to it),
without a line of the gateway changing. Without it on the path, the same mapping file is refused.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from asyncua import ua

from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
FOLDER = ROOT / "tests" / "example_driver"

MAPPING = """\
machine: counter-1
driver: {type: example, period: 0.02}
variables:
  - {path: Count, source: counter, type: UInt32}
  - {path: Setpoint, source: "memory:setpoint", type: Double, access: readwrite}
"""


def env(with_driver: bool = True) -> dict[str, str]:
    path = [str(FOLDER)] if with_driver else []
    return {**os.environ, "PYTHONPATH": os.pathsep.join([*path, os.environ.get("PYTHONPATH", "")])}


def cli(*args: str, with_driver: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(BIN / "cnc-gateway"), *args],
        env=env(with_driver),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


@pytest.fixture
def gateway_proc() -> Iterator[list[subprocess.Popen[str]]]:
    procs: list[subprocess.Popen[str]] = []
    yield procs
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)


def test_the_schema_offers_the_example_driver_only_when_it_is_installed() -> None:
    with_it = json.loads(cli("schema").stdout)
    without = json.loads(cli("schema", with_driver=False).stdout)
    assert "ExampleDriver" in with_it["$defs"] and "ExampleDriver" not in without["$defs"]
    tags = [ref["$ref"] for ref in with_it["properties"]["driver"]["oneOf"]]
    assert tags[0] == "#/$defs/OpcUaDriver" and "#/$defs/ExampleDriver" in tags


def test_its_verb_is_a_cnc_gateway_verb() -> None:
    assert cli("example-addresses").stdout.split() == ["counter", "memory"]
    assert "example-addresses" in cli("--help").stdout
    assert cli("example-addresses", with_driver=False).returncode == 2  # argparse: no such verb


def test_its_address_check_and_settings_give_file_line_errors(tmp_path: Path) -> None:
    mapping = tmp_path / "counter.yaml"
    mapping.write_text(MAPPING.replace('"memory:setpoint"', "memroy").replace("0.02", "-1"))
    proc = cli("check", str(mapping))
    assert proc.returncode == 2
    assert f"{mapping}:2: driver.period: Input should be greater than 0" in proc.stderr
    assert f"{mapping}:5: variables[1].source: 'memroy' is not an example address" in proc.stderr
    refused = cli("check", str(mapping), with_driver=False)
    assert refused.returncode == 2 and f"{mapping}:2: driver" in refused.stderr
    from gateway.sources import registry

    expected = ", ".join(repr(name) for name in registry.types())
    assert expected in refused.stderr  # the drivers there are


async def test_it_runs_through_the_gateway_values_out_and_writes_back(
    tmp_path: Path, gateway_proc: list[subprocess.Popen[str]]
) -> None:
    port = free_port()
    (tmp_path / "counter.yaml").write_text(MAPPING)
    gateway_file = tmp_path / "gateway.yaml"
    gateway_file.write_text(
        f"opcua: {{endpoint: 'opc.tcp://127.0.0.1:{port}/cnc-gateway', profile: open}}\n"
        f"state_dir: state\ninbox: {{port: {free_port()}}}\nhttp: null\n"
        "access: {anonymous: operator}\nmachines: [counter.yaml]\n"
    )
    proc = subprocess.Popen(
        [str(BIN / "cnc-gateway"), "run", str(gateway_file)],
        env=env(),
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    gateway_proc.append(proc)
    endpoint = f"opc.tcp://127.0.0.1:{port}/cnc-gateway"

    async def connected() -> bool:
        try:
            async with Client(endpoint, timeout=2):
                return True
        except (OSError, TimeoutError, ua.UaError):
            assert proc.poll() is None, proc.communicate()[1]
            return False

    await wait_until(connected, timeout=30, message="the gateway's OPC UA server up")
    async with Client(endpoint, timeout=5) as client:
        count = client.get_node("ns=2;s=counter-1/Count")
        first = await count.read_value()

        async def counting() -> bool:
            return int(await count.read_value()) > int(first) + 3

        await wait_until(counting, timeout=10, message="the counter counting in OPC UA")
        endpoint_node = client.get_node("ns=2;s=counter-1/Status/Endpoint")
        assert await endpoint_node.read_value() == "example://counter?period=0.02"
        assert await client.get_node("ns=2;s=counter-1/Status/State").read_value() == "connected"

        setpoint = client.get_node("ns=2;s=counter-1/Setpoint")
        assert await setpoint.read_value() == 0.0
        await setpoint.write_value(ua.DataValue(ua.Variant(12.5, ua.VariantType.Double)))
        assert await setpoint.read_value() == 12.5  # the driver's read-back, taken in before the answer

        with pytest.raises(ua.UaStatusCodeError):  # the mapping says read: refused before the driver
            await count.write_value(ua.DataValue(ua.Variant(7, ua.VariantType.UInt32)))

    proc.send_signal(2)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "Traceback" not in err
