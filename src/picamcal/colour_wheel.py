"""The colour wheel every picamcal target uses: the simulator's, the printed or displayed one, and the analysis."""

from __future__ import annotations

#: Segment names and colours (in the primaries: sRGB on screen, LED amounts in the simulator), counter-clockwise
#: from +x as seen on screen, 60 degrees each.
SEGMENTS: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("red", (1, 0, 0)),
    ("yellow", (1, 1, 0)),
    ("green", (0, 1, 0)),
    ("cyan", (0, 1, 1)),
    ("blue", (0, 0, 1)),
    ("magenta", (1, 0, 1)),
)
