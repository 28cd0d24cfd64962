"""The compiled PublishResponse reader (`_publish.c`) gives exactly what asyncua's decoding gives.

Every case decodes the same bytes twice: with the compiled reader, and with asyncua's
`struct_from_binary` reduced by `from_response` (the pure-Python path the source uses where the
reader is not built, forced, or not certain). Where the compiled reader answers, its answer must
equal asyncua's to the type and the bit (a float's bits, bool vs int, a datetime's zone); where
asyncua cannot decode the bytes, the compiled reader must decline (None) and `decode` must raise
asyncua's UaStructParsingError. (By hand: six deliberate breaks of the C reader, from a day off in its
calendar to ByteStrings read as text, each fail these tests; 60,000 mutated responses ran clean under
AddressSanitizer and UBSan.) The bytes are (a) real responses captured from the simulator
(tests/corpus/opcua/publish-responses.bin, made by bench/publish_capture.py) and the hand-made
cases of tests/corpus/opcua/publish.yaml, (b) responses Hypothesis builds with asyncua's own
encoder, (c) junk: arbitrary bytes, and captured responses truncated and with bytes changed.
"""

from __future__ import annotations

import os
import shutil
import struct
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
import yaml
from asyncua import ua
from asyncua.common.utils import Buffer
from asyncua.ua.ua_binary import struct_from_binary, struct_to_binary
from asyncua.ua.uaerrors import UaStructParsingError
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from bench.publish_capture import read_records
from gateway.sources.opcua import publish_decode
from gateway.sources.opcua.publish_decode import Publish, decode, decode_fast, from_response

TYPE_ID = b"\x01\x00\x3d\x03"  # PublishResponse_Encoding_DefaultBinary, a four-byte NodeId
CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "opcua"
CAPTURED = list(read_records(CORPUS / "publish-responses.bin"))
CASES: list[dict[str, Any]] = yaml.safe_load((CORPUS / "publish.yaml").read_text(encoding="utf-8"))

FAST = publish_decode.compiled is not None and not publish_decode.PURE
needs_compiled = pytest.mark.skipif(not FAST, reason="the compiled reader is not built or forced off")


def strict(x: Any) -> Any:
    """A value that compares equal only for the same types and the same bits."""
    if isinstance(x, float):
        return ("float", struct.pack("<d", x))
    if isinstance(x, list | tuple):
        return (type(x).__name__, tuple(strict(i) for i in x))
    if isinstance(x, datetime):
        return (type(x), x.isoformat(), x.tzinfo)
    return (type(x).__name__, x)


def reference(body: bytes) -> Publish | Exception:
    """asyncua's answer: the PublishResponse reduced as the source reduces it, or what it raised."""
    try:
        return from_response(struct_from_binary(ua.PublishResponse, Buffer(body)))
    except Exception as exc:  # noqa: BLE001 - any failure of asyncua's is an answer to compare
        return exc


def both(body: bytes, *, start: int = 0) -> Publish | None:
    """Decode `body` both ways; they must agree. The compiled reader's answer (None: it declined)."""
    data = Buffer(b"\x00" * start + body, start)  # a body not at the start of its bytes, as on the wire
    fast = decode_fast(data)
    expected = reference(body)
    if isinstance(expected, Exception):
        assert fast is None, f"asyncua fails with {expected!r}, the compiled reader answers {fast!r}"
        with pytest.raises(UaStructParsingError):
            decode(Buffer(body))
        return None
    if fast is not None:
        assert strict(fast) == strict(expected)
    assert strict(decode(Buffer(body))) == strict(expected)
    return fast


def response(
    notifications: list[Any],
    *,
    result: int = 0,
    subscription: int = 1,
    sequence: int = 1,
    available: list[int] | None = None,
    results: list[int] | None = None,
    more: bool = False,
) -> bytes:
    r = ua.PublishResponse()
    r.ResponseHeader.ServiceResult = ua.StatusCode(result)
    r.Parameters.SubscriptionId = subscription
    r.Parameters.AvailableSequenceNumbers = available  # type: ignore[assignment]
    r.Parameters.MoreNotifications = more
    r.Parameters.Results = [ua.StatusCode(c) for c in results] if results is not None else None  # type: ignore[assignment]
    r.Parameters.NotificationMessage.SequenceNumber = sequence
    r.Parameters.NotificationMessage.NotificationData = notifications
    return struct_to_binary(r)


# --- (a) captured from the simulator, and the hand-made corpus -------------------------------------------


def test_the_compiled_reader_is_built_where_a_compiler_is() -> None:
    """`pip install -e .` builds `_publish.c`; a silent fallback would cost the gateway its CPU."""
    compiler = os.environ.get("CI") or shutil.which("cc") or shutil.which("gcc")
    if publish_decode.compiled is None and not compiler:
        pytest.skip("no C compiler here: asyncua decodes every response")
    assert publish_decode.compiled is not None, "sources/opcua/_publish.c was not built: pip install -e ."


