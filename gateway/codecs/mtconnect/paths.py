"""`path=` filters: the XPath subset MTConnect clients use, evaluated over the probe document's shape.

Supported, as in the examples the standard and the reference agent's users give:
    //Axes                                       a component type, anywhere
    //Linear[@name="X"]                          with attribute tests: = and !=, "..." or '...'
    //DataItem[@type="POSITION" and @subType="ACTUAL"]     and / or (and binds tighter)
    //Controller//DataItem[@category="EVENT"]    steps with / (child) and // (descendant)
    //Axes/Components/Linear/DataItems/DataItem  the document's container elements
    /MTConnectDevices/Devices/Device[@name="m1"]//Path, //*[@id="x"], a|b (unions)
Anything else (functions, positions like [1], axes, `..`, parentheses) is refused with
InvalidPath, as is a path that selects no data item (what the reference agent does).

What a path selects becomes a set of data item ids, as in the reference agent: a
DataItem is itself, a DataItems element its DataItem children, any other element all
the data items below it. With a device (for /<device>/current), the path applies below
that device, as if it were written after `//Devices/Device[@uuid="..."]`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from gateway.codecs.mtconnect.attributes import PATH_ATTRIBUTES, present
from gateway.codecs.mtconnect.errors import InvalidPath
from gateway.codecs.mtconnect.model import Catalog, DataItem, Device, Node

MAX_PATH_LENGTH = 2048
MAX_UNION = 32

_NAME = re.compile(r"(?:m:)?([A-Za-z_][A-Za-z0-9_.\-]*)")
_ATTR = re.compile(r"[A-Za-z_][A-Za-z0-9_.\-]*")
_SPACE = re.compile(r"\s*")


# --- the probe document as a tree ------------------------------------------------------------


@dataclass(eq=False)
class _Element:
    name: str
    attrs: dict[str, str]
    children: list[_Element] = field(default_factory=list)
    item_id: str | None = None


def _item_element(item: DataItem) -> _Element:
    attrs = {attribute.name: value for attribute, value in present(item, PATH_ATTRIBUTES)}
    return _Element("DataItem", attrs, item_id=item.id)


def _node_element(node: Node) -> _Element:
    attrs = {"id": node.id}
    if node.name is not None:
        attrs["name"] = node.name
    if node.native_name is not None:
        attrs["nativeName"] = node.native_name
    if node.uuid is not None:  # a Device always has one, a Component may
        attrs["uuid"] = node.uuid
    element = _Element(node.type, attrs)
    if node.data_items:
        element.children.append(_Element("DataItems", {}, [_item_element(i) for i in node.data_items]))
    if node.components:
        element.children.append(_Element("Components", {}, [_node_element(c) for c in node.components]))
    return element


class PathIndex:
    """The probe document's tree for one catalog, built once and reused by every query."""

    def __init__(self, catalog: Catalog) -> None:
        self.catalog = catalog
        self.devices: dict[str, _Element] = {}
        devices = _Element("Devices", {})
        for device in catalog.devices:
            element = _node_element(device)
            self.devices[device.uuid] = element
            devices.children.append(element)
        self.document = _Element("", {}, [_Element("MTConnectDevices", {}, [devices])])

    def select(self, path: PathExpr, device: Device | None = None) -> frozenset[str]:
        """The data item ids `path` selects (below `device`, if given). Raises InvalidPath if none."""
        start = self.document if device is None else self.devices[device.uuid]
        ids: set[str] = set()
        for steps in path.union:
            for element in _evaluate(steps, start):
                _collect(element, ids)
        if not ids:
            raise InvalidPath(f"the path {path.text!r} selects no data item")
        return frozenset(ids)


def _collect(element: _Element, ids: set[str]) -> None:
    if element.item_id is not None:
        ids.add(element.item_id)
        return
    for child in element.children:
        _collect(child, ids)


def _descendants_or_self(element: _Element, out: list[_Element]) -> None:
    out.append(element)
    for child in element.children:
        _descendants_or_self(child, out)


def _evaluate(steps: tuple[_Step, ...], start: _Element) -> list[_Element]:
    context = [start]
    for step in steps:
        if step.descendant:
            expanded: list[_Element] = []
            for element in context:
                _descendants_or_self(element, expanded)
            context = expanded
        selected: list[_Element] = []
        seen: set[int] = set()
        for element in context:
            for child in element.children:
                wanted = step.name is None or child.name == step.name
                if wanted and id(child) not in seen and step.matches(child.attrs):
                    seen.add(id(child))
                    selected.append(child)
        context = selected
        if not context:
            break
    return context


# --- the expression ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Test:
    attr: str
    value: str | None  # None: the attribute exists
    negate: bool = False

    def __call__(self, attrs: dict[str, str]) -> bool:
        actual = attrs.get(self.attr)
        if self.value is None:
            return actual is not None
        if self.negate:
            return actual is not None and actual != self.value
        return actual == self.value


