"""A fencing token, as a side effect presents it: the machine and the token of the lease its process holds.

Tokens grow with every new holder of a machine's lease (gateway/shards/leases.py), so a
store that checks one in the transaction of a side effect (the claim of a job) refuses a
process that lost its lease while it was paused, even if it still believes it holds it.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Fence:
    machine: str
    token: int

    def __str__(self) -> str:
        return f"{self.machine}#{self.token}"
