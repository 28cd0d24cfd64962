def read_rows(
    text: str | bytes,
    pos: int,
    line: int,
    params: tuple[bytes, bytes, float, float, float, float, float, bool],
    state: list[float | int | None],
) -> tuple[int, int, int, int, int, bool]: ...
def text_stats(data: bytes) -> tuple[int, bool, int, int]: ...
