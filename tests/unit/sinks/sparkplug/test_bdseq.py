"""The bdSeq store: one number per CONNECT that reaches a broker, written before it goes out."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from gateway.sinks.sparkplug.bdseq import BdSeqStore


def test_numbers_advance_per_established_session_and_survive_a_restart(tmp_path: Path) -> None:
    path = tmp_path / "sparkplug-bdseq"
    store = BdSeqStore(path)
    assert store.candidate() == 0 and path.read_text() == "0\n"  # written before the CONNECT
    assert store.candidate() == 0  # that CONNECT never reached a broker: the same number again
    store.established(0)
    assert store.candidate() == 1 and path.read_text() == "1\n"
    restarted = BdSeqStore(path)  # killed with 1 written (perhaps in use): the next start goes on after it
    assert restarted.candidate() == 2


def test_255_wraps_to_0(tmp_path: Path) -> None:
    path = tmp_path / "sparkplug-bdseq"
    path.write_text("255\n")
    assert BdSeqStore(path).candidate() == 0


@pytest.mark.parametrize("text", ["", "x", "256", "-1"])
def test_a_file_that_holds_no_bdseq_starts_at_0(
    tmp_path: Path, text: str, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "sparkplug-bdseq"
    path.write_text(text)
    with caplog.at_level(logging.WARNING):
        assert BdSeqStore(path).candidate() == 0
    assert "not a bdSeq" in caplog.text


def test_a_directory_it_cannot_write_costs_only_the_memory(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    store = BdSeqStore(tmp_path / "missing" / "sparkplug-bdseq")
    with caplog.at_level(logging.WARNING):
        assert store.candidate() == 0
    store.established(0)
    assert store.candidate() == 1
    assert "cannot write" in caplog.text
