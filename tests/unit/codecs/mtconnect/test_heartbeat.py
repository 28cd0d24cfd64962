"""SHDR heartbeats: the agent pings at the adapter's period and gives up after two silent periods."""

from __future__ import annotations

from datetime import UTC, datetime

from gateway.codecs.mtconnect.heartbeat import Action, AdapterHeartbeat, AgentHeartbeat
from gateway.codecs.mtconnect.shdr import PING, Pong, ShdrReader

RECEIVED = datetime(2024, 1, 1, tzinfo=UTC)


def test_the_agent_opens_with_a_ping_and_pings_every_period_once_the_adapter_answered() -> None:
    beat = AgentHeartbeat(now=0.0)
    assert beat.opening() == PING
    beat.on_pong(1000, now=0.1)
    assert beat.period == 1.0
    assert beat.poll(0.5) is Action.NONE
    assert beat.poll(1.0) is Action.SEND_PING
    assert beat.poll(1.5) is Action.NONE  # already pinged for this period
    beat.on_pong(1000, now=1.2)
    assert beat.poll(2.0) is Action.SEND_PING
    assert beat.next_deadline() == 3.0


def test_the_agent_gives_up_after_two_periods_without_a_pong() -> None:
    beat = AgentHeartbeat(now=0.0)
    beat.on_pong(500, now=0.0)
    beat.on_data(now=0.9)  # data is not a PONG
    assert beat.poll(0.99) is not Action.TIMED_OUT
    assert beat.poll(1.0) is Action.TIMED_OUT


def test_an_adapter_without_heartbeats_gets_the_legacy_timeout_of_silence() -> None:
    beat = AgentHeartbeat(now=0.0, legacy_timeout=600.0)
    beat.on_data(now=500.0)
    assert beat.poll(1000.0) is Action.NONE
    assert beat.next_deadline() == 1100.0
    assert beat.poll(1100.0) is Action.TIMED_OUT


def test_the_adapter_answers_with_its_period_and_times_out_a_silent_agent() -> None:
    beat = AdapterHeartbeat(heartbeat_ms=2000)
    assert beat.poll(1e9) is Action.NONE  # never pinged: no timeout
    reply = beat.on_ping(now=10.0)
    assert ShdrReader().feed(reply, RECEIVED) == [Pong(2000)]
    assert beat.poll(13.9) is Action.NONE
    assert beat.poll(14.0) is Action.TIMED_OUT
