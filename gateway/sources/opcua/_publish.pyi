from typing import Any

def decode(
    data: bytes, start: int, size: int, /
) -> tuple[int, int, int, int, list[tuple[int, Any, Any, int]]] | None: ...
