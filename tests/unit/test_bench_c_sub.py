"""bench/agents/c_sub.py's reader: mosquitto_sub's `-F '%t %p'` lines into bench/delivery.py."""

from __future__ import annotations

import io

from bench.agents.c_sub import PROBE, Reader

TOPICS = ["cnc/m/noise/a", "cnc/m/noise/b"]


def line(topic: str, value: int) -> bytes:
    return f'{topic} {{"value":{float(value)!r},"ts":"2026-11-28T12:00:00.000Z","quality":"good"}}\n'.encode()


def test_lines_are_split_at_the_first_space_and_checked() -> None:
    reader = Reader()
    reader.run(io.BytesIO(b"".join(line(TOPICS[(v - 1) % 2], v) for v in range(1, 7))))
    verdict = reader.check.verdict(TOPICS, written=6)
    assert reader.count == 6 and verdict.ok and verdict.distinct == 6


def test_the_readiness_probe_is_not_counted() -> None:
    reader = Reader()
    reader.run(io.BytesIO(f"cnc/m/noise/{PROBE} {{}}\n".encode() + line(TOPICS[0], 1)))
    assert reader.probed.is_set() and reader.count == 1 and reader.check.unparsed == 0


def test_a_line_out_of_order_is_reported() -> None:
    reader = Reader()
    reader.run(io.BytesIO(line(TOPICS[0], 3) + line(TOPICS[0], 1) + line(TOPICS[1], 2)))
    verdict = reader.check.verdict(TOPICS, written=3)
    assert verdict.out_of_order == 1 and not verdict.ok
