"""Did a QoS 1 subscriber get every change once and in order? Checked against what the source wrote.

The in-process source (bench/agents/injector.py) writes the sequence numbers 1, 2, 3 … round robin
over its N variables, so variable i (0-based, in the order of its node list) gets i+1, i+1+N, … and
the values on one topic must rise. What arrives is folded as MQTT's QoS 1 allows:

- a message whose bytes equal an earlier one of its topic (same value, same source timestamp) is a
  retransmission (`redelivered`): at-least-once allows it, around a broker restart. Those the broker
  re-sent to the subscriber carry MQTT's DUP flag (`redelivered_dup`); the rest are the publisher's
  re-sends, which the broker forwards as new messages;
- a message with an earlier one's value but other bytes is a second distinct message for one change
  (`duplicates`): never allowed;
- a new value lower than the highest seen on its topic arrived late (`out_of_order`);
- a value the source wrote that never arrived is `missing`.

Used by the bench's subscriber agent (bench/agents/mqtt_sub.py `--check`) for issue 28's QoS 1 row
and by the broker-restart drill at QoS 1 (tests/integration/drills/test_broker_restarts_qos1.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

VALUE_KEY = b'"value":'


def value_of(payload: bytes) -> int | None:
    """The sequence number in the gateway's JSON payload (`{"value":123.0,…}`), or None."""
    start = payload.find(VALUE_KEY)
    if start < 0:
        return None
    start += len(VALUE_KEY)
    end = payload.find(b",", start)
    if end < 0:
        end = payload.find(b"}", start)
    try:
        return int(float(payload[start:end]))
    except ValueError:
        return None


@dataclass
class Verdict:
    """The counts of one check; `ok` when nothing was missing, doubled or out of order."""

    written: int = 0  # changes the source wrote to the checked topics
    distinct: int = 0  # different changes received (each counted once)
    missing: int = 0
    out_of_order: int = 0
    duplicates: int = 0
    redelivered: int = 0
    redelivered_dup: int = 0  # of those, re-sent by the broker (DUP set); the rest: by the publisher
    unexpected: int = 0  # values the source never wrote on that topic
    unparsed: int = 0
    first_missing: list[tuple[str, int]] | None = None  # a few examples, for the report

    @property
    def ok(self) -> bool:
        return not (self.missing or self.out_of_order or self.duplicates or self.unexpected or self.unparsed)

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "passed": self.ok}


class DeliveryCheck:
    """Fed every message as it arrives; `verdict()` compares with what the source wrote."""

    def __init__(self) -> None:
        self._seen: dict[str, dict[int, int]] = {}  # topic -> value -> hash of the payload
        self._top: dict[str, int] = {}  # topic -> highest value so far
        self.distinct = 0
        self.out_of_order = 0
        self.duplicates = 0
        self.redelivered = 0
        self.redelivered_dup = 0
        self.unparsed = 0

    def feed(self, topic: str, payload: bytes, dup: bool = False) -> None:
        value = value_of(payload)
        if value is None:
            self.unparsed += 1
            return
        seen = self._seen.get(topic)
        if seen is None:
            seen = self._seen[topic] = {}
        digest = hash(payload)
        prior = seen.get(value)
        if prior is not None:
            if prior == digest:
                self.redelivered += 1
                self.redelivered_dup += dup
            else:
                self.duplicates += 1
            return
        seen[value] = digest
        self.distinct += 1
        top = self._top.get(topic)
        if top is not None and value < top:
            self.out_of_order += 1
        else:
            self._top[topic] = value

    def verdict(self, topics: Sequence[str], written: int) -> Verdict:
        """`topics[i]` is the topic of the source's variable i; `written` its count of changes."""
        n = len(topics)
        out = Verdict(
            distinct=self.distinct,
            out_of_order=self.out_of_order,
            duplicates=self.duplicates,
            redelivered=self.redelivered,
            redelivered_dup=self.redelivered_dup,
            unparsed=self.unparsed,
        )
        examples: list[tuple[str, int]] = []
        known = set(topics)
        for i, topic in enumerate(topics):
            want = range(i + 1, written + 1, n)
            out.written += len(want)
            seen = self._seen.get(topic, {})
            got = sum(1 for v in seen if v <= written and (v - 1) % n == i)
            out.unexpected += len(seen) - got
            if got < len(want):
                out.missing += len(want) - got
                if len(examples) < 5:
                    examples.extend((topic, v) for v in want if v not in seen)
        out.unexpected += sum(len(s) for t, s in self._seen.items() if t not in known)
        out.first_missing = examples[:5] or None
        return out
