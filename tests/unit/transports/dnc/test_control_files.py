"""The drip-feed command folder's files are never written through a link, and nothing is taken from a folder
that is not the gateway's own (issue 23, item 10: a link planted at the reply's temporary name made the
gateway's reply overwrite the link's target)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from gateway.transports.dnc import control
from gateway.transports.dnc.control import (
    ControlReply,
    answer,
    control_dir,
    folder_problem,
    make_control_dir,
    take_requests,
    write_new,
)

ID = "0123456789abcdef0123456789abcdef"
VICTIM = b"the gateway's own file: must not change\n"


def request(state: Path, method: str = "DripPause") -> Path:
    folder = make_control_dir(state)
    path = folder / f"lathe.{ID}.request"
    path.write_text(json.dumps({"method": method}))
    return path


def test_a_link_planted_at_the_replys_old_temporary_name_is_not_followed(tmp_path: Path) -> None:
    state = tmp_path / "state"
    request(state)
    victim = tmp_path / "queue.sqlite3"
    victim.write_bytes(VICTIM)
    folder = control_dir(state)
    # Both names a watcher of the folder can predict once the request is there: the temporary name the
    # reply was written through before (`.reply-tmp`), and the reply itself.
    (folder / f"lathe.{ID}.reply-tmp").symlink_to(victim)
    [taken] = take_requests(state)
    answer(taken, ControlReply("Good", "part.nc paused"))
    assert victim.read_bytes() == VICTIM
    reply = folder / f"lathe.{ID}.reply"
    assert not reply.is_symlink()
    assert json.loads(reply.read_text()) == {"status": "Good", "text": "part.nc paused"}


def test_a_link_planted_at_the_reply_itself_is_replaced_not_followed(tmp_path: Path) -> None:
    state = tmp_path / "state"
    request(state)
    victim = tmp_path / "victim"
    victim.write_bytes(VICTIM)
    (control_dir(state) / f"lathe.{ID}.reply").symlink_to(victim)
    [taken] = take_requests(state)
    answer(taken, ControlReply("BadInvalidState", "nothing is being sent"))
    assert victim.read_bytes() == VICTIM
    assert json.loads((control_dir(state) / f"lathe.{ID}.reply").read_text())["status"] == "BadInvalidState"


def test_write_new_creates_its_temporary_file_exclusively_without_following_links(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    victim = tmp_path / "victim"
    victim.write_bytes(VICTIM)
    monkeypatch.setattr(control.secrets, "token_hex", lambda n: "f" * (2 * n))  # a name known beforehand
    final = tmp_path / "x.reply"
    (tmp_path / f".x.reply.{'f' * 16}.tmp").symlink_to(victim)
    with pytest.raises(FileExistsError):
        write_new(final, "{}")
    assert victim.read_bytes() == VICTIM and not final.exists()


def test_a_folder_every_user_may_write_is_refused_and_left_alone(tmp_path: Path) -> None:
    state = tmp_path / "state"
    path = request(state)
    control_dir(state).chmod(0o777)
    problem = folder_problem(state)
    assert problem is not None and "every user may write" in problem and "mode 0777" in problem
    assert "chmod o-w" in problem
    assert take_requests(state) == [] and path.exists()
    control_dir(state).chmod(0o750)
    assert folder_problem(state) is None
    assert [r.method for r in take_requests(state)] == ["DripPause"]


def test_a_folder_that_is_a_link_is_refused(tmp_path: Path) -> None:
    state = tmp_path / "state"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / f"lathe.{ID}.request").write_text('{"method": "DripAbort"}')
    control_dir(state).parent.mkdir(parents=True)
    control_dir(state).symlink_to(elsewhere)
    problem = folder_problem(state)
    assert problem is not None and "is a symbolic link" in problem
    assert take_requests(state) == [] and (elsewhere / f"lathe.{ID}.request").exists()


@pytest.mark.skipif(
    not hasattr(os, "geteuid") or os.geteuid() != 0, reason="chown to another user needs root"
)
def test_a_folder_of_another_user_is_refused(tmp_path: Path) -> None:
    state = tmp_path / "state"
    path = request(state)
    os.chown(control_dir(state), 65534, -1)
    problem = folder_problem(state)
    assert problem is not None and "not to the gateway's user" in problem and "chown" in problem
    assert take_requests(state) == [] and path.exists()


def test_the_gateway_makes_the_folder_without_write_for_every_user(tmp_path: Path) -> None:
    old = os.umask(0)  # a service started with no umask at all
    try:
        folder = make_control_dir(tmp_path / "state")
    finally:
        os.umask(old)
    assert folder.stat().st_mode & 0o777 == 0o770 and folder_problem(tmp_path / "state") is None
