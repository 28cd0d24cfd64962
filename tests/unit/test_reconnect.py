"""gateway/reconnect.py: backoff delays with jitter, and an outage said once, quietly while it lasts."""

from __future__ import annotations

import logging
from itertools import islice, pairwise

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.reconnect import Backoff, OutageLog, backoff_delays

LOG = logging.getLogger("tests.reconnect")


def test_delays_grow_by_the_factor_up_to_the_maximum() -> None:
    delays = list(islice(backoff_delays(0.5, 2.0, 10.0, rand=lambda: 0.0), 8))
    assert delays == [0.5, 1.0, 2.0, 4.0, 8.0, 10.0, 10.0, 10.0]


def test_factor_one_keeps_a_constant_delay() -> None:
    assert list(islice(backoff_delays(3.0, 1.0, 10.0, rand=lambda: 0.0), 3)) == [3.0, 3.0, 3.0]


def test_initial_above_maximum_is_capped() -> None:
    assert next(backoff_delays(5.0, 2.0, 1.0, rand=lambda: 0.0)) == 1.0


def test_jitter_only_shortens_and_by_at_most_its_share() -> None:
    delays = list(islice(backoff_delays(1.0, 2.0, 4.0, jitter=0.1, rand=lambda: 1.0), 4))
    assert delays == [0.9, 1.8, 3.6, 3.6]
    for delay, base in zip(islice(backoff_delays(1.0, 2.0, 4.0), 50), [1.0, 2.0] + [4.0] * 48, strict=True):
        assert 0.9 * base <= delay <= base


positive = st.floats(min_value=1e-3, max_value=1e4, allow_nan=False, allow_infinity=False)


@given(
    initial=positive,
    factor=st.floats(min_value=1.0, max_value=10.0),
    maximum=positive,
    jitter=st.floats(min_value=0.0, max_value=1.0),
    rands=st.lists(st.floats(min_value=0.0, max_value=1.0, exclude_max=True), min_size=1, max_size=40),
)
def test_every_delay_lies_under_its_unjittered_base_which_never_shrinks_nor_passes_the_maximum(
    initial: float, factor: float, maximum: float, jitter: float, rands: list[float]
) -> None:
    draws = iter(rands)
    stream = backoff_delays(initial, factor, maximum, jitter=jitter, rand=lambda: next(draws))
    delays = list(islice(stream, len(rands)))
    base = min(initial, maximum)
    for delay, r in zip(delays, rands, strict=True):
        assert delay == pytest.approx(base * (1.0 - jitter * r))
        assert base * (1.0 - jitter) - 1e-9 <= delay <= base <= maximum
        base = min(base * factor, maximum)


@given(initial=positive, factor=st.floats(min_value=1.0, max_value=10.0), maximum=positive)
def test_without_jitter_the_delays_never_shrink_and_reach_the_maximum(
    initial: float, factor: float, maximum: float
) -> None:
    delays = list(islice(backoff_delays(initial, factor, maximum, rand=lambda: 0.0), 200))
    assert all(a <= b for a, b in pairwise(delays))
    assert max(delays) <= maximum
    if factor >= 1.1:
        assert delays[-1] == maximum


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_backoff_starts_over_after_a_connection_that_held_and_not_after_a_short_one() -> None:
    clock = Clock()
    backoff = Backoff(1.0, 2.0, 8.0, stable_after=10.0, rand=lambda: 0.0, clock=clock)
    assert [backoff.next() for _ in range(3)] == [1.0, 2.0, 4.0]
    backoff.connected()
    clock.now += 9.9  # dropped at once: a broker refusing our client id must not be hammered
    assert backoff.ended() is False and backoff.next() == 8.0
    backoff.connected()
    clock.now += 10.0
    assert backoff.ended() is True and backoff.next() == 1.0
    assert backoff.last_delay == 1.0
    backoff.next()
    backoff.reset()
    assert backoff.next() == 1.0