@dataclass(frozen=True, slots=True)
class _Step:
    descendant: bool
    name: str | None  # None: *
    predicates: tuple[tuple[tuple[_Test, ...], ...], ...] = ()  # each: or of ands

    def matches(self, attrs: dict[str, str]) -> bool:
        return all(any(all(t(attrs) for t in conj) for conj in pred) for pred in self.predicates)


@dataclass(frozen=True, slots=True)
class PathExpr:
    text: str
    union: tuple[tuple[_Step, ...], ...]


class _Parser:
    def __init__(self, text: str) -> None:
        self.text = text
        self.pos = 0

    def fail(self, what: str) -> InvalidPath:
        return InvalidPath(f"the path {self.text!r} is not supported at character {self.pos + 1}: {what}")

    def skip_space(self) -> None:
        m = _SPACE.match(self.text, self.pos)
        assert m is not None
        self.pos = m.end()

    def peek(self, token: str) -> bool:
        return self.text.startswith(token, self.pos)

    def parse(self) -> PathExpr:
        union: list[tuple[_Step, ...]] = [self.path()]
        self.skip_space()
        while self.peek("|"):
            self.pos += 1
            self.skip_space()
            union.append(self.path())
            self.skip_space()
            if len(union) > MAX_UNION:
                raise self.fail(f"more than {MAX_UNION} alternatives")
        if self.pos != len(self.text):
            raise self.fail(f"unexpected {self.text[self.pos : self.pos + 10]!r}")
        return PathExpr(self.text, tuple(union))

    def path(self) -> tuple[_Step, ...]:
        steps: list[_Step] = []
        if not self.peek("/"):
            raise self.fail("a path starts with / or //")
        while self.peek("/"):
            descendant = self.peek("//")
            self.pos += 2 if descendant else 1
            steps.append(self.step(descendant))
        return tuple(steps)

    def step(self, descendant: bool) -> _Step:
        name: str | None
        if self.peek("*"):
            self.pos += 1
            name = None
        else:
            m = _NAME.match(self.text, self.pos)
            if m is None:
                raise self.fail("an element name or * was expected (no axes, '.', '..' or functions)")
            self.pos = m.end()
            name = m.group(1)
            if self.peek("::") or self.peek("("):
                raise self.fail("axes and functions are not supported")
        predicates = []
        while self.peek("["):
            self.pos += 1
            predicates.append(self.predicate())
        return _Step(descendant, name, tuple(predicates))

    def predicate(self) -> tuple[tuple[_Test, ...], ...]:
        alternatives = [self.conjunction()]
        while self.keyword("or"):
            alternatives.append(self.conjunction())
        self.skip_space()
        if not self.peek("]"):
            raise self.fail('a predicate is [@attribute="value"] joined by and / or')
        self.pos += 1
        return tuple(alternatives)

    def keyword(self, word: str) -> bool:
        self.skip_space()
        if self.text.startswith(word, self.pos):
            after = self.pos + len(word)
            if after < len(self.text) and (self.text[after].isspace() or self.text[after] == "@"):
                self.pos = after
                return True
        return False

    def conjunction(self) -> tuple[_Test, ...]:
        tests = [self.test()]
        while self.keyword("and"):
            tests.append(self.test())
        return tuple(tests)

    def test(self) -> _Test:
        self.skip_space()
        if not self.peek("@"):
            raise self.fail('only attribute tests (@name="value") are supported in predicates')
        self.pos += 1
        m = _ATTR.match(self.text, self.pos)
        if m is None:
            raise self.fail("an attribute name was expected after @")
        self.pos = m.end()
        attr = m.group(0)
        self.skip_space()
        negate = self.peek("!=")
        if negate or self.peek("="):
            self.pos += 2 if negate else 1
            self.skip_space()
            return _Test(attr, self.literal(), negate)
        return _Test(attr, None)

    def literal(self) -> str:
        quote = self.text[self.pos : self.pos + 1]
        if quote not in ('"', "'"):
            raise self.fail("a quoted value was expected")
        end = self.text.find(quote, self.pos + 1)
        if end < 0:
            raise self.fail("the quoted value is not closed")
        value = self.text[self.pos + 1 : end]
        self.pos = end + 1
        return value


def parse_path(text: str) -> PathExpr:
    """Compile a `path=` value; raises InvalidPath for anything outside the subset."""
    if not text.strip():
        raise InvalidPath("the path is empty")
    if len(text) > MAX_PATH_LENGTH:
        raise InvalidPath(f"the path is longer than {MAX_PATH_LENGTH} characters")
    return _Parser(text.strip()).parse()
