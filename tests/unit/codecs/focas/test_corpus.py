"""tests/corpus/focas/controller.yaml through the codec alone: each `raw` answer is junk, an incomplete
frame, a FocasError, or a frame that does not answer the poll (never another exception)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.codecs.focas.address import parse_address
from gateway.codecs.focas.commands import decode_response
from gateway.codecs.focas.errors import FocasError
from gateway.codecs.focas.frame import Frame, FrameReader, Junk, Kind
from gateway.codecs.focas.plan import make_plan

CORPUS = Path(__file__).resolve().parents[3] / "corpus" / "focas" / "controller.yaml"
RAW = [c for c in yaml.safe_load(CORPUS.read_text(encoding="utf-8")) if "raw" in c]


@pytest.mark.parametrize("case", RAW, ids=lambda c: c["name"])
def test_raw_answers_are_refused_by_the_codec(case: dict[str, Any]) -> None:
    plan = make_plan([parse_address("status.run"), parse_address("#500")])
    reader = FrameReader()
    events = reader.feed(bytes.fromhex(case["raw"].replace(" ", "")))
    if not events:
        assert reader.pending  # truncated: waits for the rest, which never comes
        return
    event = events[0]
    if isinstance(event, Junk):
        return
    assert isinstance(event, Frame)
    if event.kind != Kind.RESPONSE:
        return
    try:
        replies = decode_response(event.payload)
    except FocasError:
        return
    assert len(replies) != len(plan.commands) or not all(
        r.answers(c) for r, c in zip(replies, plan.commands, strict=True)
    )
