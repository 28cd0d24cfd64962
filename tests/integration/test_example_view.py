"""The example OPC UA view (tests/example_view/) through the whole gateway, plugged in by its own folder.

With the example driver beside it (tests/example_driver/), both on PYTHONPATH as `pip install` would put
them: the view's `example_view:` key joins the mapping file (schema, file:line errors from its check,
its lines in `cnc-gateway check`), and its nodes appear in the running gateway's address space.
"""

from __future__ import annotations

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
PLUGINS = [ROOT / "tests" / "example_driver", ROOT / "tests" / "example_view"]

MAPPING = """\
machine: counter-1
driver: {type: example}
variables:
  - {path: Count, source: counter, type: UInt32}
example_view: {note: "counts parts", about: Count}
"""

ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([*map(str, PLUGINS), os.environ.get("PYTHONPATH", "")])}


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(BIN / "cnc-gateway"), *args], env=ENV, capture_output=True, text=True, timeout=60, check=False
    )


@pytest.fixture
def gateway_proc() -> Iterator[list[subprocess.Popen[str]]]:
    procs: list[subprocess.Popen[str]] = []
    yield procs
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)


def test_check_prints_the_view_and_locates_its_errors(tmp_path: Path) -> None:
    mapping = tmp_path / "counter.yaml"
    mapping.write_text(MAPPING)
    proc = cli("check", str(mapping))
    assert proc.returncode == 0, proc.stderr
    assert "  example view: Note 'counts parts' about Count" in proc.stdout
    mapping.write_text(MAPPING.replace('"counts parts"', '""'))  # the section's model
    proc = cli("check", str(mapping))
    assert proc.returncode == 2
    assert f"{mapping}:5: example_view.note: String should have at least 1 character" in proc.stderr
    mapping.write_text(MAPPING.replace("about: Count", "about: Cuont"))  # its check against the variables
    proc = cli("check", str(mapping))
    assert proc.returncode == 2
    assert f"{mapping}:5: example_view.about: 'Cuont' is not a variable of this mapping" in proc.stderr


async def test_its_nodes_are_in_the_address_space(
    tmp_path: Path, gateway_proc: list[subprocess.Popen[str]]
) -> None:
    port = free_port()
    (tmp_path / "counter.yaml").write_text(MAPPING)
    gateway_file = tmp_path / "gateway.yaml"
    gateway_file.write_text(
        f"opcua: {{endpoint: 'opc.tcp://127.0.0.1:{port}/cnc-gateway', profile: open}}\n"
        f"state_dir: state\ninbox: {{port: {free_port()}}}\nhttp: null\nmachines: [counter.yaml]\n"
    )
    proc = subprocess.Popen(
        [str(BIN / "cnc-gateway"), "run", str(gateway_file)],
        env=ENV,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    gateway_proc.append(proc)
    endpoint = f"opc.tcp://127.0.0.1:{port}/cnc-gateway"

    async def note() -> str | None:
        assert proc.poll() is None, proc.communicate()[1]
        try:
            async with Client(endpoint, timeout=2) as client:
                return str(await client.get_node("ns=2;s=counter-1/Note").read_value())
        except (OSError, TimeoutError, ua.UaError):
            return None

    await wait_until(note, timeout=30, message="the view's Note in the address space")
    assert await note() == "counts parts"
    proc.send_signal(2)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0 and "Traceback" not in err, err
