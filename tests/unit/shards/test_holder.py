"""LeaseHolder: the fence a side effect gets, and when its own clock makes it withhold one."""

from __future__ import annotations

from gateway.shards.holder import LeaseHolder


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


async def test_a_fence_only_while_the_last_renewal_is_recent_enough(postgres_url: str) -> None:
    clock = Clock()
    holder = LeaseHolder(postgres_url, "gw-a", ["laser", "press"], lease_time=10.0, margin=2.0, clock=clock)
    async with holder:
        assert holder.held() == ["laser", "press"]
        fence = holder.fence("laser")
        assert fence is not None and fence.machine == "laser"
        assert holder.fence("punch") is None  # not a machine of its fleet
        clock.now += 7.9  # within lease_time - margin of the renewal
        assert holder.fence("laser") == fence
        clock.now += 0.2  # past it: paused, or cut off from the database, as far as it can tell
        assert holder.fence("laser") is None and holder.held() == []
        await holder.step()  # renewed: the same lease, the same token
        assert holder.fence("laser") == fence
    async with LeaseHolder(postgres_url, "gw-b", ["laser"], lease_time=10.0) as other:
        taken = other.fence("laser")  # the clean stop released it: taken at once
        assert taken is not None and taken.token > fence.token


async def test_the_holder_wakes_when_a_renewal_stops_being_trusted_and_not_again_after(
    postgres_url: str,
) -> None:
    clock = Clock()
    async with LeaseHolder(
        postgres_url, "gw-c", ["laser"], lease_time=10.0, margin=2.0, clock=clock
    ) as holder:
        assert abs(holder._until_doubt() - 8.01) < 1e-9  # the renewal is trusted 8 s: wake then, and tell
        clock.now += 5.0
        assert abs(holder._until_doubt() - 3.01) < 1e-9
        clock.now += 4.0  # past it (the table out of reach, say): told already; the next wake is a round's
        assert holder.fence("laser") is None
        assert holder._until_doubt() > 1.0
