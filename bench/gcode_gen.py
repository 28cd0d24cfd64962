"""Realistic laser-cutting programs of a given size, for the job benchmarks.

A nesting package writes one program per sheet: a header, then for each part a
rapid to the pierce point, beam on, a contour of lines and arcs at a cutting
feed, beam off; M30 and the closing `%` at the end. The generator writes the
same shapes (rectangles with rounded corners, holes as full circles) with
coordinates inside the simulator's 3000 x 1500 mm table, deterministically from a
seed, until the program reaches the requested size.
"""

from __future__ import annotations

import random

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
