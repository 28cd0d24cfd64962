"""Text the inbox sends to FTP clients: directory listings, FEAT, MDTM. Pure functions.

LIST uses the Unix `ls -l` form that every client parses; MLSD/MLST use RFC 3659
facts. Times are UTC, as RFC 3659 requires for MLSx and MDTM.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

HALF_A_YEAR = 183 * 24 * 3600
MONTHS = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")

FEATURES = (
    "EPSV",
    "PASV",
    "SIZE",
    "MDTM",
    "MLST type*;size*;modify*;",
    "REST STREAM",
    "UTF8",
)


@dataclass(frozen=True, slots=True)
class Entry:
    name: str
    is_dir: bool
    size: int
    mtime: float  # seconds since the epoch


def list_line(entry: Entry, now: float | None = None) -> str:
    """`-rw-r--r-- 1 ftp ftp 1234 Nov 21 12:00 part.nc` (the year instead of the time when older)."""
    now = time.time() if now is None else now
    t = time.gmtime(entry.mtime)
    if now - HALF_A_YEAR < entry.mtime <= now + 3600:
        when = f"{MONTHS[t.tm_mon - 1]} {t.tm_mday:2d} {t.tm_hour:02d}:{t.tm_min:02d}"
    else:
        when = f"{MONTHS[t.tm_mon - 1]} {t.tm_mday:2d}  {t.tm_year}"
    mode = "drwxr-xr-x" if entry.is_dir else "-rw-r--r--"
    return f"{mode} 1 ftp ftp {entry.size:>12d} {when} {entry.name}"


def mlsx_facts(entry: Entry) -> str:
    kind = "dir" if entry.is_dir else "file"
    return f"type={kind};size={entry.size};modify={mdtm(entry.mtime)}; {entry.name}"


def mdtm(mtime: float) -> str:
    return time.strftime("%Y%m%d%H%M%S", time.gmtime(mtime))


def split_list_argument(rest: str) -> str:
    """`LIST -la /laser-sim` -> '/laser-sim': clients pass ls options that are not paths."""
    words = rest.split(" ")
    while words and words[0].startswith("-"):
        words.pop(0)
    return " ".join(words).strip()
