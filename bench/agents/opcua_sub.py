"""An OPC UA subscriber (asyncua client, its own process) that counts data-change notifications.

It subscribes to every node id listed in a file (one `nsu=<uri>;s=<id>` per line)
with the parameters a SCADA client typically uses (queue size 1, publishing
interval 100 ms by default) and keeps two Publish requests in flight. It runs its
own publish loop on asyncua's session, so that counting costs little beside
decoding; the value of each notification is kept per node for the final check.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import time
from datetime import UTC
from pathlib import Path
from typing import Any

from asyncua import Client, ua

from bench.agents.protocol import percentiles, serve, setup_logging

BATCH = 1000


def parse(text: str, namespaces: list[str]) -> ua.NodeId:
    uri_part, ident = text.split(";s=", 1)
    return ua.NodeId(ident, namespaces.index(uri_part.removeprefix("nsu=")), ua.NodeIdType.String)


class Counter:
    def __init__(self, n: int) -> None:
        self.count = 0
        self.good = 0
        self.last: list[float | None] = [None] * n
        self.latencies: list[float] = []
        self.timeouts = 0  # Publish requests the server did not answer in time (then asked again)
        self.errors = 0  # Publish requests that failed otherwise (logged, then asked again)

    def take(self, items: list[Any]) -> None:
        now = time.time()
        last = self.last
        for item in items:
            dv = item.Value
            self.count += 1
            code = dv.StatusCode
            if code is None or code.value == 0:
                self.good += 1
            variant = dv.Value
            if variant is not None and isinstance(variant.Value, float):
                last[item.ClientHandle] = variant.Value
            ts = dv.SourceTimestamp
            if ts is not None:
                self.latencies.append((now - ts.replace(tzinfo=UTC).timestamp()) * 1000.0)

    def snap(self, request: dict[str, Any]) -> dict[str, Any]:
        latencies, self.latencies = self.latencies, []
        return {
            "count": self.count,
            "good": self.good,
            "timeouts": self.timeouts,
            "errors": self.errors,
            "latency": percentiles(latencies),
        }

    def values(self, request: dict[str, Any]) -> dict[str, Any]:
        return {"last": self.last}


async def publish_loop(session: Any, counter: Counter) -> None:
    acks: list[ua.SubscriptionAcknowledgement] = []
    while True:
        try:
            response = await session.publish(acks)
        except (ua.uaerrors.BadTimeout, TimeoutError):  # a server slow under overload: ask again
            acks = []
            counter.timeouts += 1
            continue
        except Exception as exc:  # noqa: BLE001 - counted and logged; a dead loop would stop counting
            logging.getLogger("bench.opcua_sub").warning("publish failed: %s: %s", type(exc).__name__, exc)
            acks = []
            counter.errors += 1
            await asyncio.sleep(0.05)
            continue
        result = response.Parameters
        message = result.NotificationMessage
        acks = []
        if message.NotificationData:
            acks.append(ua.SubscriptionAcknowledgement(result.SubscriptionId, message.SequenceNumber))
            for data in message.NotificationData:
                if isinstance(data, ua.DataChangeNotification):
                    counter.take(data.MonitoredItems)


async def main(args: argparse.Namespace) -> None:
    lines = [line.strip() for line in args.ids.read_text().splitlines() if line.strip()]
    counter = Counter(len(lines))
    # asyncua's 1-s watchdog would drop the session when the gateway answers late under flat-out
    # overload (its loop then lags by seconds); this subscriber counts what arrives, it does not judge.
    client = Client(args.endpoint, timeout=60, watchdog_intervall=30)
    await client.connect()
    try:
        namespaces = await client.get_namespace_array()
        ids = [parse(line, namespaces) for line in lines]
        session = client.uaclient.session
        session.ensure_publish_loop = lambda: None  # our own loop below
        params = ua.CreateSubscriptionParameters(
            RequestedPublishingInterval=args.interval,
            RequestedLifetimeCount=600,
            RequestedMaxKeepAliveCount=100,
            MaxNotificationsPerPublish=0,
            PublishingEnabled=True,
            Priority=0,
        )
        sub = await session.create_subscription(params, callback=lambda result: None)
        for start in range(0, len(ids), BATCH):
            requests = [
                ua.MonitoredItemCreateRequest(
                    ItemToMonitor=ua.ReadValueId(NodeId=node_id, AttributeId=ua.AttributeIds.Value),
                    MonitoringMode=ua.MonitoringMode.Reporting,
                    RequestedParameters=ua.MonitoringParameters(
                        ClientHandle=start + k,
                        SamplingInterval=args.interval,
                        QueueSize=args.queue,
                        DiscardOldest=True,
                    ),
                )
                for k, node_id in enumerate(ids[start : start + BATCH])
            ]
            results = await session.create_monitored_items(
                ua.CreateMonitoredItemsParameters(
                    SubscriptionId=sub.SubscriptionId,
                    TimestampsToReturn=ua.TimestampsToReturn.Both,
                    ItemsToCreate=requests,
                )
            )
            bad = [r for r in results if not r.StatusCode.is_good()]
            if bad:
                raise RuntimeError(f"{len(bad)} monitored items refused: {bad[0].StatusCode}")
        loops = [asyncio.create_task(publish_loop(session, counter), name=f"publish-{k}") for k in range(2)]
        try:
            await serve({"snap": counter.snap, "values": counter.values}, {"items": len(ids)})
        finally:
            for task in loops:
                task.cancel()
            await asyncio.gather(*loops, return_exceptions=True)
    finally:
        with contextlib.suppress(Exception):  # a slow goodbye must not fail the benchmark
            async with asyncio.timeout(2):
                await client.disconnect()


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--endpoint", required=True)
    parser.add_argument("--ids", type=Path, required=True)
    parser.add_argument("--interval", type=float, default=100.0)
    parser.add_argument("--queue", type=int, default=1)
    setup_logging()
    asyncio.run(main(parser.parse_args()))
