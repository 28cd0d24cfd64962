"""docker-compose.fleet.yml and the gateway file it runs fit together (no Docker daemon runs here).

Each gateway service's environment, as compose would give it (the anchors merged), loads
mappings/compose-fleet/gateway.yaml over the simulator's six machines: lease-served on the PostgreSQL
service, its shard K, its own passive ports; the redundant set names every shard's URI as the
containers' hostname makes it; host ports do not collide; the simulator writes as many machines as
the gateway file lists, with the address the shards reach it at.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import yaml

from gateway.config.loader import load
from gateway.sinks.opcua.redundancy import application_uri

ROOT = Path(__file__).resolve().parents[3]


def compose() -> dict[str, Any]:
    data: dict[str, Any] = yaml.safe_load((ROOT / "docker-compose.fleet.yml").read_text())
    return data


def test_every_shard_of_the_compose_fleet_loads_its_gateway_file(tmp_path: Path) -> None:
    services = compose()["services"]
    shards = {name: s for name, s in services.items() if name.startswith("gateway-")}
    assert len(shards) == 3
    simulator = services["simulator"]["command"]
    machines = int(simulator[simulator.index("--machines") + 1])
    assert simulator[simulator.index("--fleet-address") + 1] == "simulator"
    # The layout of the image: /app/mappings/compose-fleet/gateway.yaml, the fleet volume at /app/fleet.
    (tmp_path / "mappings" / "compose-fleet").mkdir(parents=True)
    gateway_file = tmp_path / "mappings/compose-fleet/gateway.yaml"
    shutil.copy(ROOT / "mappings/compose-fleet/gateway.yaml", gateway_file)
    (tmp_path / "fleet").mkdir()
    for k in range(1, machines + 1):
        (tmp_path / "fleet" / f"laser-{k:03d}.yaml").write_text(
            f"machine: laser-{k:03d}\ndriver: {{endpoint: 'opc.tcp://simulator:4841'}}\n"
            "variables: [{path: A/B, source: 'ns=2;s=x', type: Double}]\n"
        )
    host_ports: list[str] = []
    passive: list[range] = []
    for name, service in sorted(shards.items()):
        env = {k: str(v) for k, v in service["environment"].items()}
        k = int(env["CNC_SHARD_INDEX"])
        assert name == f"gateway-{k}" and env["CNC_SHARD"] == f"{k}/3"
        assert service["hostname"] == "cnc-gateway"
        env["CNC_STATE_DIR"] = str(tmp_path / f"state-{k}")
        config = load([gateway_file], environ=env)
        gw = config.gateway
        assert gw.leased and len(config.machines) == machines
        assert gw.queue is not None and "@postgres:5432/cnc" in gw.queue
        assert application_uri(k, service["hostname"]) in gw.opcua.redundant_servers
        ports = gw.inbox.passive_ports
        passive.append(range(ports.min, ports.max + 1))
        assert (ports.min, ports.max) == (int(env["PASSIVE_MIN"]), int(env["PASSIVE_MAX"]))
        host_ports += [p.split(":")[0] for p in service["ports"]]
        assert f"{ports.min}-{ports.max}:{ports.min}-{ports.max}" in service["ports"]
    assert len(host_ports) == len(set(host_ports)), host_ports
    assert not set(passive[0]) & set(passive[1]) and not set(passive[1]) & set(passive[2])
