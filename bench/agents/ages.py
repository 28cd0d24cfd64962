"""Where a change's age accrues inside the gateway (bench only: `bench.agents.gateway --ages`).

The MQTT subscriber measures the whole age of a value (its receipt - the controller's source
timestamp). To tell the part before the gateway from the part inside it and the part after,
this records the same age at two points of the gateway: when the OPC UA source hands a
change to the tree (`ingest`: the simulator, its publish queue and the TCP link are behind
it), and when the MQTT sink encodes it into the packets it writes to the socket (`write`).
What the subscriber sees beyond `write` accrued in the kernel, Mosquitto or the subscriber.

It wraps two methods of the running classes, only when asked for, and records every
`STRIDE`th change of each batch: about 0.05 ms of CPU per 1,000 changes, so that the
peer's CPU figure stays the gateway's (every change: 0.35 ms, 2-6 % of that figure).
"""

from __future__ import annotations

import time
from typing import Any

from bench.agents.protocol import percentiles
from gateway.model.hub import Change
from gateway.model.tree import VariableNode
from gateway.sinks.mqtt.sink import MqttSink
from gateway.sources.opcua.client import OpcUaSource
from gateway.sources.opcua.publish_decode import Change as SourceChange

STRIDE = 8  # every 8th change of a batch: thousands a second under load, plenty for a p99


class Ages:
    """Ages (ms) at ingest and at the MQTT write since the last `take`, and the responses' sizes."""

    def __init__(self) -> None:
        self.ingest: list[float] = []
        self.write: list[float] = []
        self.responses: list[float] = []  # changes per PublishResponse

    def install(self) -> None:
        ages = self
        process = OpcUaSource._process
        encode = MqttSink._encode

        def timed_process(self: OpcUaSource, changes: list[SourceChange], *args: Any) -> None:
            now = time.time()
            record = ages.ingest.append
            for _, _, stamp, _ in changes[::STRIDE]:
                if stamp is not None:
                    record((now - stamp.timestamp()) * 1000.0)
            ages.responses.append(float(len(changes)))
            process(self, changes, *args)

        async def timed_encode(self: MqttSink, batch: list[Change[VariableNode]]) -> None:
            now = time.time()
            record = ages.write.append
            for _, sample in batch[::STRIDE]:
                record((now - sample.source_ts.timestamp()) * 1000.0)
            await encode(self, batch)

        OpcUaSource._process = timed_process  # type: ignore[method-assign]
        MqttSink._encode = timed_encode  # type: ignore[method-assign]

    def take(self) -> dict[str, Any]:
        ingest, write, responses = self.ingest, self.write, self.responses
        self.ingest, self.write, self.responses = [], [], []
        return {
            "ingest": percentiles(ingest),
            "write": percentiles(write),
            "responses": {**percentiles(responses), "count": len(responses)},
        }
