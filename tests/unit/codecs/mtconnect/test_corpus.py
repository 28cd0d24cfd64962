"""tests/corpus/mtconnect: junk SHDR and bad REST requests, each refused with its reason (see its README)."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.codecs.mtconnect.buffer import ObservationBuffer
from gateway.codecs.mtconnect.errors import RequestError
from gateway.codecs.mtconnect.paths import PathIndex
from gateway.codecs.mtconnect.queries import Request, parse_request, resolve_device, select_items
from gateway.codecs.mtconnect.shdr import ItemKind, Junk, Observation, ShdrReader

from .machines import shop

CORPUS = Path(__file__).resolve().parents[3] / "corpus" / "mtconnect"
NOW = datetime(2024, 5, 1, 12, 0, tzinfo=UTC)
KINDS = {"system": ItemKind.CONDITION, "msg": ItemKind.MESSAGE, "vib": ItemKind.TIME_SERIES}


def cases(name: str) -> list[dict[str, Any]]:
    loaded = yaml.safe_load((CORPUS / name).read_text(encoding="utf-8"))
    assert isinstance(loaded, list) and loaded
    return loaded


@pytest.mark.parametrize("case", cases("shdr.yaml"), ids=lambda c: c["name"])
def test_junk_shdr_is_refused_with_its_reason_and_reading_goes_on(case: dict[str, Any]) -> None:
    data = bytes.fromhex(case["hex"]) if "hex" in case else case["text"].encode("utf-8")
    data += case.get("then", "").encode("utf-8") * case.get("repeat", 1 if "then" in case else 0)
    data += case.get("end", "").encode("utf-8")
    reader = ShdrReader(lambda key: KINDS.get(key, ItemKind.VALUE), max_line=case.get("max_line", 64 * 1024))
    events = []
    for start in range(0, len(data), 4096):
        events += reader.feed(data[start : start + 4096], NOW)
    events += reader.feed(b"|corpus_sentinel|ok\n", NOW)
    junk = [e for e in events if isinstance(e, Junk)]
    assert len(junk) == len(case["junk"]), junk
    for event, fragment in zip(junk, case["junk"], strict=True):
        assert fragment in event.reason
    assert reader.errors == len(case["junk"])
    assert events[-1] == Observation(NOW, "corpus_sentinel", "ok")


CATALOG = shop(2)
INDEX = PathIndex(CATALOG)


def state() -> ObservationBuffer:
    """Sequences 25..40 held of 40 (the README's promise)."""
    buffer = ObservationBuffer(CATALOG, instance_id=99, size=16)
    for n in range(40):
        buffer.add_value("m1_Xpos" if n % 2 else "m2_Xpos", "2024-05-01T12:00:00Z", n)
    assert (buffer.first_sequence, buffer.last_sequence, buffer.next_sequence) == (25, 40, 41)
    return buffer


def answer(target: str, buffer: ObservationBuffer) -> Request:
    """What the agent does with a request before it renders: every check that can refuse it."""
    request = parse_request(target)
    if request.kind in ("current", "sample"):
        items = select_items(request, CATALOG, INDEX)
        if request.kind == "current":
            buffer.current(items, at=request.at)
        else:
            buffer.sample(items, from_=request.from_, count=request.count, to=request.to)
    else:
        resolve_device(CATALOG, request.device)
    return request


@pytest.mark.parametrize("case", cases("requests.yaml"), ids=lambda c: c["name"])
def test_bad_requests_are_refused_with_their_error_code_and_reason(case: dict[str, Any]) -> None:
    target = case["target"] + "x" * case.get("pad", 0)
    with pytest.raises(RequestError) as caught:
        answer(target, state())
    assert caught.value.code.value == case["expect"]["code"]
    assert case["expect"]["error"] in caught.value.message


@pytest.mark.parametrize(
    "target",
    [
        "/",
        "/laser1",
        "/urn:example:laser:2/probe",
        "/current",
        "/laser2/current?at=30&path=//Axes",
        "/sample?from=25&count=16",
        "/sample?from=41&count=5",
        "/laser1/sample?from=30&to=35&count=3&format=json",
        "/sample?count=-16&interval=100&heartbeat=500",
        "/current?path=" + '//DataItem[@type="POSITION"]|//Controller',
        "/assets?type=CuttingTool&removed=true&count=5",
        "/asset/T1;T2",
    ],
)
def test_the_same_checks_let_good_requests_through(target: str) -> None:
    assert answer(target, state()).kind in ("probe", "current", "sample", "assets")


@pytest.mark.parametrize("case", cases("responses.yaml"), ids=lambda c: c["name"])
def test_junk_answers_of_an_agent_are_refused_with_their_reason(case: dict[str, Any]) -> None:
    from gateway.codecs.mtconnect.responses import ResponseError, parse_devices, parse_streams

    parse = parse_streams if case.get("probe") else parse_devices
    try:
        document = parse(case["body"])
    except ResponseError as exc:
        assert case["error"] in str(exc)
        return
    assert case["error"] == "describes no device" and not getattr(document, "devices", [1])
