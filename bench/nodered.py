"""Node-RED as the bench runs it: the pinned install, a headless settings file, a generated flow, the process.

The peer the gateway is measured against (bench/scenarios/peer.py) is the flow
people build by hand: node-red-contrib-opcua's OpcUa-Client in its multiple-subscribe
mode (action `subscribe`, `msg.topic = "multiple"`, `msg.payload` the list of node
ids: one ClientMonitoredItemGroup, queue size 1) → a function node that writes the
gateway's JSON shape → an `mqtt out` node. `make bench` installs Node-RED,
the OPC UA nodes and Node.js 22 (the `node` package on npm) into bench/peer/node_modules
from the committed package-lock.json; nothing here installs anything.

Node-RED runs headless: no editor and no admin API (`httpAdminRoot: false`), no
HTTP nodes, no telemetry, no palette or module installs, its user directory, HOME
and PKI folder inside the run's work directory, and the HTTP server on a free
loopback port.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
from pathlib import Path
from typing import Any, Self

from bench.procs import ROOT, BenchError, free_port

PEER_DIR = ROOT / "bench" / "peer"
MODULES = PEER_DIR / "node_modules"
NODE = MODULES / "node" / "bin" / "node"
RED = MODULES / "node-red" / "red.js"
PACKAGES = ("node", "node-red", "node-red-contrib-opcua")

# What the function node does to each notification of the group: the gateway's payload shape
# (gateway/sinks/mqtt/payloads.py: value first, then the source time in ISO with milliseconds, then
# quality), so bench/agents/mqtt_sub.py measures both the same way, and a topic per variable.
FORMAT = """\
const dv = msg.payload;
if (!dv || !dv.value || typeof msg.topic !== "string") { return null; }
const id = msg.topic;
const ts = dv.sourceTimestamp || dv.serverTimestamp || new Date();
const good = dv.statusCode ? dv.statusCode.value === 0 : true;
msg.topic = PREFIX + id.slice(id.lastIndexOf(":") + 1).replace(".", "/");
msg.payload = JSON.stringify({value: dv.value.value, ts: ts.toISOString(), quality: good ? "good" : "bad"});
return msg;
"""


def installed_versions() -> dict[str, str]:
    """The versions in bench/peer/node_modules; a clear error when `make bench` has not installed them."""
    found = {}
    for name in PACKAGES:
        manifest = MODULES / name / "package.json"
        if not manifest.exists():
            raise BenchError(
                f"{name} is not installed in {MODULES}: `make bench` installs the peer (needs npm)"
            )
        found[name] = str(json.loads(manifest.read_text(encoding="utf-8"))["version"])
    if not NODE.exists():
        raise BenchError(f"{NODE} is missing: the `node` package's install script did not run (make bench)")
    return found


def settings_js(user_dir: Path, port: int, flow_file: Path) -> str:
    """A settings file for a headless run: nothing listens but a loopback port, nothing calls out."""
    settings: dict[str, Any] = {
        "uiHost": "127.0.0.1",
        "uiPort": port,
        "userDir": str(user_dir),
        "flowFile": str(flow_file),
        "flowFilePretty": False,
        "credentialSecret": False,
        "httpAdminRoot": False,  # no editor, no admin API, so no login either
        "httpNodeRoot": False,
        "disableEditor": True,
        "diagnostics": {"enabled": False, "ui": False},
        "runtimeState": {"enabled": False, "ui": False},
        "telemetry": {"enabled": False, "updateNotification": False},
        "externalModules": {
            "autoInstall": False,
            "palette": {"allowInstall": False, "allowUpload": False},
            "modules": {"allowInstall": False},
        },
        "functionExternalModules": False,
        "editorTheme": {"projects": {"enabled": False}},
        "logging": {"console": {"level": "warn", "metrics": False, "audit": False}},
    }
    return "module.exports = " + json.dumps(settings, indent=2) + ";\n"


def flow(
    endpoint: str, node_ids: list[str], broker_port: int, *, interval_ms: float, qos: int, topic_prefix: str
) -> list[dict[str, Any]]:
    """inject (once, at start: the node ids) → OpcUa-Client (subscribe, multiple) → function → mqtt out."""
    items = [{"nodeId": ident} for ident in node_ids]
    return [
        {"id": "bench.tab", "type": "tab", "label": "cnc-gateway bench peer", "disabled": False, "info": ""},
        {
            "id": "bench.endpoint",
            "type": "OpcUa-Endpoint",
            "endpoint": endpoint,
            "secpol": "None",
            "secmode": "None",
            "none": True,
            "login": False,
            "usercert": False,
            "name": "simulator",
        },
        {
            "id": "bench.broker",
            "type": "mqtt-broker",
            "name": "bench mosquitto",
            "broker": "127.0.0.1",
            "port": str(broker_port),
            "clientid": f"bench-nodered-{broker_port}",
            "autoConnect": True,
            "usetls": False,
            "protocolVersion": "4",
            "keepalive": "30",
            "cleansession": True,
            "autoUnsubscribe": True,
            "birthTopic": "",
            "closeTopic": "",
            "willTopic": "",
            "sessionExpiry": "",
        },
        {
            "id": "bench.start",
            "type": "inject",
            "z": "bench.tab",
            "name": "subscribe all",
            "props": [{"p": "topic", "vt": "str"}, {"p": "payload"}],
            "repeat": "",
            "crontab": "",
            "once": True,
            "onceDelay": "0.5",
            "topic": "multiple",
            "payload": json.dumps(items),
            "payloadType": "json",
            "x": 120,
            "y": 80,
            "wires": [["bench.client"]],
        },
        {
            "id": "bench.client",
            "type": "OpcUa-Client",
            "z": "bench.tab",
            "endpoint": "bench.endpoint",
            "action": "subscribe",
            "deadbandtype": "a",
            "deadbandvalue": 1,
            "time": interval_ms,
            "timeUnit": "ms",
            "certificate": "n",
            "localfile": "",
            "localkeyfile": "",
            "securitymode": "None",
            "securitypolicy": "None",
            "useTransport": False,
            "maxChunkCount": 1,
            "maxMessageSize": 8192,
            "receiveBufferSize": 8192,
            "sendBufferSize": 8192,
            "setstatusandtime": False,
            "keepsessionalive": False,
            "name": "noise",
            "applicationName": "",
            "applicationUri": "",
            "x": 320,
            "y": 80,
            "wires": [["bench.format"], [], []],
        },
        {
            "id": "bench.format",
            "type": "function",
            "z": "bench.tab",
            "name": "gateway JSON",
            "func": FORMAT.replace("PREFIX", json.dumps(topic_prefix)),
            "outputs": 1,
            "timeout": 0,
            "noerr": 0,
            "initialize": "",
            "finalize": "",
            "libs": [],
            "x": 520,
            "y": 80,
            "wires": [["bench.out"]],
        },
        {
            "id": "bench.out",
            "type": "mqtt out",
            "z": "bench.tab",
            "name": "",
            "topic": "",
            "qos": str(qos),
            "retain": "true",
            "respTopic": "",
            "contentType": "",
            "userProps": "",
            "correl": "",
            "expiry": "",
            "broker": "bench.broker",
            "x": 700,
            "y": 80,
            "wires": [],
        },
    ]


class NodeRed:
    """Node-RED with a generated flow, in `folder`; `pid` for meters; SIGTERM (then SIGKILL) on exit."""

    def __init__(self, folder: Path, flow_nodes: list[dict[str, Any]]) -> None:
        self.folder = folder
        self.flow_nodes = flow_nodes
        self.port = free_port()
        self.log = folder / "node-red.log"
        self.proc: asyncio.subprocess.Process | None = None

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.returncode is None

    async def __aenter__(self) -> Self:
        installed_versions()
        user_dir = self.folder / "userdir"
        user_dir.mkdir(parents=True, exist_ok=True)
        flows = user_dir / "flows.json"
        flows.write_text(json.dumps(self.flow_nodes, indent=1), encoding="utf-8")
        settings = user_dir / "settings.js"
        settings.write_text(settings_js(user_dir, self.port, flows), encoding="utf-8")
        env = {k: v for k, v in os.environ.items() if "proxy" not in k.lower()}
        env.update({
            "HOME": str(self.folder),  # node-opcua's PKI (env-paths) and Node-RED's defaults stay in the run
            "XDG_CONFIG_HOME": str(self.folder / ".config"),
            "NODE_RED_DISABLE_TELEMETRY": "1",
            "NODE_ENV": "production",
        })  # fmt: skip
        with self.log.open("ab") as log:
            self.proc = await asyncio.create_subprocess_exec(
                str(NODE), str(RED), "--settings", str(settings), "--userDir", str(user_dir),
                "--no-telemetry", str(flows),
                stdin=asyncio.subprocess.DEVNULL, stdout=log, stderr=log, env=env, cwd=str(self.folder),
            )  # fmt: skip
        return self

    def check(self) -> None:
        if not self.running:
            raise BenchError(
                f"Node-RED exited with {self.proc.returncode if self.proc else '?'} "
                f"(see {self.log}):\n{self.tail()}"
            )

    def tail(self, lines: int = 20) -> str:
        try:
            return "\n".join(self.log.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    async def __aexit__(self, *exc: object) -> None:
        if self.proc is None or self.proc.returncode is not None:
            return
        self.proc.send_signal(signal.SIGTERM)
        try:
            async with asyncio.timeout(10):
                await self.proc.wait()
        except TimeoutError:
            self.proc.kill()
            await self.proc.wait()
