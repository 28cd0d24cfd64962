"""Every case of tests/corpus/dnc/control.yaml: the drip-feed command folder takes a good request once and
drops (and removes) everything else, without following links."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.transports.dnc.control import control_dir, take_requests

CORPUS = Path(__file__).resolve().parents[3] / "corpus" / "dnc" / "control.yaml"
CASES: list[dict[str, Any]] = yaml.safe_load(CORPUS.read_text(encoding="utf-8"))


@pytest.mark.timeout(30)
@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_control_corpus(tmp_path: Path, case: dict[str, Any]) -> None:
    folder = control_dir(tmp_path / "state")
    folder.mkdir(parents=True)
    path = folder / case["file"]
    if "link" in case:
        outside = tmp_path / "outside.request"
        outside.write_text(case["link"])
        path.symlink_to(outside)
    elif case.get("fifo"):
        os.mkfifo(path)
    elif "hex" in case:
        path.write_bytes(bytes.fromhex(case["hex"]))
    else:
        path.write_text(case["text"])
    if "folder_mode" in case:
        folder.chmod(int(case["folder_mode"], 8))
    if case.get("age"):
        then = time.time() - case["age"]
        os.utime(path, (then, then), follow_symlinks=False)
    taken = take_requests(tmp_path / "state")  # a FIFO read that waited would hang here (the test's timeout)
    expect = case["expect"]
    assert [r.method for r in taken] == ([expect["method"]] if expect["method"] else [])
    assert path.is_symlink() or path.exists() if expect["kept"] else not os.path.lexists(path)
    if "link" in case:
        assert (tmp_path / "outside.request").read_text() == case["link"], "the link's target is untouched"
