"""The agent's observation buffer: a ring of the last `size` observations, numbered as MTConnect says.

Every observation gets the next sequence number (1, 2, ...). The buffer keeps the
last `size` of them: `first_sequence` is the oldest still held, `last_sequence`
the newest, `next_sequence` the one the next observation will get. `instance_id`
names this numbering: a client that sees it change knows the sequences restarted.

Queries follow the reference agent (cppagent), which is stricter than the standard's text:
- /sample `from` must be in [first_sequence, next_sequence] (`from=next_sequence` is an empty
  answer, the way a client polls); `to` in (from, next_sequence] (without `from`: in
  [first_sequence, next_sequence]), inclusive, and then `count` > 0 (the last `count` up to `to`);
  `count` is non-zero, |count| <= size; a negative count walks backwards from `from`
  (default: the newest). Anything else is OutOfRange naming the parameter.
- /current `at` must be in [first_sequence, last_sequence]; the state at `at` is rebuilt from
  the nearest checkpoint (one every `checkpoint_every` sequences, plus the state just
  before the oldest held observation) rolled forward.

A condition data item can have several active conditions at once (a Fault per
conditionId); /current shows all of them, or the one Normal/Unavailable.

Pure: no clock, no I/O. Timestamps come in as datetimes or preformatted text.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime

from gateway.codecs.mtconnect.errors import OutOfRange, ValueRejected
from gateway.codecs.mtconnect.model import Catalog, ItemInfo
from gateway.codecs.mtconnect.timestamps import format_timestamp
from gateway.codecs.mtconnect.vocabulary import CONDITION_LEVELS, UNAVAILABLE, RawValue, render_value
from gateway.codecs.mtconnect.xmltext import xml_attr, xml_text

DEFAULT_SIZE = 131_072


@dataclass(slots=True, eq=False)
class Entry:
    """One observation in the buffer; `xml` is its element, rendered on first use and kept."""

    sequence: int
    info: ItemInfo
    timestamp: str
    value: str  # the element text: the value, or a condition's message ("" for none)
    level: str = ""  # conditions: Normal, Warning, Fault, Unavailable
    native_code: str | None = None
    native_severity: str | None = None
    qualifier: str | None = None
    condition_id: str | None = None
    sample_count: int | None = None
    sample_rate: float | None = None
    reset_triggered: str | None = None
    duration: float | None = None
    asset_type: str | None = None  # ASSET_CHANGED / ASSET_REMOVED: the schema requires assetType
    xml_cache: str | None = field(default=None, repr=False)  # entry_xml's rendering
    json_cache: str | None = field(default=None, repr=False)  # json_documents.entry_json's rendering

    @property
    def item_id(self) -> str:
        return self.info.item.id

    @property
    def unavailable(self) -> bool:
        return self.level == "Unavailable" if self.info.is_condition else self.value == UNAVAILABLE

    @property
    def element(self) -> str:
        return self.level if self.info.is_condition else self.info.element

    @property
    def xml(self) -> str:
        return self.xml_cache or entry_xml(self)


def entry_xml(e: Entry) -> str:
    """The observation's element, rendered once and kept in `xml_cache`."""
    cached = e.xml_cache
    if cached is not None:
        return cached
    info = e.info
    if (
        not info.is_condition
        and e.sample_count is None
        and e.reset_triggered is None
        and e.duration is None
        and e.asset_type is None
    ):
        value = e.value
        text = e.xml_cache = (
            f'{info.prefix}{e.sequence}" timestamp="{e.timestamp}">{xml_text(value)}</{info.element}>'
            if value
            else f'{info.prefix}{e.sequence}" timestamp="{e.timestamp}"/>'
        )
        return text
    text = e.xml_cache = _render_xml(e)
    return text


