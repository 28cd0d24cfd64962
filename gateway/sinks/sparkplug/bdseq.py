"""The birth/death sequence number, kept in `<state_dir>/sparkplug-bdseq` across restarts.

A host matches an NDEATH to the NBIRTH with the same bdSeq. A gateway that restarts at 0 every
time would, after a crash, be born again with the number of the death the broker has yet to
deliver (the will of the killed process), and a host that takes that late death for the new
session shows the gateway offline although it is up. So the number a CONNECT is about to use is
written before the CONNECT goes out, and a restart goes on from it.

A CONNECT that never reached a broker (refused at TCP, no answer) does not use up a number: the
next attempt carries the same one, so that after a broker outage the next NBIRTH has the next
bdSeq. A file that cannot be read or written costs only that memory (a log line), never the start.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from gateway.codecs.sparkplug import BdSeq

log = logging.getLogger(__name__)

FILE = "sparkplug-bdseq"


class BdSeqStore:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.last: int | None = None  # the bdSeq of the last session that was established
        self._written: int | None = None
        try:
            text = path.read_text(encoding="ascii").strip()
        except FileNotFoundError:
            return
        except OSError as exc:
            log.warning("Sparkplug: cannot read %s (%s); bdSeq starts at 0", path, exc.strerror or exc)
            return
        if text.isdigit() and 0 <= int(text) <= 255:
            self.last = self._written = int(text)
        else:
            log.warning("Sparkplug: %s holds %r, not a bdSeq; starting at 0", path, text[:20])

    def candidate(self) -> int:
        """The bdSeq of the next CONNECT's will; written down before it goes out."""
        number = BdSeq(last=self.last).connect()
        if number != self._written:
            self._write(number)
        return number

    def established(self, number: int) -> None:
        """The CONNECT with `number` was accepted: its NBIRTHs carry it; the next CONNECT one more."""
        self.last = number

    def _write(self, number: int) -> None:
        self._written = number
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            with tmp.open("w", encoding="ascii") as out:
                out.write(f"{number}\n")
                out.flush()
                os.fsync(out.fileno())
            tmp.replace(self.path)
        except OSError as exc:
            log.warning(
                "Sparkplug: cannot write %s (%s); a restart may reuse bdSeq %d",
                self.path,
                exc.strerror or exc,
                number,
            )
