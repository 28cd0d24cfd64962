"""What a serial line's owner does with bytes that arrive while no job is sending: `IdleListener`.

The line owner (transport.py, `SerialTransport`) keeps the port open between
transfers. When nothing is being sent it reads the line and hands every byte to
its idle listener: the punch desk (an operator's PUNCH, a remote request) plugs
in here. A listener that wants something sent back (the answer to a remote
request) returns it; the owner sends it before it listens again, load or drip as
the line's mode says (or always as a load when `answer_load`), naming
`answer_user` in the transfer log.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

# (program, user for the transfer log, send as a load whatever the line's mode): the line sends it later
SendAnswer = Callable[[bytes, str | None, bool], None]


class IdleListener(Protocol):
    """Hears a serial line while no job uses it. Called on the event loop; must not block."""

    answer_user: str | None  # who the transfer log names for the answer `feed` last returned
    answer_load: bool  # send that answer as a load even on a drip line

    def feed(self, data: bytes) -> bytes | None:
        """Bytes read from the port (as the port gave them: with software parity, bit 7 still set).

        Returns a program (plain text, `%` markers optional, LF line ends) to send to the
        controller now, as the answer to a remote request, or None.
        """
        ...

    def line_lost(self, reason: str) -> None:
        """The port closed or failed while listening (the listener drops any half-read program)."""
        ...
