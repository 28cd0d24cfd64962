"""A real Mosquitto per test on a free loopback port, and a recording MQTT subscriber.

Mosquitto runs with `persistence true`, so a persistent subscriber session
(clean_session=False) and the retained messages survive the broker being
stopped and started again on the same port: that is what lets the broker
restart test check that a QoS 1 subscriber lost nothing.
"""

from __future__ import annotations

import getpass
import json
import os
import shutil
import signal
import socket
import subprocess
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import paho.mqtt.client as paho
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config
from gateway.config.mapping import MachineMapping
from gateway.sinks.mqtt.config import MqttConfig
from tests.loops import LoopFactory, both
from tests.waiting import free_port, wait_until_sync

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


class Mosquitto:
    """A Mosquitto process with its own config and persistence directory; restartable on its port."""

    def __init__(self, directory: Path, port: int, *, extra: str = "", anonymous: bool = True) -> None:
        self.directory = directory
        self.port = port
        self.extra = extra
        self.anonymous = anonymous
        self.proc: subprocess.Popen[bytes] | None = None
        self.conf = directory / "mosquitto.conf"
        self.log = directory / "mosquitto.log"

    def write_config(self) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        self.conf.write_text(
            f"listener {self.port} 127.0.0.1\n"
            f"allow_anonymous {'true' if self.anonymous else 'false'}\n"
            # Started as root, Mosquitto would switch to the `mosquitto` user, who cannot read our files.
            f"user {getpass.getuser()}\n"
            "persistence true\n"
            f"persistence_location {self.directory}/\n"
            "autosave_interval 1\n"
            "max_queued_messages 100000\n"
            "max_inflight_messages 100\n"
            "log_dest stderr\n"
            "log_type error\n"
            "log_type warning\n" + self.extra,
            encoding="utf-8",
        )

    def start(self) -> None:
        self.write_config()
        with self.log.open("ab") as log:
            self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.conf)], stdout=log, stderr=log)
        deadline = time.monotonic() + 10
        while not _listening(self.port):
            if self.proc.poll() is not None:
                raise RuntimeError(f"mosquitto exited: {self.log.read_text(errors='replace')}")
            if time.monotonic() > deadline:
                raise RuntimeError("mosquitto did not start listening")
            time.sleep(0.02)

    def stop(self, sig: int = signal.SIGTERM) -> None:
        """SIGTERM saves the persistence file (sessions, queued and retained messages); SIGKILL does not."""
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        self.proc = None
        wait_until_sync(lambda: not _listening(self.port), timeout=5, message="the port to close")


@dataclass
class Received:
    topic: str
    payload: bytes
    retain: bool
    qos: int
    properties: Any = None

    def json(self) -> Any:
        return json.loads(self.payload)


@dataclass
class Recorder:
    """A paho subscriber in its own network thread that records every message it gets."""

    port: int
    topics: list[str] = field(default_factory=lambda: ["cnc/#"])
    client_id: str = field(default_factory=lambda: f"test-{uuid.uuid4().hex[:8]}")
    persistent: bool = False
    v5: bool = False
    tls: Any = None  # (ca, cert, key) file paths for a TLS listener
    resumed: int = 0  # reconnections that found the broker still holding our session
    messages: list[Received] = field(default_factory=list)
    subscribed: threading.Event = field(default_factory=threading.Event)
    client: paho.Client | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def start(self) -> Recorder:
        kwargs: dict[str, Any] = {}
        if self.v5:
            kwargs["protocol"] = paho.MQTTv5
        else:
            kwargs["clean_session"] = not self.persistent
        client = paho.Client(CallbackAPIVersion.VERSION2, client_id=self.client_id, **kwargs)
        client.on_connect = self._on_connect
        client.on_message = self._on_message
        client.on_subscribe = lambda *a: self.subscribed.set()
        client.reconnect_delay_set(0.05, 0.2)
        if self.tls is not None:
            ca, cert, key = self.tls
            client.tls_set(
                ca_certs=str(ca), certfile=str(cert) if cert else None, keyfile=str(key) if key else None
            )
        if self.v5:
            from paho.mqtt.packettypes import PacketTypes
            from paho.mqtt.properties import Properties

            props = Properties(PacketTypes.CONNECT)
            if self.persistent:
                props.SessionExpiryInterval = 3600
            client.connect(
                "127.0.0.1", self.port, keepalive=10, clean_start=not self.persistent, properties=props
            )
        else:
            client.connect("127.0.0.1", self.port, keepalive=10)
        client.loop_start()
        self.client = client
        wait_until_sync(self.subscribed.is_set, timeout=10, message="the test subscriber's SUBACK")
        return self

    def _on_connect(self, client: paho.Client, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            return
        if self.persistent and flags.session_present:
            # The broker kept our session (subscriptions and queued messages): rely on it, so that a
            # lost session fails the test instead of being papered over by a new subscription.
            self.resumed += 1
            return
        client.subscribe([(t, 1) for t in self.topics])

    def _on_message(self, client: paho.Client, userdata: Any, msg: paho.MQTTMessage) -> None:
        with self._lock:
            self.messages.append(
                Received(msg.topic, bytes(msg.payload), bool(msg.retain), msg.qos, msg.properties)
            )

    def stop(self) -> None:
        if self.client is not None:
            self.client.disconnect()
            self.client.loop_stop()
            self.client = None

    # --- reading what arrived ------------------------------------------------------------------

    def on(self, topic: str) -> list[Received]:
        with self._lock:
            return [m for m in self.messages if m.topic == topic]

    def last(self, topic: str) -> Received | None:
        got = self.on(topic)
        return got[-1] if got else None

    def last_json(self, topic: str) -> Any:
        got = self.last(topic)
        return got.json() if got is not None else None

    def publish(
        self, topic: str, payload: bytes | str, qos: int = 1, retain: bool = False, properties: Any = None
    ) -> None:
        assert self.client is not None
        self.client.publish(topic, payload, qos, retain, properties)


def subscriber(recorders: list[Recorder], port: int, **kwargs: Any) -> Recorder:
    rec = Recorder(port, **kwargs).start()
    recorders.append(rec)
    return rec


def mqtt_config(port: int, **overrides: Any) -> MqttConfig:
    """Fast timings, so loss and reconnect tests stay short."""
    settings: dict[str, Any] = {
        "port": port,
        "client_id": f"gw-{uuid.uuid4().hex[:8]}",
        "keepalive": 5,
        "connect_timeout": 2,
        "reconnect": {"initial": 0.05, "max": 0.3},
    }
    settings.update(overrides)
    return MqttConfig.model_validate(settings)


def gateway_config(mapping: MachineMapping, state_dir: Path, mqtt: MqttConfig, opcua_port: int) -> Config:
    gateway = GatewayConfig.model_validate(
        {
            "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{opcua_port}/cnc-gateway"},
            "state_dir": str(state_dir),
            "inbox": {"port": free_port()},
        }
    ).model_copy(update={"mqtt": mqtt})
    return Config(gateway, (mapping,), state_dir.parent)


def env_without_proxy() -> dict[str, str]:
    env = dict(os.environ)
    for key in ("http_proxy", "https_proxy", "all_proxy", "HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY"):
        env.pop(key, None)
    return env


def pytest_asyncio_loop_factories(config: pytest.Config, item: pytest.Item) -> dict[str, LoopFactory]:
    """The sink's own tests on asyncio's loop and on uvloop (tests/loops.py): paho's socket hooks meet
    the loop there."""
    return both(item, {"test_sink.py", "test_freshness.py"})
