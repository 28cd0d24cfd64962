"""One gateway with every door open, for the bad-input corpus: simulator, Mosquitto, FTP inbox, COPYDATA.

The machine is mappings/laser-sim.yaml pointed at an in-process simulator, with
its jobs (delivered to the simulator's FTP store), its COPYDATA tcp-server target
(accept_writes, with access.copydata_role operator) and MQTT writes and commands
enabled, except Machine/Mode, which keeps MQTT writes off, and Laser/PowerSetpoint
made readwrite in the mapping (the simulator keeps it read-only: the controller's
own refusal). Next to it, one
jobs-only machine per set of validation rules that the G-code corpus asks for
(`gc0`, `gc1`, …), delivering to `/DATA/<machine>` on the same store.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load_mapping
from gateway.sinks.copydata.emitter import Emitter
from gateway.sinks.copydata.tcp import TcpServerTransport
from gateway.sinks.sparkplug.config import SparkplugConfig
from simulator.runner import Simulator
from tests.integration.drills.processes import ROOT, write_yaml
from tests.integration.jobs.conftest import PASSWORD_HASH, USER
from tests.integration.mqtt.conftest import mqtt_config
from tests.waiting import free_port

MACHINE = "laser-sim"
# Inbox limits small enough for tests/corpus/ftp/attacks.yaml to reach quickly: appends past max_file_size,
# sessions held until login_timeout, a transfer that waits for a data connection from its own address.
ATTACK_LIMITS = {"max_file_size": "1MiB", "login_timeout": 3, "max_connections_per_address": 4,
                 "transfer_timeout": 5}  # fmt: skip


def laser_sim_mapping(sim_port: int, ftp_port: int) -> dict[str, Any]:
    data = yaml.safe_load((ROOT / "mappings" / "laser-sim.yaml").read_text())
    data["driver"].update(endpoint=f"opc.tcp://127.0.0.1:{sim_port}", watchdog_interval=0.5,
                          reconnect={"initial": 0.2, "max": 2.0, "factor": 2})  # fmt: skip
    data["jobs"]["controller"].update(host="127.0.0.1", port=ftp_port, user="cnc", password="simulator")
    data["jobs"]["retry"] = {"initial": 0.05, "max": 0.5, "factor": 2}
    target = data["copydata"]["targets"][0]
    target.update(bind="127.0.0.1", port=0, accept_writes=True)  # with access.copydata_role below
    data["mqtt"] = {"writable": True, "commands": True}
    for variable in data["variables"]:
        if variable["path"] == "Machine/Mode":
            variable["mqtt"] = {"writable": False}
        if variable["path"] == "Laser/PowerSetpoint":
            variable["access"] = "readwrite"
    return data


SPARKPLUG_MACHINE = "spb"


def sparkplug_machine(sim_port: int) -> dict[str, Any]:
    """A machine with the variables that tests/corpus/sparkplug/commands.yaml's births name: they need not
    exist on the simulator, the refusals come before any write."""
    from tests.integration.sparkplug.test_corpus import TYPES

    variables = [{"path": "Machine/State", "source": "ns=2;s=::AsGlobalPV:gMachine.State", "type": "Int16"}]
    variables += [{"path": path, "source": f"ns=2;s=::Corpus:{path}", "type": kind, "access": "readwrite"}
                  for path, kind in TYPES.items()]  # fmt: skip
    return {"machine": SPARKPLUG_MACHINE, "driver": {"endpoint": f"opc.tcp://127.0.0.1:{sim_port}"},
            "variables": variables, "mqtt": {"writable": True}}  # fmt: skip


def rules_machine(name: str, sim_port: int, ftp_port: int, rules: dict[str, Any]) -> dict[str, Any]:
    return {
        "machine": name,
        "driver": {"endpoint": f"opc.tcp://127.0.0.1:{sim_port}"},
        "variables": [
            {"path": "Machine/State", "source": "ns=2;s=::AsGlobalPV:gMachine.State", "type": "Int16"}
        ],
        "jobs": {
            "controller": {"host": "127.0.0.1", "port": ftp_port, "user": "cnc", "password": "simulator",
                           "folder": f"/DATA/{name}", "timeout": 5},
            "validation": rules,
            "retry": {"initial": 0.05, "max": 0.2, "factor": 2},
        },
    }  # fmt: skip


@dataclass
class CorpusRig:
    gateway: Gateway
    sim: Simulator
    opcua_port: int
    mqtt_port: int
    store: Path
    rule_machines: dict[str, str]  # canonical JSON of a rule set -> machine name
    run: asyncio.Task[None]  # the gateway's run(): must still be running at the end

    @property
    def state(self) -> Path:
        return self.gateway.config.state_dir

    @property
    def inbox_port(self) -> int:
        return self.gateway.jobs.inbox.port  # type: ignore[no-any-return]

    @property
    def inbox(self) -> Any:
        return self.gateway.jobs.inbox

    @property
    def queue(self) -> Any:
        return self.gateway.jobs.queue

    def emitter(self) -> Emitter:
        return self.gateway.sink("copydata").emitter(MACHINE, "nesting")  # type: ignore[no-any-return]

    async def copydata_port(self) -> int:
        transport = self.emitter().transport
        assert isinstance(transport, TcpServerTransport)
        await asyncio.wait_for(transport.listening.wait(), 10)
        return transport.port

    def machine_for(self, rules: dict[str, Any]) -> str:
        return self.rule_machines[json.dumps(rules, sort_keys=True)]


@asynccontextmanager
async def corpus_rig(
    tmp_path: Path, mqtt_port: int, rule_sets: list[dict[str, Any]]
) -> AsyncIterator[CorpusRig]:
    sim_port, ftp_port, opcua_port = free_port(), free_port(), free_port()
    store = tmp_path / "store"
    tmp_path.mkdir(parents=True, exist_ok=True)
    files = [write_yaml(tmp_path / f"{MACHINE}.yaml", laser_sim_mapping(sim_port, ftp_port)),
             write_yaml(tmp_path / f"{SPARKPLUG_MACHINE}.yaml", sparkplug_machine(sim_port))]  # fmt: skip
    machines: dict[str, str] = {}
    for index, rules in enumerate(rule_sets):
        name = f"gc{index}"
        machines[json.dumps(rules, sort_keys=True)] = name
        files.append(write_yaml(tmp_path / f"{name}.yaml", rules_machine(name, sim_port, ftp_port, rules)))
    mappings = tuple(load_mapping(f, environ={}) for f in files)
    gateway = GatewayConfig.model_validate({
        "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{opcua_port}/cnc-gateway", "security": ["None"]},
        "state_dir": str(tmp_path / "state"),
        "access": {"copydata_role": "operator"},
        "inbox": {"host": "127.0.0.1", "port": 0,
                  "accounts": [{"user": USER, "password_hash": PASSWORD_HASH}], **ATTACK_LIMITS},
    }).model_copy(update={"mqtt": mqtt_config(mqtt_port), "sparkplug": SparkplugConfig()})  # fmt: skip
    async with Simulator(opcua_port=sim_port, ftp_port=ftp_port, speed=20.0, store=store) as sim:
        for name in machines.values():
            (store / "DATA" / name).mkdir(parents=True, exist_ok=True)
        async with Gateway(Config(gateway, mappings, tmp_path)) as gw:
            run = asyncio.create_task(gw.run(), name="gateway")
            try:
                yield CorpusRig(gw, sim, opcua_port, mqtt_port, store, machines, run)
            finally:
                if run.done() and not run.cancelled() and run.exception() is not None:
                    raise AssertionError("the gateway stopped") from run.exception()
                run.cancel()
                await asyncio.gather(run, return_exceptions=True)
