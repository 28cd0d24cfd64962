"""Failed logins per source address: after too many, that address is turned away for a while.

Pure bookkeeping with an injectable clock, no I/O. A locked-out address is
refused without its password being checked, so guessing costs the attacker a
cooling period per `failures` attempts, and the gateway no scrypt work at all.
Memory is bounded: at most `max_addresses` addresses are tracked; the stalest
go first.
"""

from __future__ import annotations

import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field

MAX_ADDRESSES = 10_000


@dataclass
class _Record:
    failures: deque[float] = field(default_factory=deque)
    locked_until: float = 0.0


class LoginLimiter:
    def __init__(
        self,
        failures: int = 5,
        window: float = 60.0,
        lockout: float = 300.0,
        *,
        clock: Callable[[], float] = time.monotonic,
        max_addresses: int = MAX_ADDRESSES,
    ) -> None:
        self.failures = failures
        self.window = window
        self.lockout = lockout
        self._clock = clock
        self._max = max_addresses
        self._records: OrderedDict[str, _Record] = OrderedDict()

    def locked(self, address: str) -> float:
        """Seconds until `address` may try again (0.0: it may try now)."""
        record = self._records.get(address)
        if record is None:
            return 0.0
        remaining = record.locked_until - self._clock()
        return remaining if remaining > 0 else 0.0

    def failed(self, address: str) -> bool:
        """Count one failure; True when this failure locks the address out."""
        now = self._clock()
        record = self._records.get(address)
        if record is None:
            record = self._records[address] = _Record()
            while len(self._records) > self._max:
                self._records.popitem(last=False)
        else:
            self._records.move_to_end(address)
        recent = record.failures
        recent.append(now)
        while recent and recent[0] <= now - self.window:
            recent.popleft()
        if len(recent) >= self.failures:
            recent.clear()
            record.locked_until = now + self.lockout
            return True
        return False

    def recent_failures(self, address: str) -> int:
        record = self._records.get(address)
        if record is None:
            return 0
        now = self._clock()
        return sum(1 for t in record.failures if t > now - self.window)
