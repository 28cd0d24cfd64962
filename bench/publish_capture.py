"""Real PublishResponses from the simulator, as the bytes asyncua hands its decoder.

`python -m bench.publish_capture OUT [--seconds S] [--noise N] [--rate R] [--measure]` runs the simulator in
process (the demo program looping, plus N noise Doubles at R changes/s), subscribes an asyncua
client to every variable, and records the body of each PublishResponse (from its TypeId on) as
`struct_from_binary` would read it. The records are stored as a 4-byte little-endian length and
the body, one after another: tests/corpus/opcua/publish-responses.bin is such a file (the
differential tests of the compiled reader read it). With `--measure` it then decodes the same
captured responses over and over with asyncua (`struct_from_binary`, what `UaSession.publish` does)
and with the source's compiled reader, and prints the notifications decoded per CPU second of each
as JSON (bench/scenarios/baselines.py, `publish_decode`).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import struct
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from asyncua import Client, ua
from asyncua.common.utils import Buffer
from asyncua.ua.ua_binary import struct_from_binary

from gateway.sources.opcua import publish_decode
from simulator.noise import NoiseSpec
from simulator.runner import Simulator
from simulator.variables import NAMESPACE_URI, build_variables

_LENGTH = struct.Struct("<I")


def write_records(path: Path, bodies: list[bytes]) -> None:
    path.write_bytes(b"".join(_LENGTH.pack(len(b)) + b for b in bodies))


def read_records(path: Path) -> Iterator[bytes]:
    data = path.read_bytes()
    pos = 0
    while pos < len(data):
        (n,) = _LENGTH.unpack_from(data, pos)
        yield data[pos + 4 : pos + 4 + n]
        pos += 4 + n


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Quiet:
    """A subscription handler that takes the notifications and does nothing with them."""

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        pass


async def capture(seconds: float, noise: int, rate: float, interval_ms: float = 50.0) -> list[bytes]:
    """PublishResponse bodies received in `seconds` from a fresh simulator."""
    bodies: list[bytes] = []
    with tempfile.TemporaryDirectory(prefix="cnc-capture-") as store:
        spec = NoiseSpec(noise, rate) if noise else None
        simulator = Simulator(
            opcua_port=_free_port(),
            ftp_port=0,
            store=Path(store),
            loop_program="demo.nc",
            speed=5.0,
            noise=spec,
        )
        async with simulator as sim:
            client = Client(sim.opcua_endpoint)
            await client.connect()
            try:
                session = client.uaclient.session
                send = session._send_request

                async def recording(request: Any, *args: Any, **kwargs: Any) -> Any:
                    data = await send(request, *args, **kwargs)
                    if isinstance(request, ua.PublishRequest):
                        bodies.append(bytes(data))
                    return data

                session._send_request = recording
                ns = await client.get_namespace_index(NAMESPACE_URI)
                ids = [v.node_id for v in build_variables()]
                if spec is not None:
                    ids += [spec.node_id(i) for i in range(noise)]
                subscription = await client.create_subscription(interval_ms, _Quiet())
                nodes = [client.get_node(ua.NodeId(i, ns)) for i in ids]
                await subscription.subscribe_data_change(nodes, queuesize=1)
                await asyncio.sleep(seconds)
                await subscription.delete()
            finally:
                await client.disconnect()
    return bodies


def _per_second(bodies: list[bytes], decode: Any, changes: int, minimum: float = 1.0) -> float:
    """Notifications decoded per CPU second: the best of three passes of at least `minimum` s each."""
    best = 0.0
    for _ in range(3):
        rounds, start = 0, time.process_time()
        while (spent := time.process_time() - start) < minimum or rounds == 0:
            for body in bodies:
                decode(Buffer(body))
            rounds += 1
        best = max(best, rounds * changes / spent)
    return best


def measure(bodies: list[bytes]) -> dict[str, Any]:
    """asyncua's decoding and the compiled reader on the same responses."""
    published = [
        publish_decode.from_response(struct_from_binary(ua.PublishResponse, Buffer(b))) for b in bodies
    ]
    changes = sum(len(p.changes) for p in published)
    fast = [publish_decode.decode_fast(Buffer(b)) for b in bodies]
    out: dict[str, Any] = {
        "responses": len(bodies),
        "changes": changes,
        "fast_share": sum(f is not None for f in fast) / max(1, len(bodies)),
        "asyncua": _per_second(bodies, lambda b: struct_from_binary(ua.PublishResponse, b), changes),
        "compiled": None,
    }
    if publish_decode.compiled is not None and not publish_decode.PURE:
        out["compiled"] = _per_second(bodies, publish_decode.decode, changes)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--noise", type=int, default=100)
    parser.add_argument("--rate", type=float, default=500.0)
    parser.add_argument("--measure", action="store_true", help="then time both decoders on them (JSON)")
    args = parser.parse_args()
    bodies = asyncio.run(capture(args.seconds, args.noise, args.rate))
    write_records(args.out, bodies)
    if args.measure:
        print(json.dumps(measure(bodies)))
    else:
        print(f"{len(bodies)} PublishResponses, {sum(map(len, bodies)):,} bytes, in {args.out}")


if __name__ == "__main__":
    main()
