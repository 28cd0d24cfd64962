"""Who is asking: the context every write, call and acknowledgement carries through the tree.

At the bottom of the model (it imports nothing of it), so that the tree, the
methods and the access policy can all name it without importing each other.
"""

from __future__ import annotations


class WriteContext:
    """Who is writing or calling, through which sink, with which role (see gateway/model/access.py)."""

    __slots__ = ("origin", "role", "user")

    def __init__(self, origin: str, user: str | None = None, role: str | None = None) -> None:
        self.origin = origin
        self.user = user
        self.role = role

    def __repr__(self) -> str:
        return f"<WriteContext {self.origin} user={self.user!r} role={self.role!r}>"
