"""Realistic laser-cutting programs of a given size for the job benchmarks; paced drip programs for DNC.

A nesting package writes one program per sheet: a header, then for each part a
rapid to the pierce point, beam on, a contour of lines and arcs at a cutting
feed, beam off; M30 and the closing `%` at the end. The generator writes the
same shapes (rectangles with rounded corners, holes as full circles) with
coordinates inside the simulator's 3000 x 1500 mm table, deterministically from a
seed, until the program reaches the requested size.
"""

from __future__ import annotations

import random

from simulator.machine import RAPID

SHEET_X, SHEET_Y = 3000.0, 1500.0


def laser_program(size: int, *, seed: int = 1, number: int = 1001) -> bytes:
    """A valid program of about `size` bytes (within one part's worth above it)."""
    rng = random.Random(seed)
    out: list[str] = ["%", f"O{number} (BENCH SHEET {seed})", "G21 G90 G17", "G0 X0 Y0"]
    length = sum(len(line) + 1 for line in out)
    tail = ["M5", "G0 X0 Y0", "M30", "%"]
    budget = size - sum(len(line) + 1 for line in tail)
    while length < budget:
        for line in _part(rng):
            out.append(line)
            length += len(line) + 1
    out.extend(tail)
    return ("\n".join(out) + "\n").encode("ascii")


def _part(rng: random.Random) -> list[str]:
    w, h = rng.uniform(20, 200), rng.uniform(20, 150)
    x0, y0 = rng.uniform(10, SHEET_X - w - 10), rng.uniform(10, SHEET_Y - h - 10)
    r = min(w, h) * 0.1
    feed = rng.choice((3000, 4500, 6000, 8000))
    lines = [f"G0 X{x0 + r:.3f} Y{y0:.3f}", f"M3 S{rng.choice((2000, 3000, 4000))}"]
    # rounded rectangle, counter-clockwise
    lines += [
        f"G1 X{x0 + w - r:.3f} Y{y0:.3f} F{feed}",
        f"G3 X{x0 + w:.3f} Y{y0 + r:.3f} I0 J{r:.3f}",
        f"G1 X{x0 + w:.3f} Y{y0 + h - r:.3f}",
        f"G3 X{x0 + w - r:.3f} Y{y0 + h:.3f} I{-r:.3f} J0",
        f"G1 X{x0 + r:.3f} Y{y0 + h:.3f}",
        f"G3 X{x0:.3f} Y{y0 + h - r:.3f} I0 J{-r:.3f}",
        f"G1 X{x0:.3f} Y{y0 + r:.3f}",
        f"G3 X{x0 + r:.3f} Y{y0:.3f} I{r:.3f} J0",
        "M5",
    ]
    # a hole: a full circle by I/J, then a short slot of straight segments
    cx, cy, hr = x0 + w / 2, y0 + h / 2, min(w, h) * 0.15
    lines += [
        f"G0 X{cx + hr:.3f} Y{cy:.3f}",
        "M3",
        f"G2 X{cx + hr:.3f} Y{cy:.3f} I{-hr:.3f} J0 F{feed // 2}",
        "M5",
    ]
    sx = x0 + w * 0.2
    lines += [f"G0 X{sx:.3f} Y{y0 + h * 0.8:.3f}", "M3"]
    for k in range(1, rng.randint(4, 12)):
        lines.append(f"G1 X{sx + k * w * 0.05:.3f} Y{y0 + h * 0.8 + (k % 2) * h * 0.05:.3f}")
    lines.append("M5")
    return lines


PACED_FEED = 600  # mm/min of a paced program's moves: x 8 is 4,800 mm/min, far below the simulator's rapid


def paced_program(
    size: int, *, factor: float, rate: float, speed: float = 1.0, pad: int | None = None, number: int = 42
) -> bytes:
    """About `size` bytes of equal feed moves at F600, back and forth along X, that the simulator's machine
    at `factor` times the gateway's run-time estimate (a feed override of 100 x factor %) consumes at
    `rate` characters per real second when the simulator runs at `speed`: each block of B bytes (`pad`,
    with a comment to fill it, or as short as it comes) is estimated (gateway/codecs/dnc/runtime.py,
    length / F) at B * factor * speed / rate seconds and runs `factor` times faster than that."""
    if PACED_FEED * factor > RAPID:
        raise ValueError(f"F{PACED_FEED} at {factor:g}x would be capped at the simulator's rapid ({RAPID:g})")
    bare = len(f"G1 X{0.0:09.3f} Y100 F{PACED_FEED}\n")
    filler = "" if pad is None else f" ({'P' * max(0, pad - bare - 3)})"
    block = bare + len(filler)
    move = block * factor * speed / rate * PACED_FEED / 60.0  # mm
    if move > 2000.0:
        raise ValueError(f"{move:.0f} mm moves do not fit the table")
    head = f"%\nO{number:04d} (PACED {factor:g}X)\nG21 G90 G17\nG0 X100 Y100\n".encode()
    out, length = [head], len(head)
    x, sign = 100.0, 1.0
    while length < size:
        if not 50.0 <= x + sign * move <= 2900.0:
            sign = -sign
        x += sign * move
        line = f"G1 X{x:09.3f} Y100 F{PACED_FEED}{filler}\n".encode()
        out.append(line)
        length += len(line)
    out.append(b"M30\n%\n")
    return b"".join(out)