def test_the_captured_corpus_is_real() -> None:
    assert len(CAPTURED) > 20
    changes = [c for body in CAPTURED if isinstance(p := reference(body), Publish) for c in p.changes]
    assert len(changes) > 500
    assert {type(c[1]) for c in changes} >= {float, int, str, bool, list}


@pytest.mark.parametrize("index", range(len(CAPTURED)))
def test_every_captured_response_reads_the_same(index: int) -> None:
    fast = both(CAPTURED[index], start=index % 7)
    if FAST:
        assert fast is not None, "the compiled reader declined a plain data-change response"


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_every_corpus_case_reads_the_same(case: dict[str, Any]) -> None:
    body = bytes.fromhex(case["hex"])
    fast = both(body)
    expected = reference(body)
    assert case["asyncua"] == ("error" if isinstance(expected, Exception) else "decodes")
    if FAST:
        assert case["compiled"] == ("declines" if fast is None else "reads")


# --- (b) built by asyncua's encoder ------------------------------------------------------------------------

V = ua.VariantType
EPOCH_MIN = datetime(1601, 1, 1, tzinfo=UTC)
EPOCH_MAX = datetime(9999, 12, 31, 23, 59, 59, tzinfo=UTC)
timestamps = st.datetimes(
    min_value=EPOCH_MIN.replace(tzinfo=None), max_value=EPOCH_MAX.replace(tzinfo=None), timezones=st.just(UTC)
)
#: Raw strings: any bytes, as asyncua reads them (UTF-8 with surrogateescape, so invalid UTF-8 too).
texts = st.one_of(st.text(st.characters(exclude_categories=["Cs"])), st.binary().map(
    lambda b: b.decode("utf-8", "surrogateescape")
))  # fmt: skip
SCALARS: dict[ua.VariantType, st.SearchStrategy[Any]] = {
    V.Boolean: st.booleans(),
    V.SByte: st.integers(-(2**7), 2**7 - 1),
    V.Byte: st.integers(0, 2**8 - 1),
    V.Int16: st.integers(-(2**15), 2**15 - 1),
    V.UInt16: st.integers(0, 2**16 - 1),
    V.Int32: st.integers(-(2**31), 2**31 - 1),
    V.UInt32: st.integers(0, 2**32 - 1),
    V.Int64: st.integers(-(2**63), 2**63 - 1),
    V.UInt64: st.integers(0, 2**64 - 1),
    V.Float: st.floats(width=32),
    V.Double: st.floats(),
    V.String: st.none() | texts,
    V.DateTime: timestamps,
    V.ByteString: st.none() | st.binary(),
}
#: Types the compiled reader leaves to asyncua.
OTHERS: dict[ua.VariantType, st.SearchStrategy[Any]] = {
    V.Guid: st.uuids(),
    V.NodeId: st.integers(0, 2**32 - 1).map(lambda i: ua.NodeId(i, 2)),
    V.StatusCode: st.integers(0, 2**32 - 1).map(ua.StatusCode),
    V.QualifiedName: texts.map(lambda t: ua.QualifiedName(t, 1)),
    V.LocalizedText: texts.map(ua.LocalizedText),
}


@st.composite
def variants(draw: st.DrawFn, types: dict[ua.VariantType, st.SearchStrategy[Any]] = SCALARS) -> ua.Variant:
    vtype = draw(st.sampled_from(sorted(types, key=lambda t: t.value)))
    if draw(st.booleans()):
        return ua.Variant(draw(types[vtype]), vtype)
    if vtype is V.DateTime or types is OTHERS:
        element = types[vtype]
    else:
        element = types[vtype].filter(lambda v: v is not None)
    values = draw(st.none() | st.lists(element, max_size=6))
    return ua.Variant(values, vtype, is_array=True)


@st.composite
def data_values(
    draw: st.DrawFn, values: st.SearchStrategy[ua.Variant | None], drop: bool = True
) -> ua.DataValue:
    codes = st.sampled_from([0, 0x00A80000, 0x40000000, 0x80340000]).map(ua.StatusCode)
    dv = ua.DataValue(
        Value=draw(values),
        StatusCode=draw(st.none() | codes),
        SourceTimestamp=draw(st.none() | timestamps),
        ServerTimestamp=draw(st.none() | timestamps),
        SourcePicoseconds=draw(st.none() | st.integers(0, 2**16 - 1)),
        ServerPicoseconds=draw(st.none() | st.integers(0, 2**16 - 1)),
    )
    if drop and draw(st.integers(0, 9)) == 0:
        dv.Value = None  # no Value on the wire at all (encoding bit 0 clear)
    return dv


def items(
    values: st.SearchStrategy[ua.Variant | None], drop: bool = True
) -> st.SearchStrategy[list[ua.MonitoredItemNotification]]:
    """MonitoredItemNotifications; `drop`: a tenth of them without a Value on the wire."""
    item = st.builds(
        ua.MonitoredItemNotification, ClientHandle=st.integers(0, 2**32 - 1), Value=data_values(values, drop)
    )
    return st.lists(item, max_size=8)


