"""A face or a service the files do not configure is not imported (start-up time and memory, issue 28).

Run in a fresh interpreter, as `cnc-gateway run` starts: load the files, build the Gateway (which builds
the configured sinks), then list what is in sys.modules.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = """
import json, sys
from gateway.app import Gateway
from pathlib import Path
from gateway.config.loader import load
Gateway(load([Path(sys.argv[1])]))
print(json.dumps(sorted(sys.modules)))
"""

MAPPING = """\
machine: m1
driver: {type: opcua, endpoint: "opc.tcp://127.0.0.1:4840"}
variables:
  - {path: A, source: "ns=2;s=A", type: Double}
"""


def modules_after_building(tmp_path: Path, gateway_yaml: str) -> set[str]:
    (tmp_path / "m1.yaml").write_text(MAPPING)
    path = tmp_path / "gateway.yaml"
    path.write_text(gateway_yaml + "state_dir: state\nmachines: [m1.yaml]\n")
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(path)], capture_output=True, text=True, timeout=120, check=True
    )
    return set(json.loads(done.stdout.splitlines()[-1]))


def test_an_opcua_only_gateway_loads_neither_sparkplug_nor_protobuf_nor_the_alarm_service(
    tmp_path: Path,
) -> None:
    loaded = modules_after_building(tmp_path, "opcua: {endpoint: 'opc.tcp://127.0.0.1:4841/gw'}\n")
    assert "gateway.sinks.opcua.server" in loaded  # what is configured is there
    absent = {
        "google.protobuf",
        "gateway.codecs.sparkplug.wire",
        "gateway.sinks.sparkplug.sink",
        "gateway.alarms.service",
        "gateway.alarms.manager",
        "gateway.sinks.copydata.sink",
        "gateway.jobs.service",
    }
    assert absent.isdisjoint(loaded), sorted(absent & loaded)


def test_sparkplug_configured_loads_its_codec(tmp_path: Path) -> None:
    loaded = modules_after_building(
        tmp_path,
        "opcua: {endpoint: 'opc.tcp://127.0.0.1:4841/gw'}\n"
        "sparkplug: {group_id: plant, edge_node_id: gw, broker: {port: 1883}}\n",
    )
    assert {"gateway.sinks.sparkplug.sink", "google.protobuf"} <= loaded
