"""Is this a file name the controller's program store can hold?

Some checks hold for every controller, because names travel through FTP
servers and Windows PCs on the way: no folders, no leading dot, no Windows device
names (CON, NUL, COM1...), no trailing dot or space, no control characters. The
rest is per machine: a pattern, a length and the allowed extensions.
"""

from __future__ import annotations

from gateway.config.validation import ValidationRules
from gateway.jobs.validation.verdict import Rejection

WINDOWS_DEVICES = frozenset(
    {"CON", "PRN", "AUX", "NUL", "CONIN$", "CONOUT$"}
    | {f"COM{n}" for n in range(1, 10)}
    | {f"LPT{n}" for n in range(1, 10)}
)


def split_name(name: str) -> tuple[str, str]:
    """`part.NC` -> ("part", ".nc"); `O1234` -> ("O1234", ""). The extension is lower-cased."""
    stem, dot, ext = name.rpartition(".")
    if not dot or not stem:
        return name, ""
    return stem, "." + ext.lower()


def check_file_name(name: str, rules: ValidationRules) -> list[Rejection]:
    """Every reason the controller cannot hold a file of this name (empty when it can)."""
    problem = _structural(name)
    if problem:
        return [Rejection("file-name", f"file name {name!r} {problem}")]
    found: list[Rejection] = []
    if len(name) > rules.max_name_length:
        found.append(
            Rejection(
                "file-name",
                f"file name {name[:40]!r}{'...' if len(name) > 40 else ''} is {len(name)} characters long; "
                f"this controller takes at most {rules.max_name_length}",
            )
        )
    ext = split_name(name)[1]
    if ext not in rules.extensions:
        allowed = ", ".join(e or "(none)" for e in rules.extensions)
        what = f"extension {ext!r}" if ext else "a name without an extension"
        found.append(
            Rejection("file-name", f"file name {name!r}: {what} is not allowed here (allowed: {allowed})")
        )
    if not rules.file_name_re.fullmatch(name):
        hint = "contains a space; " if " " in name else ""
        found.append(
            Rejection(
                "file-name",
                f"file name {name!r} {hint}is not a name this controller can hold "
                f"(it must match {rules.file_name_pattern})",
            )
        )
    return found


def _structural(name: str) -> str | None:
    """What makes a name unusable on any controller, or None."""
    if not name or not name.strip():
        return "is empty"
    if "/" in name or "\\" in name:
        return "contains a path separator: a program name cannot name a folder"
    if name.startswith("."):
        return "starts with a dot (a hidden file, or a relative path)"
    if any(ord(c) < 0x20 or ord(c) == 0x7F for c in name):
        return "contains a control character"
    if name.endswith((".", " ")):
        return "ends with a dot or a space, which Windows drops"
    device = name.split(".", 1)[0].rstrip(" ").upper()
    if device in WINDOWS_DEVICES:
        return f"is the Windows device name {device}, which no Windows PC can store as a file"
    return None