plain_values = st.none() | st.just(ua.Variant()) | variants()
data_changes = st.builds(ua.DataChangeNotification, MonitoredItems=items(plain_values))
headers = st.fixed_dictionaries(
    {
        "result": st.sampled_from([0, 0x80000000, 0x800D0000, 0x00A80000, 2**32 - 1]),
        "subscription": st.integers(0, 2**32 - 1),
        "sequence": st.integers(0, 2**32 - 1),
        "available": st.none() | st.lists(st.integers(0, 2**32 - 1), max_size=4),
        "results": st.none() | st.lists(st.integers(0, 2**32 - 1), max_size=4),
        "more": st.booleans(),
    }
)
SLOW = settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SLOW
@given(notifications=st.none() | st.lists(data_changes, max_size=3), header=headers)
@example(notifications=None, header={})
@example(notifications=[], header={})
def test_data_change_responses_read_the_same_and_take_the_fast_path(
    notifications: list[Any] | None, header: dict[str, Any]
) -> None:
    fast = both(response(notifications, **header))  # type: ignore[arg-type]
    if FAST:
        assert fast is not None, "the compiled reader declined a response of data changes it knows"


other_notifications = st.one_of(
    st.builds(ua.StatusChangeNotification, Status=st.integers(0, 2**32 - 1).map(ua.StatusCode)),
    st.builds(ua.EventNotificationList, Events=st.just([])),
    st.builds(ua.DataChangeNotification, MonitoredItems=items(variants(OTHERS), drop=False).filter(bool)),
    st.builds(
        ua.DataChangeNotification,
        MonitoredItems=items(plain_values),
        DiagnosticInfos=st.lists(st.just(ua.DiagnosticInfo()), min_size=1, max_size=2),
    ),
    # a two-dimensional array (ArrayDimensions on the wire)
    st.builds(
        ua.DataChangeNotification,
        MonitoredItems=items(st.just(ua.Variant([[1, 2], [3, 4]], V.Int32)), drop=False).filter(bool),
    ),
)


@SLOW
@given(
    before=st.lists(data_changes, max_size=2),
    other=other_notifications,
    after=st.lists(data_changes, max_size=2),
    header=headers,
)
def test_other_notifications_go_to_asyncua_and_read_the_same(
    before: list[Any], other: Any, after: list[Any], header: dict[str, Any]
) -> None:
    fast = both(response([*before, other, *after], **header))
    assert fast is None


EDGES = [0, 1, 9, 10, 2650467743990000000 - 1, 2650467743990000000]  # asyncua clamps at the last


@given(epoch=st.integers(-(2**63), 2**63 - 1) | st.sampled_from(EDGES))
@example(epoch=-1)
@settings(max_examples=600)
def test_any_filetime_reads_as_asyncua_reads_it(epoch: int) -> None:
    """Every Int64 a SourceTimestamp can carry, beyond what asyncua's encoder writes (clamped both ends)."""
    dv = ua.DataValue(Value=ua.Variant(1.0), SourceTimestamp=datetime(2024, 1, 1, tzinfo=UTC))
    body = response([ua.DataChangeNotification(MonitoredItems=[ua.MonitoredItemNotification(5, dv)])])
    stamp = struct.pack("<q", ua.datetime_to_win_epoch(dv.SourceTimestamp))
    assert body.count(stamp) == 1
    fast = both(body.replace(stamp, struct.pack("<q", epoch)))
    if FAST:
        assert fast is not None


# --- (c) junk ---------------------------------------------------------------------------------------------


@settings(max_examples=1500, deadline=None)
@given(st.binary(max_size=200))
def test_arbitrary_bytes_never_crash_and_read_the_same(body: bytes) -> None:
    both(body)


@settings(max_examples=500, deadline=None)
@given(
    prefix=st.sampled_from([TYPE_ID, TYPE_ID + bytes(16) + b"\x00\xff\xff\xff\xff\x00\x00\x00"]),
    tail=st.binary(max_size=300),
)
def test_bytes_after_a_valid_start_read_the_same(prefix: bytes, tail: bytes) -> None:
    both(prefix + tail)


@pytest.mark.parametrize("index", [0, 1, len(CAPTURED) // 2, len(CAPTURED) - 1])
def test_every_truncation_of_a_captured_response_reads_the_same(index: int) -> None:
    body = CAPTURED[index]
    for end in range(len(body)):
        assert both(body[:end]) is None  # asyncua reads to the last field: any cut fails there too


@settings(max_examples=800, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    index=st.integers(0, len(CAPTURED) - 1),
    changes=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), min_size=1, max_size=4),
)
def test_captured_responses_with_bytes_changed_read_the_same(
    index: int, changes: list[tuple[int, int]]
) -> None:
    body = bytearray(CAPTURED[index])
    for at, value in changes:
        body[at % len(body)] = value
    assume(bytes(body) != CAPTURED[index])
    both(bytes(body))


@needs_compiled
def test_start_and_size_outside_the_data_are_refused() -> None:
    assert publish_decode.compiled is not None
    for start, size in [(-1, 0), (0, -1), (5, 0), (0, 5), (2, 3)]:
        with pytest.raises(ValueError, match="within the data"):
            publish_decode.compiled.decode(TYPE_ID, start, size)
