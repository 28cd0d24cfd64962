"""A settings model as plain JSON data with every secret masked: what the console shows of a configuration."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel, SecretStr

SECRET_WORDS = ("password", "secret", "token", "passphrase")
MASK = "********"
URL_PASSWORD = re.compile(r"(\w+://[^/:@\s]*:)[^@/\s]+@")  # postgresql://user:PASSWORD@host/db


def masked(model: BaseModel) -> dict[str, Any]:
    """A configuration as plain JSON data, every secret masked (for the console's Gateway page)."""
    return _mask(model.model_dump(mode="json"))  # type: ignore[no-any-return]


def _mask(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {
            k: (MASK if v is not None and any(w in str(k).lower() for w in SECRET_WORDS) else _mask(v))
            for k, v in value.items()
        }
    if isinstance(value, list):
        return [_mask(v) for v in value]
    if isinstance(value, str):  # a URL with its password in it (the gateway file's queue:)
        return URL_PASSWORD.sub(rf"\g<1>{MASK}@", value)
    if isinstance(value, SecretStr):  # pragma: no cover - model_dump(mode="json") has already hidden it
        return MASK
    return value
