"""bench/delivery.py: the QoS 1 subscriber's verdict that issue 28's rows and the QoS 1 drill rest on."""

from __future__ import annotations

from bench.delivery import DeliveryCheck, value_of

TOPICS = ["t/a", "t/b"]  # variable 0 gets 1, 3, 5, …; variable 1 gets 2, 4, 6, …


def payload(value: int, ts: str = "2026-11-28T12:00:00.000Z") -> bytes:
    return f'{{"value":{float(value)!r},"ts":"{ts}","quality":"good"}}'.encode()


def fed(*messages: tuple[str, bytes, bool]) -> DeliveryCheck:
    check = DeliveryCheck()
    for topic, data, dup in messages:
        check.feed(topic, data, dup)
    return check


def test_value_of_reads_the_sequence_number_from_the_gateway_json() -> None:
    assert value_of(payload(42)) == 42
    assert value_of(b'{"value":7.0}') == 7
    assert value_of(b'{"quality":"bad"}') is None


def test_every_change_once_in_order_passes() -> None:
    check = fed(*[(TOPICS[(v - 1) % 2], payload(v), False) for v in range(1, 7)])
    verdict = check.verdict(TOPICS, written=6)
    assert verdict.ok and verdict.written == 6 and verdict.distinct == 6 and verdict.missing == 0


def test_a_change_that_never_came_is_missing_and_named() -> None:
    check = fed(("t/a", payload(1), False), ("t/b", payload(2), False), ("t/a", payload(5), False))
    verdict = check.verdict(TOPICS, written=5)
    assert not verdict.ok
    assert verdict.missing == 2  # 3 on t/a, 4 on t/b
    assert verdict.first_missing == [("t/a", 3), ("t/b", 4)]


def test_a_byte_identical_repeat_is_a_redelivery_split_by_who_resent_it() -> None:
    check = fed(
        ("t/a", payload(1), False),
        ("t/a", payload(3), False),
        ("t/a", payload(1), True),  # the broker's re-send: DUP set
        ("t/a", payload(3), False),  # the publisher's re-send, forwarded as a new message
        ("t/b", payload(2), False),
    )
    verdict = check.verdict(TOPICS, written=3)
    assert verdict.ok
    assert verdict.redelivered == 2 and verdict.redelivered_dup == 1 and verdict.out_of_order == 0


def test_the_same_change_in_other_bytes_is_a_duplicate() -> None:
    check = fed(("t/a", payload(1), False), ("t/a", payload(1, ts="2026-11-28T12:00:01.000Z"), False))
    verdict = check.verdict(["t/a"], written=1)
    assert not verdict.ok and verdict.duplicates == 1 and verdict.redelivered == 0


def test_a_change_after_a_later_one_of_its_topic_is_out_of_order() -> None:
    check = fed(("t/a", payload(3), False), ("t/a", payload(1), False), ("t/b", payload(2), False))
    verdict = check.verdict(TOPICS, written=3)
    assert not verdict.ok and verdict.out_of_order == 1 and verdict.missing == 0


def test_a_value_the_source_never_wrote_on_that_topic_is_unexpected() -> None:
    check = fed(("t/a", payload(2), False), ("t/z", payload(1), False))
    verdict = check.verdict(TOPICS, written=2)
    assert not verdict.ok and verdict.unexpected == 2  # 2 belongs to t/b; t/z is no variable's
