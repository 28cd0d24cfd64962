from __future__ import annotations

from gateway.auth.ratelimit import LoginLimiter


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_failures_within_the_window_lock_the_address_out_for_the_duration() -> None:
    clock = Clock()
    limiter = LoginLimiter(failures=3, window=60, lockout=300, clock=clock)
    assert not limiter.failed("10.0.0.5") and not limiter.failed("10.0.0.5")
    assert limiter.locked("10.0.0.5") == 0.0
    assert limiter.failed("10.0.0.5")  # the third within a minute
    assert limiter.locked("10.0.0.5") == 300.0
    assert limiter.locked("10.0.0.6") == 0.0  # per address
    clock.now += 299
    assert limiter.locked("10.0.0.5") == 1.0
    clock.now += 1
    assert limiter.locked("10.0.0.5") == 0.0
    assert not limiter.failed("10.0.0.5")  # the count started again after the lockout


def test_failures_older_than_the_window_are_forgotten() -> None:
    clock = Clock()
    limiter = LoginLimiter(failures=3, window=60, lockout=300, clock=clock)
    limiter.failed("a")
    limiter.failed("a")
    clock.now += 61
    assert not limiter.failed("a")
    assert limiter.recent_failures("a") == 1 and limiter.locked("a") == 0.0


def test_memory_is_bounded_by_the_number_of_addresses() -> None:
    limiter = LoginLimiter(failures=2, window=60, lockout=300, clock=Clock(), max_addresses=100)
    for i in range(1000):
        limiter.failed(f"10.0.{i // 256}.{i % 256}")
    assert len(limiter._records) == 100
    assert limiter.recent_failures("10.0.3.231") == 1  # the newest are kept
    assert limiter.recent_failures("10.0.0.0") == 0