def _render_xml(e: Entry) -> str:
    info = e.info
    element = e.level if info.is_condition else info.element
    parts = [f'<{element}{info.attrs} sequence="{e.sequence}" timestamp="{e.timestamp}"']
    if e.native_code is not None:
        parts.append(f' nativeCode="{xml_attr(e.native_code)}"')
    if e.native_severity is not None:
        parts.append(f' nativeSeverity="{xml_attr(e.native_severity)}"')
    if e.qualifier is not None:
        parts.append(f' qualifier="{xml_attr(e.qualifier)}"')
    if e.condition_id is not None:
        parts.append(f' conditionId="{xml_attr(e.condition_id)}"')
    if e.sample_count is not None:
        parts.append(f' sampleCount="{e.sample_count}"')
    if e.sample_rate is not None:
        parts.append(f' sampleRate="{e.sample_rate!r}"')
    if e.reset_triggered is not None:
        parts.append(f' resetTriggered="{xml_attr(e.reset_triggered)}"')
    if e.duration is not None:
        parts.append(f' duration="{e.duration!r}"')
    if e.asset_type is not None:
        parts.append(f' assetType="{xml_attr(e.asset_type)}"')
    text = e.value
    if info.time_series and text == UNAVAILABLE:
        # The 2.4 schema's time series hold a list of floats only: an UNAVAILABLE one is
        # rendered empty, with sampleCount="0".
        text = ""
    if text:
        parts.append(f">{xml_text(text)}</{element}>")
    else:
        parts.append("/>")
    return "".join(parts)


class Checkpoint:
    """The latest observation of every data item (all active conditions for a condition item)."""

    __slots__ = ("conditions", "values")

    def __init__(self) -> None:
        self.values: dict[str, Entry] = {}
        self.conditions: dict[str, tuple[Entry, ...]] = {}

    def copy(self) -> Checkpoint:
        other = Checkpoint()
        other.values = self.values.copy()
        other.conditions = self.conditions.copy()
        return other

    def is_duplicate(self, entry: Entry) -> bool:
        """Would `entry` change nothing? (Discrete items and resets are never duplicates.)"""
        info = entry.info
        if info.is_condition:
            active = self.conditions.get(info.item.id)
            if not active:
                return False
            if entry.level in ("Normal", "Unavailable") and entry.condition_id is None:
                return len(active) == 1 and active[0].level == entry.level
            return any(_same_condition(a, entry) for a in active)
        last = self.values.get(info.item.id)
        if info.item.discrete or entry.reset_triggered is not None:
            return last is not None and last.value == entry.value == UNAVAILABLE
        return last is not None and last.value == entry.value and last.sample_count == entry.sample_count

    def apply(self, entry: Entry) -> None:
        info = entry.info
        item_id = info.item.id
        if not info.is_condition:
            self.values[item_id] = entry
            return
        level = entry.level
        active = self.conditions.get(item_id, ())
        if level == "Unavailable" or (level == "Normal" and entry.condition_id is None):
            self.conditions[item_id] = (entry,)
            return
        kept = tuple(
            a for a in active if a.level in ("Warning", "Fault") and a.condition_id != entry.condition_id
        )
        if level == "Normal":
            self.conditions[item_id] = kept or (entry,)
        else:
            self.conditions[item_id] = (*kept, entry)

    def entries(self, catalog: Catalog, items: frozenset[str] | None = None) -> list[Entry]:
        """The held observations in probe order, only of `items` if given."""
        out: list[Entry] = []
        values = self.values
        conditions = self.conditions
        for item_id, info in catalog.items.items():
            if items is not None and item_id not in items:
                continue
            if info.is_condition:
                out.extend(conditions.get(item_id, ()))
            else:
                entry = values.get(item_id)
                if entry is not None:
                    out.append(entry)
        return out


def _same_condition(a: Entry, b: Entry) -> bool:
    return (
        a.level == b.level
        and a.condition_id == b.condition_id
        and a.native_code == b.native_code
        and a.native_severity == b.native_severity
        and a.qualifier == b.qualifier
        and a.value == b.value
    )


@dataclass(frozen=True, slots=True)
class Window:
    """Sequence numbers of the header of a Streams document."""

    instance_id: int
    buffer_size: int
    first_sequence: int
    last_sequence: int
    next_sequence: int


