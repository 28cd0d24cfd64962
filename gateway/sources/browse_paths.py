"""Tree paths for browsed nodes: the browse names, cleaned up to the mapping rules (both drivers' discover).

Pure helpers for `discover`. Paths are made unique case-insensitively, because
MQTT topics are lower-case, and a path is never both a folder and a variable.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Sequence
from dataclasses import dataclass, field

from gateway.settings.names import RESERVED_SEGMENTS

RESERVED_PREFIX = "Controller_"

Key = tuple[str, str]  # (node id string: identity, browse name: what the path is made of)

_EDGE_RE = re.compile(r"^[^A-Za-z0-9_.\-]+|[^A-Za-z0-9_.\-]+$")
_INNER_RE = re.compile(r"[^A-Za-z0-9_.\-]+")


def sanitize_segment(name: str) -> str:
    """A browse name as a path segment: ASCII letters, digits, '_', '-', '.', not starting with '.' or '-'.

    `::AsGlobalPV` → `AsGlobalPV`, `gAxis[0]` → `gAxis_0`, `Höhe` → `Hohe`.
    """
    text = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode("ascii")
    text = _INNER_RE.sub("_", _EDGE_RE.sub("", text))
    if not text:
        return "Node"
    if text[0] in ".-":
        text = "_" + text
    return text


def _unique(base: str, used: set[str]) -> str:
    name, n = base, 2
    while name.lower() in used:
        name = f"{base}_{n}"
        n += 1
    used.add(name.lower())
    return name


@dataclass
class _Trie:
    raw: str = ""  # the browse name
    name: str = ""  # the path segment assigned to it
    children: dict[str, _Trie] = field(default_factory=dict)
    variable: int | None = None  # index into the input when this node is a mapped variable


def assign_paths(key_paths: Sequence[Sequence[Key]]) -> list[str]:
    """Valid, unique tree paths for browse paths; the result is aligned with the input.

    Each browse path is a sequence of (identity, browse name) pairs. Leading folders
    common to everything are dropped; a top-level name the gateway reserves gets a
    prefix; siblings whose names clash (also by case) get `_2`, `_3`; a variable
    that also has mapped children moves inside its own folder as `Value`.
    """
    root = _Trie()
    for index, keys in enumerate(key_paths):
        node = root
        for identity, browse_name in keys:
            child = node.children.get(identity)
            if child is None:
                child = node.children[identity] = _Trie(browse_name)
            node = child
        node.variable = index
    while len(root.children) == 1:
        (only,) = root.children.values()
        if only.variable is not None or not only.children or _is_array(only):
            break
        root = only
    paths: list[str] = [""] * len(key_paths)

    def walk(node: _Trie, prefix: str, top: bool) -> None:
        used: set[str] = set()
        for child in node.children.values():
            raw = child.raw
            if node.raw and raw.startswith(node.raw + "["):  # B&R array elements: gAxis/gAxis[0] → gAxis/0
                raw = raw[len(node.raw) :]
            base = sanitize_segment(raw)
            if top and base.lower() in _RESERVED_LOWER:
                base = RESERVED_PREFIX + base
            child.name = _unique(base, used)
        for child in node.children.values():
            path = f"{prefix}{child.name}"
            walk(child, path + "/", False)
            if child.variable is not None:
                if child.children:
                    own = _unique("Value", {c.name.lower() for c in child.children.values()})
                    paths[child.variable] = f"{path}/{own}"
                else:
                    paths[child.variable] = path

    walk(root, "", True)
    return paths


_RESERVED_LOWER = {s.lower() for s in RESERVED_SEGMENTS}


def _is_array(node: _Trie) -> bool:
    """Whether the children are B&R-style array elements (gAxis[0], gAxis[1]), which need the array's name."""
    return any(c.raw.startswith(node.raw + "[") for c in node.children.values())
