"""How long an MTConnect /current and /sample take to render for 20 machines x 500 data items.

    .venv/bin/python -m bench.mtconnect_render [--devices 20] [--items 500] [--rounds 50]

Pure CPU, no server: the buffer query plus the document join, per request, as the agent
sink will do it. Between rounds 5 % of the data items change, so every /current renders
some new observations (the rest reuse their element, rendered once). Wall-clock and
CPU time are both printed: on a shared machine the wall clock mostly measures the
neighbours. Issue 17: /current
p50 must be under 100 ms at 10,000 data items, aim 25 ms.
"""

from __future__ import annotations

import argparse
import random
import statistics
import time
from collections.abc import Callable
from datetime import UTC, datetime

from gateway.codecs.mtconnect.buffer import ObservationBuffer
from gateway.codecs.mtconnect.documents import DocumentInfo, streams_xml
from gateway.codecs.mtconnect.json_documents import streams_json
from gateway.codecs.mtconnect.model import Category
from gateway.codecs.mtconnect.paths import PathIndex, parse_path
from gateway.codecs.mtconnect.timestamps import format_timestamp
from tests.unit.codecs.mtconnect.machines import shop


def _change(buffer: ObservationBuffer, rng: random.Random, share: float) -> None:
    now = datetime.now(UTC)
    items = list(buffer.catalog.items.values())
    for info in rng.sample(items, int(len(items) * share)):
        item = info.item
        if item.category is Category.CONDITION:
            buffer.add_condition(item.id, now, rng.choice(["NORMAL", "WARNING", "FAULT"]), native_code="E1")
        elif info.time_series:
            buffer.add_value(item.id, now, [rng.random() for _ in range(8)], sample_rate=100.0)
        elif item.category is Category.SAMPLE:
            buffer.add_value(
                item.id, now, [rng.random()] * 3 if item.type == "PATH_POSITION" else rng.random()
            )
        elif item.type in ("EXECUTION", "CONTROLLER_MODE", "EMERGENCY_STOP", "AVAILABILITY", "POWER_STATE"):
            continue
        elif item.type in ("ASSET_CHANGED", "ASSET_REMOVED"):
            buffer.add_value(item.id, now, "T1", asset_type="CuttingTool")
        elif item.type in ("LINE_NUMBER", "PART_COUNT"):
            buffer.add_value(item.id, now, rng.randrange(1000))
        elif item.type == "PATH_FEEDRATE_OVERRIDE":
            buffer.add_value(item.id, now, rng.randrange(150))
        else:
            buffer.add_value(item.id, now, f"v{rng.randrange(1000)}")


def _time(
    rounds: int, before: Callable[[], None], run: Callable[[], str]
) -> tuple[list[float], list[float], int]:
    """Wall-clock and CPU milliseconds per call (CPU is what counts on a shared, loaded machine)."""
    wall: list[float] = []
    cpu: list[float] = []
    size = 0
    for _ in range(rounds):
        before()
        start, start_cpu = time.perf_counter(), time.process_time()
        size = len(run())
        cpu.append((time.process_time() - start_cpu) * 1000)
        wall.append((time.perf_counter() - start) * 1000)
    return wall, cpu, size


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--devices", type=int, default=20)
    parser.add_argument("--items", type=int, default=500)
    parser.add_argument("--rounds", type=int, default=50)
    args = parser.parse_args()
    rng = random.Random(17)
    catalog = shop(args.devices, args.items)
    buffer = ObservationBuffer(catalog, instance_id=1)
    stamp = format_timestamp(datetime.now(UTC))
    buffer.add_unavailable(catalog.items, stamp)
    _change(buffer, rng, 1.0)
    info = DocumentInfo("bench", stamp, stamp)

    def current_xml() -> str:
        entries, window = buffer.current()
        return streams_xml(catalog, entries, window, info)

    def current_json() -> str:
        entries, window = buffer.current()
        return streams_json(catalog, entries, window, info)

    axes = PathIndex(catalog).select(parse_path("//Axes"))

    def current_axes() -> str:
        entries, window = buffer.current(axes)
        return streams_xml(catalog, entries, window, info)

    def sample_1000() -> str:
        result = buffer.sample(from_=buffer.next_sequence - 1000, count=1000)
        return streams_xml(catalog, result.entries, result.window, info)

    def at_sequence() -> str:
        entries, window = buffer.current(at=buffer.next_sequence - 20_000)
        return streams_xml(catalog, entries, window, info)

    cold_start = time.process_time()
    cold_size = len(current_xml())
    cold = (time.process_time() - cold_start) * 1000
    print(f"{len(catalog.items)} data items, buffer {len(buffer)} of {buffer.size} observations")
    print(f"/current XML, first (renders every element): CPU {cold:6.1f} ms  {cold_size / 1e6:.2f} MB")
    for name, run in (
        ("/current XML", current_xml),
        ("/current JSON", current_json),
        ("/current?path=//Axes", current_axes),
        ("/sample count=1000", sample_1000),
        ("/current?at=next-20000", at_sequence),
    ):
        wall, cpu, size = _time(args.rounds, lambda: _change(buffer, rng, 0.05), run)
        print(
            f"{name:24s} wall p50 {statistics.median(wall):6.1f} ms  max {max(wall):6.1f} ms"
            f"   CPU p50 {statistics.median(cpu):6.1f} ms  max {max(cpu):6.1f} ms   {size / 1e6:.2f} MB"
        )


if __name__ == "__main__":
    main()
