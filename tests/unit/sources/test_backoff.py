from itertools import islice

from gateway.sources.backoff import backoff_delays


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
    for delay, base in zip(islice(backoff_delays(1.0, 2.0, 4.0), 50), [1.0, 2.0] + [4.0] * 48):
        assert 0.9 * base <= delay <= base
