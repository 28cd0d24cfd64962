"""Escaping for XML built from strings: text and attribute values that any input can go into.

Characters XML 1.0 cannot carry at all (NUL and the other C0 controls but tab, LF, CR;
lone surrogates; U+FFFE/U+FFFF) become U+FFFD, so a controller's odd byte never makes
a document unreadable.
"""

from __future__ import annotations

import re

_INVALID = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")
_TEXT_SPECIAL = re.compile("[&<>\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")
TEXT_SPECIAL = _TEXT_SPECIAL  # what xml_text() changes: a caller rendering many values tests before calling
_ATTR_SPECIAL = re.compile('[&<>"\t\n\r\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]')


def _clean(text: str) -> str:
    return _INVALID.sub("\ufffd", text)


def xml_text(text: str) -> str:
    """`text` as element content."""
    if _TEXT_SPECIAL.search(text) is None:
        return text
    return _clean(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def xml_attr(text: str) -> str:
    """`text` as a double-quoted attribute value; tab, LF and CR survive attribute normalisation."""
    if _ATTR_SPECIAL.search(text) is None:
        return text
    return (
        _clean(text)
        .replace("&", "&amp;")
        .replace("<", "&lt;")
        .replace(">", "&gt;")
        .replace('"', "&quot;")
        .replace("\t", "&#9;")
        .replace("\n", "&#10;")
        .replace("\r", "&#13;")
    )
