"""The names a mapping file gives: machines and the segments of tree paths.

Here rather than in gateway/config/mapping.py because the drivers' `discover` verbs write mapping files
and must name what the loader will accept.
"""

from __future__ import annotations

import re

RESERVED_SEGMENTS = frozenset({"Status", "Jobs", "Commands", "Programs", "Alarms"})
SEGMENT_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")
MACHINE_RE = re.compile(r"^[a-z0-9][a-z0-9_\-]{0,62}$")
