"""The inbox's path checks: nothing a client sends can point outside its machine folders."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.jobs.inbox.paths import InboxPath, PathRefused, check_file_name, is_temp_name, resolve

MACHINES = {"laser", "plasma"}
SUFFIXES = (".part", ".tmp", ".filepart")


@pytest.mark.parametrize(
    ("cwd", "arg", "expected"),
    [
        ("/", "", InboxPath("root")),
        ("/", "/", InboxPath("root")),
        ("/", "laser", InboxPath("machine", "laser")),
        ("/", "/laser/", InboxPath("machine", "laser")),
        ("/laser", "part.nc", InboxPath("file", "laser", "part.nc")),
        ("/laser", "./part.nc", InboxPath("file", "laser", "part.nc")),
        ("/", "/laser//part.nc", InboxPath("file", "laser", "part.nc")),
        ("/laser", "tmp", InboxPath("tmp", "laser")),
        ("/laser/tmp", "part.nc", InboxPath("file", "laser", "part.nc", in_tmp=True)),
        ("/plasma", "/laser/tmp/x.nc", InboxPath("file", "laser", "x.nc", in_tmp=True)),
    ],
)
def test_paths_inside_the_layout_resolve(cwd: str, arg: str, expected: InboxPath) -> None:
    assert resolve(cwd, arg, MACHINES) == expected


@pytest.mark.parametrize(
    ("cwd", "arg", "fragment"),
    [
        ("/laser", "../plasma/x.nc", "'..'"),
        ("/", "..", "'..'"),
        ("/laser", "/laser/../../etc/passwd", "'..'"),
        ("/laser", "..\\..\\x.nc", "'\\'"),
        ("/laser", "C:/Windows/x.nc", "drive"),
        ("/", "press/x.nc", "no such machine folder"),  # not served
        ("/", "secret", "no such machine folder"),
        ("/laser", "sub/x.nc", "no sub-folders"),
        ("/laser", "tmp/a/b.nc", "no folders inside tmp"),
        ("/laser", "x\x00.nc", "control"),
        ("/laser", "x\r\nDELE y", "control"),
    ],
)
def test_escapes_and_odd_paths_are_refused(cwd: str, arg: str, fragment: str) -> None:
    with pytest.raises(PathRefused) as info:
        resolve(cwd, arg, MACHINES)
    assert fragment in info.value.reason


@pytest.mark.parametrize(
    "name",
    [
        ".hidden.nc",
        "-rf.nc",
        " lead.nc",
        "trail.nc ",
        "end.",
        "CON",
        "nul.nc",
        "COM1.txt",
        "a:b.nc",
        "a*b.nc",
        "a?.nc",
        "tab\t.nc",
        "bell\x07.nc",
        "rtl\u202e.nc",
        "x" * 256,
        "..",
        ".",
    ],
)
def test_odd_file_names_are_refused(name: str) -> None:
    with pytest.raises(PathRefused):
        check_file_name(name)


@pytest.mark.parametrize("name", ["part.nc", "O1234", "sheet 12 (2 mm).nc", "Teil_ä.nc", "a.b.c.NC"])
def test_ordinary_names_pass(name: str) -> None:
    assert check_file_name(name) == name


def test_temporary_names_by_suffix_or_folder() -> None:
    assert is_temp_name("part.nc.part", SUFFIXES) and is_temp_name("PART.NC.TMP", SUFFIXES)
    assert not is_temp_name(".part", SUFFIXES) and not is_temp_name("part.nc", SUFFIXES)
    assert InboxPath("file", "laser", "part.nc", in_tmp=True).is_temporary(SUFFIXES)
    assert not InboxPath("file", "laser", "part.nc").is_temporary(SUFFIXES)
    assert not InboxPath("machine", "laser").is_temporary(SUFFIXES)


@settings(max_examples=300, deadline=None)
@given(
    cwd=st.sampled_from(["/", "/laser", "/laser/tmp", "/plasma"]),
    arg=st.lists(
        st.sampled_from([*list("./\\ab:\x00-_ ~"), "..", "laser", "plasma", "tmp", "etc"]), max_size=12
    ).map("".join),
)
def test_whatever_a_client_sends_stays_inside_the_inbox(cwd: str, arg: str) -> None:
    root = Path("/srv/inbox")
    try:
        place = resolve(cwd, arg, MACHINES)
    except PathRefused:
        return
    real = os.path.normpath(root.joinpath(*place.parts))
    assert real == str(root) or real.startswith(str(root) + os.sep)
    assert all(part not in ("..", ".", "") and "/" not in part for part in place.parts)
    assert place.machine is None or place.machine in MACHINES


def test_a_machine_another_shard_serves_is_refused_saying_so() -> None:
    with pytest.raises(PathRefused, match=r"/press: press is served by another shard.*queue: postgresql://"):
        resolve("/", "/press/part.nc", MACHINES, elsewhere={"press"})
    with pytest.raises(PathRefused, match="/drill: no such machine folder"):
        resolve("/", "/drill/part.nc", MACHINES, elsewhere={"press"})
    assert resolve("/", "/laser/part.nc", MACHINES, elsewhere={"press"}).machine == "laser"
