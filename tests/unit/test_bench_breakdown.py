"""bench/breakdown.py: py-spy's collapsed stacks sorted into the parts issue 13's note names."""

from __future__ import annotations

from bench.breakdown import CLIENT, JSON, LOOP, PAHO, PARTS, SERVER, SINK, TREE, breakdown, parse_collapsed

LOOP_FRAMES = "_run (asyncio/events.py:80);_run_once (asyncio/base_events.py:1922)"
MQTT = "gateway/sinks/mqtt"
STACKS = [
    (
        f"_drain_latest ({MQTT}/sink.py);_encode ({MQTT}/sink.py);encode_json ({MQTT}/payloads.py:88)",
        5,
    ),
    (f"_writable ({MQTT}/client.py:300);loop_write (paho/mqtt/client.py:2120);send (libc.so.6)", 4),
    (
        f"_writable ({MQTT}/client.py);loop_write (paho/mqtt/client.py);_published ({MQTT}/sink.py:600)",
        1,
    ),
    ("data_received (asyncua/client/ua_client.py:80);decode (asyncua/ua/ua_binary.py:500)", 6),
    (
        "_process (gateway/sources/opcua/client.py);ingest (gateway/model/tree.py);set (asyncio/locks.py:1)",
        3,
    ),
    ("_push (gateway/sinks/opcua/server.py:340);pack (asyncua/ua/ua_binary.py:300)", 2),
    ("process (asyncua/server/uaprocessor.py:100);to_binary (asyncua/ua/ua_binary.py:200)", 1),
    ("select (selectors.py:468);epoll_wait (libc.so.6)", 50),
    ("", 2),
]
PARKED = (
    "thread_run (libpython3.11.so);Queue.get (queue.py:171);PyThread_acquire_lock_timed (libpython3.11.so)"
)
TEXT = "\n".join(f"{LOOP_FRAMES}{';' + s if s else ''} {n}" for s, n in STACKS) + f"\n{PARKED} 40\n"


def test_each_sample_goes_to_its_innermost_known_part_and_waits_are_left_out() -> None:
    stacks = parse_collapsed(TEXT)
    assert sum(n for _, n in stacks) == 114
    parts = breakdown(stacks)
    assert list(parts) == list(PARTS)
    working = 24  # the selector's wait and the parked thread are not CPU
    assert parts[JSON] == round(100 * 5 / working, 1)
    assert parts[PAHO] == round(100 * 4 / working, 1)
    assert parts[SINK] == round(100 * 1 / working, 1)  # the sink's callback, called by paho
    assert parts[CLIENT] == round(100 * 6 / working, 1)
    assert parts[TREE] == round(100 * 3 / working, 1)  # Event.set in the hub counts for the hub
    assert parts[SERVER] == round(100 * 3 / working, 1)  # asyncua's encoding, called by the server
    assert parts[LOOP] == round(100 * 2 / working, 1)
    assert round(sum(parts.values())) == 100


def test_lines_that_are_not_stacks_are_skipped() -> None:
    assert parse_collapsed("\nnot a stack\nframe (x.py:1) 3\n") == [(["frame (x.py:1)"], 3)]
