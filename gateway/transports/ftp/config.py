"""The FTP transport's settings: `jobs.controller: {type: ftp, host, ...}` (`type` may be left out).

The model this transport's spec registers (gateway/transports/ftp/__init__.py): the
mapping file's `jobs.controller` union is built from the registry's models.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import ByteSize, Field, SecretStr, field_validator

from gateway.settings.base import Strict

Port = Annotated[int, Field(ge=1, le=65535)]
# "64 MiB", "512kB" or a number of bytes
Size = Annotated[ByteSize, Field(description="Bytes, or a size with a unit: 64MiB, 500kB")]


class ControllerFtp(Strict):
    """The controller's FTP program store."""

    type: Literal["ftp"] = Field(default="ftp", description="ftp (the default) or serial")
    host: str = Field(min_length=1, description="Controller address")
    port: Port = 21
    user: str = Field(default="anonymous", min_length=1)
    password: SecretStr | None = Field(
        default=None, description="Use ${NAME} to take it from the environment"
    )
    folder: str = Field(default="/DATA/Programs", description="Where programs go on the controller")
    passive: Literal["auto", "epsv", "pasv"] = Field(
        default="auto",
        description="Passive mode command: auto tries EPSV, then PASV (active mode is not supported)",
    )
    tls: Literal["none", "implicit", "explicit"] = Field(
        default="none", description="FTPS: implicit (TLS from the first byte) or explicit (AUTH TLS)"
    )
    tls_verify: bool = Field(default=True, description="Check the controller's certificate")
    timeout: float = Field(default=10.0, gt=0, description="Seconds per connect, command and data block")
    upload: Literal["temp-rename", "direct"] = Field(
        default="temp-rename",
        description="temp-rename: upload under a temporary name, then rename (atomic); "
        "direct: for stores without RNFR/RNTO",
    )
    temp_suffix: str = Field(
        default=".tmp", min_length=1, description="Suffix of the temporary name on the controller"
    )
    rate_limit: Size | None = Field(
        default=None, description="Upload speed limit in bytes per second (slow controllers)"
    )

    @field_validator("folder")
    @classmethod
    def _folder(cls, folder: str) -> str:
        if not folder.startswith("/"):
            raise ValueError(
                f"folder {folder!r} must be an absolute path on the controller, e.g. /DATA/Programs"
            )
        if any(part == ".." for part in folder.split("/")) or "\\" in folder:
            raise ValueError(f"folder {folder!r} must not contain '..' or backslashes")
        return folder.rstrip("/") or "/"

    @field_validator("temp_suffix")
    @classmethod
    def _suffix(cls, suffix: str) -> str:
        if "/" in suffix or "\\" in suffix or not suffix.isprintable():
            raise ValueError("temp_suffix must be a plain, printable file name suffix such as .tmp")
        return suffix
