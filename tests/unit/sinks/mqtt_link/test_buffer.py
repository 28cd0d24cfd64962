"""Store-and-forward: bounds, order, drop counting, retained values kept current, the journal."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.sinks.mqtt_link.buffer import Backlog, Journal, Message


def msg(
    b: Backlog,
    topic: str,
    value: int | str,
    *,
    qos: int = 1,
    retain: bool = False,
    machine: str = "m1",
    latest: bool = False,
) -> Message:
    m = Message(b.next_seq(), topic, str(value).encode(), qos, retain, machine, latest)
    b.put(m)
    return m


def drain(b: Backlog) -> list[tuple[str, bytes]]:
    out = []
    while batch := b.take(3):
        for m in batch:
            out.append((m.topic, m.payload))
            b.done(m)
    return out


def test_every_change_comes_out_in_order() -> None:
    b = Backlog(100)
    for i in range(10):
        msg(b, f"t/{i % 3}", i)
    assert len(b) == 10
    assert [int(p) for _, p in drain(b)] == list(range(10))
    assert not b


def test_over_the_limit_the_oldest_are_dropped_and_counted_per_machine() -> None:
    b = Backlog(5)
    for i in range(8):
        msg(b, "t/a", i, machine="m1" if i < 2 else "m2")
    assert b.counted == 5
    assert b.dropped == {"m1": 2, "m2": 1} and b.dropped_total == 3
    assert [int(p) for _, p in drain(b)] == [3, 4, 5, 6, 7]


def test_a_retained_value_that_would_be_lost_is_set_aside_so_the_broker_ends_up_current() -> None:
    b = Backlog(3)
    msg(b, "state/door", "open", retain=True)  # the only message for this topic
    for i in range(6):
        msg(b, "stream/x", i)
    out = drain(b)
    assert ("state/door", b"open") in out  # not dropped: it is still the newest for its topic
    assert [p for t, p in out if t == "stream/x"] == [b"3", b"4", b"5"]
    assert b.dropped_total == 3


def test_a_set_aside_value_is_superseded_by_a_newer_one() -> None:
    b = Backlog(1)
    msg(b, "state/door", "open", retain=True)
    msg(b, "stream/x", 1)  # pushes the door value aside
    msg(b, "state/door", "closed", retain=True)  # pushes x out, supersedes the set-aside value
    assert [p for t, p in drain(b) if t == "state/door"] == [b"closed"]


def test_latest_only_messages_keep_one_per_topic_outside_the_limit() -> None:
    b = Backlog(2)
    for i in range(50):
        msg(b, f"q0/{i % 5}", i, qos=0, retain=True, latest=True)
    msg(b, "stream", "a")
    msg(b, "stream", "b")
    assert len(b) == 7 and b.counted == 2 and b.dropped_total == 0
    out = drain(b)
    assert sorted(p for t, p in out if t.startswith("q0/")) == [b"45", b"46", b"47", b"48", b"49"]


def test_unacknowledged_messages_go_back_to_the_front() -> None:
    b = Backlog(10)
    for i in range(6):
        msg(b, "t", i)
    taken = b.take(3)
    msg(b, "t", 6)
    b.put_front(taken)
    assert [int(p) for _, p in drain(b)] == list(range(7))


def test_put_front_respects_the_limit_by_dropping_the_oldest() -> None:
    b = Backlog(3)
    first = [msg(b, "t", i) for i in range(3)]
    taken = b.take(3)
    assert taken == first
    for i in range(3, 6):
        msg(b, "t", i)
    b.put_front(taken)
    assert [int(p) for _, p in drain(b)] == [3, 4, 5] and b.dropped_total == 3


@settings(max_examples=150)
@given(st.integers(1, 20), st.lists(st.tuples(st.integers(0, 3), st.booleans()), max_size=60))
def test_bounded_and_ordered_per_topic_whatever_happens(limit: int, ops: list[tuple[int, bool]]) -> None:
    b = Backlog(limit)
    sent: dict[str, list[int]] = {}
    for i, (topic_no, retain) in enumerate(ops):
        topic = f"t/{topic_no}{'r' if retain else ''}"
        msg(b, topic, i, retain=retain)
        sent.setdefault(topic, []).append(i)
        assert b.counted <= limit
    out = drain(b)
    got: dict[str, list[int]] = {}
    for topic, payload in out:
        got.setdefault(topic, []).append(int(payload))
    for topic, values in got.items():
        assert values == sorted(values) and set(values) <= set(sent[topic])
    for topic, values in sent.items():
        if topic.endswith("r"):  # retained: the newest value always arrives
            assert got[topic][-1] == values[-1]
    assert len(out) + b.dropped_total == len(ops)


# --- the journal -------------------------------------------------------------------------------


def test_journal_survives_reopening_in_order(tmp_path: Path) -> None:
    path = tmp_path / "backlog.sqlite3"
    b = Backlog(100, Journal(path))
    for i in range(10):
        msg(b, "t", i, retain=i % 2 == 0)
    b.journal.commit()
    taken = b.take(4)
    for m in taken[:2]:
        b.done(m)  # acknowledged: gone for good; the other two are still unacknowledged
    b.journal.close()

    again = Backlog(100, Journal(path))
    assert [int(p) for _, p in drain(again)] == list(range(2, 10))
    assert again.next_seq() > 10  # new messages sort after the old ones
    again.journal.commit()
    assert again.journal.count() == 0


def test_journal_keeps_set_aside_values_and_drops_what_was_dropped(tmp_path: Path) -> None:
    path = tmp_path / "backlog.sqlite3"
    b = Backlog(2, Journal(path))
    msg(b, "door", "open", retain=True)
    for i in range(4):
        msg(b, "x", i)
    b.journal.close()
    again = Backlog(2, Journal(path))
    assert sorted(drain(again)) == [("door", b"open"), ("x", b"2"), ("x", b"3")]


def test_journal_over_a_smaller_limit_drops_the_oldest(tmp_path: Path) -> None:
    path = tmp_path / "backlog.sqlite3"
    b = Backlog(10, Journal(path))
    for i in range(10):
        msg(b, "x", i)
    b.journal.close()
    again = Backlog(4, Journal(path))
    assert [int(p) for _, p in drain(again)] == [6, 7, 8, 9] and again.dropped_total == 6


def test_a_damaged_journal_is_moved_aside_and_the_backlog_starts_empty(tmp_path: Path) -> None:
    path = tmp_path / "backlog.sqlite3"
    path.write_bytes(b"this is not a database" * 100)
    b = Backlog(10, Journal(path))
    assert len(b) == 0 and not b.journal.broken
    assert (tmp_path / "backlog.sqlite3.damaged").exists()
    msg(b, "x", 1)
    b.journal.commit()
    assert b.journal.count() == 1


def test_an_unusable_journal_turns_itself_off_and_memory_goes_on(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    b = Backlog(10, Journal(blocker / "backlog.sqlite3"))  # parent is a file: cannot create
    assert b.journal.broken
    msg(b, "x", 1)
    b.journal.commit()
    assert drain(b) == [("x", b"1")]


def test_limit_must_be_positive() -> None:
    with pytest.raises(ValueError):
        Backlog(0)
