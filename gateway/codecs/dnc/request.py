"""Remote requests: the operator punches a short program that names the program wanted.

    %
    O9999 (PRG=O4711)
    M30
    %

The request's O-number is configurable (9999 by default) and so is the key in
the comment (`PRG`). The name must be a plain file name of [A-Za-z0-9_.-], not
starting with a dot and never `..`: whatever the operator types, it cannot
reach outside the gateway's program folder. Every refusal is answered with a
short program whose comment says why, which the operator reads on the screen:

    %
    O9999 (NOT FOUND O4711)
    M30
    %
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from gateway.codecs.dnc.framing import FramingError, split_program

DEFAULT_REQUEST_NUMBER = 9999
DEFAULT_KEY = "PRG"
MAX_NAME = 64
#: Longest comment in an answer (Fanuc shows about this much on one line).
MAX_COMMENT = 60
_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")
_O_WORD = re.compile(r"^\s*O\s*0*(\d{1,8})\b", re.IGNORECASE)
_COMMENT = re.compile(r"\(([^()]*)\)")


@dataclass(frozen=True, slots=True)
class RemoteRequest:
    """A valid request for the program called `name`."""

    name: str


@dataclass(frozen=True, slots=True)
class BadRequest:
    """A request program that names nothing usable; `reason` goes into the answer's comment."""

    reason: str
    name: str | None = None


def check_name(name: str) -> str | None:
    """Why `name` cannot be a program name in a folder, or None when it can."""
    if not name:
        return "NO PROGRAM NAME"
    if len(name) > MAX_NAME:
        return "NAME TOO LONG"
    if "/" in name or "\\" in name or ".." in name or name.startswith("."):
        return "NAME LEAVES THE FOLDER"
    if not _NAME.match(name):
        return "BAD CHARACTERS IN NAME"
    return None


def parse_request(
    program: bytes, *, number: int = DEFAULT_REQUEST_NUMBER, key: str = DEFAULT_KEY
) -> RemoteRequest | BadRequest | None:
    """The request a punched program makes, or None when it is an ordinary program (another O-number)."""
    try:
        lines = split_program(program)
    except FramingError as exc:
        return BadRequest(f"UNREADABLE REQUEST {exc.reason}")
    texts = [line.text.decode("ascii", "replace") for line in lines.lines]
    if lines.header is not None:
        texts.insert(0, lines.header.decode("ascii", "replace").lstrip("%"))
    first = next((t for t in texts if t.strip()), "")
    match = _O_WORD.match(first)
    if match is None or int(match.group(1)) != number:
        return None
    pattern = re.compile(rf"^\s*{re.escape(key)}\s*=\s*(.*?)\s*$", re.IGNORECASE)
    for text in texts:
        for comment in _COMMENT.findall(text):
            found = pattern.match(comment)
            if found is None:
                continue
            name = found.group(1)
            reason = check_name(name)
            if reason is not None:
                return BadRequest(reason, name)
            return RemoteRequest(name)
    return BadRequest(f"NO {key.upper()}= IN REQUEST")


def answer_program(comment: str, *, number: int = DEFAULT_REQUEST_NUMBER) -> bytes:
    """The short program that answers a refused request: `%`, `O9999 (comment)`, `M30`, `%`.

    The comment is made safe for any controller: upper case, printable ASCII, no
    parentheses, at most MAX_COMMENT characters.
    """
    safe = "".join(c if " " <= c <= "~" and c not in "()%;" else " " for c in comment.upper())
    safe = " ".join(safe.split())[:MAX_COMMENT].strip()
    return f"%\nO{number:04d} ({safe})\nM30\n%\n".encode("ascii")


def not_found(name: str, *, number: int = DEFAULT_REQUEST_NUMBER) -> bytes:
    """The answer to a request for a program the gateway does not have."""
    return answer_program(f"NOT FOUND {name}", number=number)
