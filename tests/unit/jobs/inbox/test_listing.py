"""What the inbox sends to clients in listings."""

from __future__ import annotations

import calendar

from gateway.jobs.inbox.listing import Entry, list_line, mdtm, mlsx_facts, split_list_argument

T = calendar.timegm((2026, 3, 4, 5, 6, 7))


def test_list_lines_look_like_ls() -> None:
    assert list_line(Entry("part.nc", False, 1234, T), now=T + 60) == (
        "-rw-r--r-- 1 ftp ftp         1234 Mar  4 05:06 part.nc"
    )
    assert list_line(Entry("tmp", True, 0, T), now=T + 400 * 86400).startswith("drwxr-xr-x 1 ftp ftp")
    assert list_line(Entry("old", False, 1, T), now=T + 400 * 86400).endswith("Mar  4  2026 old")


def test_machine_readable_facts_and_times_are_utc() -> None:
    assert mdtm(T) == "20260304050607"
    assert mlsx_facts(Entry("a.nc", False, 5, T)) == "type=file;size=5;modify=20260304050607; a.nc"


def test_ls_options_are_not_paths() -> None:
    assert split_list_argument("-la /laser") == "/laser"
    assert split_list_argument("-a") == ""
    assert split_list_argument("part 1.nc") == "part 1.nc"
