"""`--since WHEN` of `alarms list` and `audit list`: a point in time from what a person types.

Accepted, in any of those commands:

- a duration back from now: a number and a unit, `90s`, `15m`, `2h`, `1.5d`, `2w`;
- `today`: local midnight;
- an ISO-8601 date or time, `2026-05-06`, `2026-05-06T07:00`, `2026-05-06 07:00:30`: local time, as the
  commands print it, unless it names a zone (`Z`, `+02:00`).
"""

from __future__ import annotations

import argparse
from datetime import datetime

from gateway.codecs.since import parse_since

__all__ = ["HELP", "parse_since", "since_arg"]

HELP = "90s, 15m, 2h, 7d, 2w, today, or an ISO-8601 date/time (local time unless it names a zone: Z, +02:00)"


def since_arg(text: str) -> datetime:
    """`parse_since` as an argparse type: a bad value is a usage error naming the accepted forms."""
    try:
        return parse_since(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
