"""The planner divides the fleet: every machine to one live member, shares within one, little movement."""

from __future__ import annotations

from collections import Counter

from hypothesis import given
from hypothesis import strategies as st

from gateway.shards.planner import assign, plan, shares

names = st.text(alphabet="abcdefgh", min_size=1, max_size=3)
fleets = st.sets(names.map(lambda s: f"m-{s}"), max_size=40)
memberships = st.sets(names.map(lambda s: f"gw-{s}"), min_size=1, max_size=8)


@st.composite
def tables(draw: st.DrawFn) -> tuple[set[str], set[str], dict[str, str]]:
    machines = draw(fleets)
    members = draw(memberships)
    holders = sorted(members | {"gw-dead", "gw-gone"})  # some holders are no members (any more)
    held = {m: draw(st.sampled_from(holders)) for m in machines if draw(st.booleans())}
    return machines, members, held


@given(tables())
def test_every_machine_goes_to_exactly_one_live_member_and_shares_are_within_one(
    table: tuple[set[str], set[str], dict[str, str]],
) -> None:
    machines, members, held = table
    result = assign(machines, members, held)
    assert set(result) == machines  # total coverage (a dict: no machine twice)
    assert set(result.values()) <= members
    load = Counter(result.values())
    counts = [load[m] for m in members]
    assert max(counts) - min(counts) <= 1
    assert sum(counts) == len(machines)


@given(tables())
def test_a_machine_held_within_its_holders_share_stays_put(
    table: tuple[set[str], set[str], dict[str, str]],
) -> None:
    machines, members, held = table
    result = assign(machines, members, held)
    floor = len(machines) // len(members)
    for member in members:
        mine = sorted(m for m, h in held.items() if h == member)
        if len(mine) <= floor:
            assert all(result[m] == member for m in mine)


@given(tables())
def test_the_members_plans_take_each_machine_once_and_add_up_to_the_assignment(
    table: tuple[set[str], set[str], dict[str, str]],
) -> None:
    machines, members, held = table
    plans = {m: plan(m, machines, members, held) for m in members}
    taken = Counter(machine for p in plans.values() for machine in p.take)
    assert set(taken.values()) <= {1}  # no machine taken by two members
    for member, p in plans.items():
        kept = {m for m, h in held.items() if h == member} - set(p.release)
        assert kept.isdisjoint(p.take)
        assert len(kept) + len(p.take) == p.share
    assert sum(p.share for p in plans.values()) == len(machines)


def test_shares_give_the_extra_machines_to_those_that_hold_most() -> None:
    assert shares(10, ["a", "b", "c"]) == {"a": 4, "b": 3, "c": 3}
    assert shares(10, ["a", "b", "c"], {"m1": "c"}) == {"a": 3, "b": 3, "c": 4}
    assert shares(0, ["a"]) == {"a": 0} and shares(5, []) == {}


def test_a_new_member_gets_half_and_the_old_one_releases_it() -> None:
    machines = {f"m{i}" for i in range(4)}
    held = dict.fromkeys(machines, "a")
    old, new = plan("a", machines, ["a", "b"], held), plan("b", machines, ["a", "b"], held)
    assert len(old.release) == 2 and old.take == ()
    assert set(new.take) == set(old.release) and new.share == 2
