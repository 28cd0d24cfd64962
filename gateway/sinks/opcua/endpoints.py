"""OPC UA endpoint security (gateway file, `opcua:`): which security policies and modes are offered.

Names follow the OPC UA policy names with the message security mode appended,
as clients such as UaExpert show them. A profile is a shorthand for a list:

- `standard` (the default): None, plus every signed and every signed-and-encrypted endpoint;
- `secure`: the same without None;
- `open`: None only (no certificate is generated).

`security:` lists the endpoints explicitly instead; giving both is an error.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

SecurityName = Literal[
    "None",
    "Basic256Sha256_Sign",
    "Basic256Sha256_SignAndEncrypt",
    "Aes128_Sha256_RsaOaep_Sign",
    "Aes128_Sha256_RsaOaep_SignAndEncrypt",
    "Aes256_Sha256_RsaPss_Sign",
    "Aes256_Sha256_RsaPss_SignAndEncrypt",
]
Profile = Literal["standard", "secure", "open"]

SECURE: tuple[str, ...] = (
    "Basic256Sha256_SignAndEncrypt",
    "Basic256Sha256_Sign",
    "Aes256_Sha256_RsaPss_SignAndEncrypt",
    "Aes256_Sha256_RsaPss_Sign",
    "Aes128_Sha256_RsaOaep_SignAndEncrypt",
    "Aes128_Sha256_RsaOaep_Sign",
)
PROFILES: dict[str, tuple[str, ...]] = {
    "standard": ("None", *SECURE),
    "secure": SECURE,
    "open": ("None",),
}


def endpoints_for(security: Sequence[str] | None, profile: str | None) -> tuple[str, ...]:
    """The endpoints to offer: the explicit list, else the profile's (default: standard)."""
    if security is not None:
        return tuple(security)
    return PROFILES[profile or "standard"]


def check_security(security: Sequence[str] | None, profile: str | None) -> None:
    if security is not None and profile is not None:
        raise ValueError("give either opcua.profile or opcua.security, not both")
    if security is not None:
        seen = set()
        for name in security:
            if name in seen:
                raise ValueError(f"security: {name} is listed twice")
            seen.add(name)


def is_secure(name: str) -> bool:
    return name != "None"
