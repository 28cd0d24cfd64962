"""The compiled part of validation (`_plain.c`), or None where it was not built.

setup.py builds it when a C compiler is at hand and leaves it out otherwise; the
pure-Python readers give the same verdicts, only slower on large programs.
"""

from __future__ import annotations

from types import ModuleType

plain: ModuleType | None
try:
    from gateway.jobs.validation import _plain as plain
except ImportError:  # pragma: no cover - installed without a C compiler
    plain = None