@dataclass(frozen=True, slots=True)
class SampleResult:
    entries: list[Entry]
    window: Window  # next_sequence is where the client goes on from
    end_of_buffer: bool  # the walk reached the end (forward: the newest; backward: the oldest)


def _stamp(timestamp: datetime | str) -> str:
    return timestamp if isinstance(timestamp, str) else format_timestamp(timestamp)


class ObservationBuffer:
    """Ring buffer of Entries with MTConnect sequence numbers, /current and /sample queries."""

    def __init__(
        self,
        catalog: Catalog,
        *,
        instance_id: int,
        size: int = DEFAULT_SIZE,
        checkpoint_every: int | None = None,
    ) -> None:
        if size < 1:
            raise ValueError("the buffer size must be at least 1")
        if not 1 <= instance_id < 2**64:
            raise ValueError("instanceId must be in [1, 2**64)")
        self.catalog = catalog
        self.instance_id = instance_id
        self.size = size
        self.checkpoint_every = checkpoint_every or max(1, size // 8)
        self._ring: list[Entry | None] = [None] * size
        self._next = 1
        self._floor = 1  # the oldest sequence ever held (above 1 after `restore` or `resume_at`)
        self._latest = Checkpoint()
        self._first = Checkpoint()  # state of everything before first_sequence
        self._checkpoints: list[tuple[int, Checkpoint]] = []  # (sequence covered up to, state)

    # --- the window ---------------------------------------------------------------------------

    @property
    def next_sequence(self) -> int:
        return self._next

    @property
    def last_sequence(self) -> int:
        """The newest sequence held; 0 while the buffer is empty."""
        return self._next - 1

    @property
    def first_sequence(self) -> int:
        return max(self._floor, self._next - self.size)

    def window(self, next_sequence: int | None = None) -> Window:
        return Window(
            self.instance_id,
            self.size,
            self.first_sequence,
            self.last_sequence,
            self._next if next_sequence is None else next_sequence,
        )

    def __len__(self) -> int:
        return self._next - self.first_sequence

    def get(self, sequence: int) -> Entry | None:
        """The observation with this sequence number, if the buffer still holds it."""
        if self.first_sequence <= sequence < self._next:
            return self._ring[(sequence - 1) % self.size]
        return None

    # --- adding ---------------------------------------------------------------------------------

    def add_value(
        self,
        item_id: str,
        timestamp: datetime | str,
        value: RawValue,
        *,
        sample_rate: float | None = None,
        reset_triggered: str | None = None,
        duration: float | None = None,
        asset_type: str | None = None,
        dedupe: bool = True,
    ) -> Entry | None:
        """Add a SAMPLE or EVENT observation; returns it, or None if it repeats the latest value.

        ASSET_CHANGED and ASSET_REMOVED need `asset_type` (UNAVAILABLE ones get "UNAVAILABLE").
        Raises KeyError for an unknown data item and ValueRejected for a value its element cannot hold.
        """
        info = self.catalog.items[item_id]
        if info.is_condition:
            raise ValueRejected(f"{item_id} is a CONDITION: use add_condition")
        text = render_value(info.item.category.value, info.item.type, value, time_series=info.time_series)
        if info.item.type in ("ASSET_CHANGED", "ASSET_REMOVED"):
            if text == UNAVAILABLE:
                asset_type = UNAVAILABLE
            elif not asset_type:
                raise ValueRejected(f"{item_id} ({info.item.type}) needs the asset's type")
        else:
            asset_type = None
        count: int | None = None
        if info.time_series:
            count = 0 if text == UNAVAILABLE else len(text.split())
        entry = Entry(
            0,
            info,
            _stamp(timestamp),
            text,
            sample_count=count,
            sample_rate=sample_rate,
            reset_triggered=reset_triggered,
            duration=duration,
            asset_type=asset_type,
        )
        return self._append(entry, dedupe)

    def add_condition(
        self,
        item_id: str,
        timestamp: datetime | str,
        level: str,
        *,
        native_code: str | None = None,
        native_severity: str | None = None,
        qualifier: str | None = None,
        condition_id: str | None = None,
        text: str = "",
        dedupe: bool = True,
    ) -> Entry | None:
        """Add a CONDITION observation (level NORMAL/WARNING/FAULT/UNAVAILABLE, any case).

        A Warning or Fault needs a conditionId in 2.4: without one, the native code is used,
        else the data item id (one condition per data item).
        """
        info = self.catalog.items[item_id]
        if not info.is_condition:
            raise ValueRejected(f"{item_id} is not a CONDITION")
        element = CONDITION_LEVELS.get(level.upper())
        if element is None:
            raise ValueRejected(
                f"condition level must be NORMAL, WARNING, FAULT or UNAVAILABLE, not {level!r}"
            )
        if qualifier is not None and qualifier not in ("HIGH", "LOW"):
            raise ValueRejected(f"condition qualifier must be HIGH or LOW, not {qualifier!r}")
        if element in ("Warning", "Fault") and condition_id is None:
            condition_id = native_code or item_id
        if element == "Unavailable":
            native_code = native_severity = qualifier = condition_id = None
            text = ""
        entry = Entry(
            0,
            info,
            _stamp(timestamp),
            text,
            level=element,
            native_code=native_code,
            native_severity=native_severity,
            qualifier=qualifier,
            condition_id=condition_id,
        )
        return self._append(entry, dedupe)

    def add_unavailable(self, item_ids: Iterable[str], timestamp: datetime | str) -> list[Entry]:
        """Mark data items UNAVAILABLE (a controller went away); the entries that changed something."""
        stamp = _stamp(timestamp)
        added: list[Entry] = []
        for item_id in item_ids:
            info = self.catalog.items[item_id]
            if info.is_condition:
                entry = self.add_condition(item_id, stamp, "UNAVAILABLE")
            else:
                entry = self.add_value(item_id, stamp, None)
            if entry is not None:
                added.append(entry)
        return added

    def restore(self, entries: Iterable[Entry]) -> None:
        """Refill an empty buffer with observations kept from an earlier run, with their own sequences.

        The first entry's sequence becomes the buffer's starting point; the rest must follow it
        without a gap (what `entries_between` gave, stored in order). Their `info` must come from
        this buffer's catalog. Raises ValueError otherwise (the caller then starts afresh).
        """
        if self._next != 1:
            raise ValueError("restore needs an empty buffer")
        expected: int | None = None
        for entry in entries:
            if expected is None:
                if entry.sequence < 1:
                    raise ValueError(f"sequence {entry.sequence} is not a sequence number")
                self._next = self._floor = expected = entry.sequence
            elif entry.sequence != expected:
                raise ValueError(f"sequence {entry.sequence} follows {expected - 1}: a gap in what was kept")
            if self.catalog.items.get(entry.info.item.id) is not entry.info:
                raise ValueError(f"{entry.info.item.id} is not a data item of this catalog")
            entry.xml_cache = entry.json_cache = None
            self._append(entry, dedupe=False)
            expected += 1

    def resume_at(self, next_sequence: int) -> None:
        """Start an empty buffer's numbering at `next_sequence` (a kept sequence, nothing to restore)."""
        if self._next != 1:
            raise ValueError("resume_at needs an empty buffer")
        if next_sequence < 1:
            raise ValueError("sequences start at 1")
        self._next = self._floor = next_sequence

    def _append(self, entry: Entry, dedupe: bool) -> Entry | None:
        if dedupe and self._latest.is_duplicate(entry):
            return None
        seq = self._next
        entry.sequence = seq
        slot = (seq - 1) % self.size
        old = self._ring[slot]
        if old is not None:
            self._first.apply(old)
        self._ring[slot] = entry
        self._latest.apply(entry)
        self._next = seq + 1
        if seq % self.checkpoint_every == 0:
            self._checkpoints.append((seq, self._latest.copy()))
            first = self.first_sequence
            while self._checkpoints and self._checkpoints[0][0] < first - 1:
                del self._checkpoints[0]
        return entry

    # --- queries --------------------------------------------------------------------------------

    def current(
        self, items: frozenset[str] | None = None, at: int | None = None
    ) -> tuple[list[Entry], Window]:
        """The latest observation of each data item (of `items`), or the state as of sequence `at`.

        With `at`, the window's next_sequence is at + 1: where a client goes on to see what followed.
        """
        if at is None:
            return self._latest.entries(self.catalog, items), self.window()
        first, last = self.first_sequence, self.last_sequence
        if not first <= at <= last:
            raise OutOfRange("at", at, first, last, f"'at' must be in [{first}, {last}]")
        return self._checkpoint_at(at).entries(self.catalog, items), self.window(at + 1)

    def _checkpoint_at(self, at: int) -> Checkpoint:
        first = self.first_sequence
        base_seq, base = first - 1, self._first
        for seq, checkpoint in reversed(self._checkpoints):
            if seq <= at and seq >= first - 1:
                base_seq, base = seq, checkpoint
                break
        state = base.copy()
        ring, size = self._ring, self.size
        for seq in range(base_seq + 1, at + 1):
            entry = ring[(seq - 1) % size]
            assert entry is not None
            state.apply(entry)
        return state

    def sample(
        self,
        items: frozenset[str] | None = None,
        *,
        from_: int | None = None,
        count: int = 100,
        to: int | None = None,
    ) -> SampleResult:
        """Observations by sequence (of `items`), at most |count|; see the module text for the rules."""
        first, nxt, size = self.first_sequence, self._next, self.size
        if from_ is not None and not first <= from_ <= nxt:
            raise OutOfRange("from", from_, first, nxt, f"'from' must be in [{first}, {nxt}]")
        lower_count = -size
        if to is not None:
            low = from_ + 1 if from_ is not None else first
            if not low <= to <= nxt:
                raise OutOfRange("to", to, low, nxt, f"'to' must be in [{low}, {nxt}]")
            lower_count = 1
        if count == 0 or not lower_count <= count <= size:
            raise OutOfRange(
                "count", count, lower_count, size, f"'count' must be in [{lower_count}, {size}] and not 0"
            )
        ring = self._ring
        out: list[Entry] = []
        if to is not None:
            # The last `count` observations in [from, to], returned oldest first.
            low = from_ if from_ is not None else first
            seq = min(to, nxt - 1)
            while seq >= low and len(out) < count:
                entry = ring[(seq - 1) % size]
                assert entry is not None
                if items is None or entry.info.item.id in items:
                    out.append(entry)
                seq -= 1
            out.reverse()
            return SampleResult(out, self.window(min(to, nxt - 1) + 1), to >= nxt - 1)
        if count > 0:
            seq = from_ if from_ is not None else first
            while seq < nxt and len(out) < count:
                entry = ring[(seq - 1) % size]
                assert entry is not None
                if items is None or entry.info.item.id in items:
                    out.append(entry)
                seq += 1
            return SampleResult(out, self.window(seq), seq >= nxt)
        # count < 0: walk back from `from` (inclusive, default the newest); next_sequence is the
        # sequence before the oldest one looked at, so that from=next_sequence&count=-n goes on back.
        seq = from_ if from_ is not None and from_ < nxt else nxt - 1
        while seq >= first and len(out) < -count:
            entry = ring[(seq - 1) % size]
            assert entry is not None
            if items is None or entry.info.item.id in items:
                out.append(entry)
            seq -= 1
        out.reverse()
        return SampleResult(out, self.window(max(seq, 1)), seq < first)

    def entries_between(self, start: int, stop: int) -> Sequence[Entry]:
        """Held observations with start <= sequence < stop (for persistence and streaming)."""
        lo = max(start, self.first_sequence)
        hi = min(stop, self._next)
        out: list[Entry] = []
        for seq in range(lo, hi):
            entry = self._ring[(seq - 1) % self.size]
            assert entry is not None
            out.append(entry)
        return out
