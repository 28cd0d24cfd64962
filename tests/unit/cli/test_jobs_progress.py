"""`cnc-gateway jobs`: how a serial delivery's progress reads, and the progress bar of `submit --follow`."""

from __future__ import annotations

import io

from gateway.cli.jobs import Progress, progress_text


def test_progress_text_of_a_drip_feed() -> None:
    text = progress_text(13_200, 29_300, 512, 3.4, 41.0, "DC3")
    assert text == "45% 13.2 kB/29.3 kB, line 512, lead 3 s, 0:41 left, held: DC3"


def test_progress_text_of_a_load() -> None:
    assert progress_text(500, 1000, None, None, None, "") == "50% 500 B/1.0 kB"


def test_the_bar_shows_the_callers_words_and_ends_its_line() -> None:
    out = io.StringIO()
    bar = Progress(100, out, threshold=0)
    bar.show(50, "line 7")
    bar.done()
    assert out.getvalue() == "\r[###############               ] line 7\x1b[K\n"