def test_backoff_without_stable_after_only_starts_over_when_reset() -> None:
    clock = Clock()
    backoff = Backoff(1.0, 2.0, 8.0, rand=lambda: 0.0, clock=clock)
    backoff.next()
    backoff.connected()
    clock.now += 1e6
    assert backoff.ended() is False and backoff.next() == 2.0
    assert backoff.ended() is False  # never connected


def test_backoff_of_a_config_section() -> None:
    from gateway.settings.base import Backoff as BackoffConfig

    backoff = Backoff.of(BackoffConfig(initial=0.25, max=1.0, factor=3.0), stable_after=5.0)
    assert (backoff.initial, backoff.factor, backoff.maximum, backoff.stable_after) == (0.25, 3.0, 1.0, 5.0)


def lines(caplog: pytest.LogCaptureFixture) -> list[tuple[int, str]]:
    return [(r.levelno, r.getMessage()) for r in caplog.records if r.name == LOG.name]


def test_an_outage_is_said_once_then_quietly_and_its_end_once(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger=LOG.name)
    outage = OutageLog(LOG)
    assert outage.failed("connection refused", "cannot connect to %s: %s", "plc", "connection refused")
    for _ in range(5):
        said = outage.failed("connection refused", "cannot connect to %s: %s", "plc", "connection refused")
        assert not said
    assert outage.down and outage.failures == 6 and outage.quiet == 5
    outage.recovered("connected to %s", "plc")
    assert not outage.down and outage.reason == ""
    assert lines(caplog) == [
        (logging.WARNING, "cannot connect to plc: connection refused"),
        *[(logging.DEBUG, "cannot connect to plc: connection refused")] * 5,
        (logging.INFO, "connected to plc (after 6 failed attempts)"),
    ]


def test_a_new_reason_is_said_again_at_the_callers_level(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger=LOG.name)
    outage = OutageLog(LOG)
    outage.failed("refused", "down: %s", "refused", level=logging.ERROR)
    outage.failed("refused", "down: %s", "refused", level=logging.ERROR)
    assert outage.failed("timed out", "down: %s", "timed out", level=logging.ERROR)
    assert [level for level, _ in lines(caplog)] == [logging.ERROR, logging.DEBUG, logging.ERROR]


def test_a_traceback_goes_only_with_the_loud_line(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger=LOG.name)
    outage = OutageLog(LOG)
    error = RuntimeError("boom")
    outage.failed("boom", "failed: %s", "boom", level=logging.ERROR, exc_info=error)
    outage.failed("boom", "failed: %s", "boom", level=logging.ERROR, exc_info=error)
    records = [r for r in caplog.records if r.name == LOG.name]
    assert records[0].exc_info is not None and records[0].exc_info[1] is error
    assert records[1].levelno == logging.DEBUG and not records[1].exc_info


def test_a_long_outage_is_recalled_every_so_often(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger=LOG.name)
    clock = Clock()
    outage = OutageLog(LOG, remind_every=60.0, clock=clock)
    said = []
    for _ in range(13):  # one attempt every 10 s for two minutes
        said.append(outage.failed("refused", "broker: refused"))
        clock.now += 10.0
    assert said == [True] + [False] * 5 + [True] + [False] * 5 + [True]


def test_a_recovery_without_failures_is_said_plainly_and_clear_says_nothing(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.DEBUG, logger=LOG.name)
    outage = OutageLog(LOG)
    outage.recovered("connected to %s", "plc")
    outage.failed("refused", "refused once")
    outage.recovered("connected again")
    outage.failed("refused", "refused")
    outage.clear()
    assert lines(caplog) == [
        (logging.INFO, "connected to plc"),
        (logging.WARNING, "refused once"),
        (logging.INFO, "connected again (after 1 failed attempt)"),
        (logging.WARNING, "refused"),
    ]
    assert outage.failed("refused", "refused after clear")  # a new outage is said again
