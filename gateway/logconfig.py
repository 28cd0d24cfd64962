"""Log set-up for the command line: one readable line per event, no library noise."""

from __future__ import annotations

import logging
import sys

NOISY = ("asyncua", "aioftp", "amqtt", "transitions")


def configure(level: str = "info") -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper(), logging.INFO),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%Y-%m-%d %H:%M:%S",
        stream=sys.stderr,
        force=True,
    )
    # Third-party libraries log stack traces for conditions we already report in one line.
    for name in NOISY:
        logging.getLogger(name).setLevel(logging.ERROR if level != "debug" else logging.INFO)
