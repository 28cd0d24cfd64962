"""Fail when `make install`'s output carries a warning: a new user's first screen shows none.

Usage: make install 2>&1 | tee install.log; python3 .ci/check_install_output.py install.log

pip relays the build backend's warnings (setuptools' `BuildBackendWarning` blocks), its own
deprecations and errors; each is a line naming a warning, a deprecation or an error. One kind is
not the project's and is left out: pip saying that an index location from the machine's pip
configuration does not exist ("WARNING: Location 'file:///…' is ignored: it is neither a file nor a
directory."), which only the machine's configuration can change.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterable

FLAGGED = re.compile(r"warning|deprecat|error|!!", re.IGNORECASE)
NOT_OURS = re.compile(r"^\s*WARNING: Location '[^']+' is ignored: it is neither a file nor a directory\.\s*$")


def warnings_in(lines: Iterable[str]) -> list[str]:
    """The lines of an install's output that report a warning, a deprecation or an error of ours."""
    return [line.rstrip("\n") for line in lines if FLAGGED.search(line) and not NOT_OURS.match(line)]


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(f"usage: {argv[0]} <output of make install>", file=sys.stderr)
        return 2
    with open(argv[1], encoding="utf-8", errors="replace") as log:
        found = warnings_in(log)
    if found:
        print("make install printed warnings (a fresh install must print none):", file=sys.stderr)
        for line in found:
            print(f"  {line}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
