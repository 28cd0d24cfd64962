"""The names a mapping file gives: machines and the segments of tree paths.

Here rather than in gateway/config/mapping.py because the drivers' `discover` verbs write mapping files
and must name what the loader will accept.
"""

from __future__ import annotations

import re

RESERVED_SEGMENTS = frozenset({"Status", "Jobs", "Commands", "Programs", "Alarms"})
SEGMENT_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")
MACHINE_RE = re.compile(r"^[a-z0-9][a-z0-9_\-]{0,62}$")
VARIABLE_PATH_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*(/[A-Za-z0-9_][A-Za-z0-9_.\-]*)*$")


def check_variable_path(path: str) -> str:
    """A mapped variable's path as the `jobs:` settings name it (`Control/Start`); ValueError if not one."""
    if not VARIABLE_PATH_RE.match(path):
        raise ValueError(f"{path!r} is not a variable path such as Control/Start")
    return path
