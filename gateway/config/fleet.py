"""The fleet file of `cnc-gateway fleet`: which gateway file its shards run, how many, and what tells
them apart (issue 29).

```yaml
gateway: gateway.yaml        # relative to this file; it says shard: ${CNC_SHARD}, state_dir: ${CNC_STATE_DIR}
shards: 2                    # default: one per core
ports: {OPCUA_PORT: 4840, HTTP_PORT: 8080}   # shard K gets each base + K - 1 in that variable
state_dir: state/shards      # shard K's state directory: <state_dir>/shard-K, in CNC_STATE_DIR
restart: {initial: 1, max: 30}
```
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from pydantic import Field, field_validator

from gateway.config.loader import read_yaml, validate
from gateway.settings.base import Backoff, Strict
from gateway.shards.supervisor import ShardSpec


class RestartBackoff(Backoff):
    initial: float = Field(default=1.0, gt=0)
    max: float = Field(default=30.0, gt=0)


class FleetFile(Strict):
    gateway: str = Field(description="The gateway file every shard runs (relative to the fleet file)")
    shards: int = Field(default_factory=lambda: os.cpu_count() or 1, ge=1, le=256)
    ports: dict[str, int] = Field(
        default_factory=dict, description="Environment variables with a base port: shard K gets base + K - 1"
    )
    state_dir: str = Field(
        default="state/shards", description="Shard K's state directory: <state_dir>/shard-K"
    )
    restart: RestartBackoff = Field(default_factory=RestartBackoff)

    @field_validator("ports")
    @classmethod
    def _ports(cls, ports: dict[str, int]) -> dict[str, int]:
        for name, port in ports.items():
            if not name.replace("_", "").isalnum() or not name[0].isalpha():
                raise ValueError(f"{name!r} is not an environment variable name")
            if not 1 <= port <= 65535:
                raise ValueError(f"{name}: {port} is not a port (1-65535)")
        return ports


def load_fleet(path: Path) -> tuple[FleetFile, Path]:
    """The fleet file and the gateway file it names (resolved). Raises ConfigError with file:line."""
    fleet = validate(FleetFile, read_yaml(path))
    return fleet, (path.parent / fleet.gateway).resolve()


def shard_specs(fleet: FleetFile, fleet_path: Path, gateway: Path) -> list[ShardSpec]:
    """One `cnc-gateway run` per shard, with the environment that makes it shard K."""
    base = fleet_path.parent
    out = []
    for k in range(1, fleet.shards + 1):
        environ = {name: str(port + k - 1) for name, port in fleet.ports.items()}
        environ["CNC_SHARD"] = f"{k}/{fleet.shards}"
        environ["CNC_SHARD_INDEX"] = str(k)  # for names: `edge_node_id: gw-${CNC_SHARD_INDEX}`
        environ["CNC_STATE_DIR"] = str((base / fleet.state_dir / f"shard-{k}").resolve())
        command = [sys.executable, "-m", "gateway.cli.main", "run", str(gateway)]
        out.append(ShardSpec(k, fleet.shards, command, environ))
    return out
