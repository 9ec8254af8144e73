"""Trust but verify: check what a raw file says about itself against its data.

Files in the wild lie. A real PiDNG file from an IMX219 declares GBRG while its greens sit on the other
diagonal, and has no black level. The two green sites of a 2x2 block see the same colour, so on a white
or natural scene they agree with each other far better than with red or blue: that tells which diagonal
the greens are on (not which of the other two sites is red).
"""

from __future__ import annotations

import numpy as np

from ..sensors import SENSORS, black_level_at
from .model import RawImage

#: Diagonals of the 2x2 block: sites (0, 0)/(1, 1) and (0, 1)/(1, 0).
_DIAGONALS = ((0, 3), (1, 2))
_GREEN_DIAGONAL = {"RGGB": 1, "BGGR": 1, "GRBG": 0, "GBRG": 0}
#: The declared green pair must differ this many times more than the other pair before we say so.
_EVIDENCE = 2.5
#: A DNG without a BlackLevel tag whose darkest pixels sit above this fraction of its white level is said to have a
#: black level the default (0) misses (:func:`check_metadata`).
_DARK_FRACTION = 0.01


def site_disagreement(raw: RawImage, max_rows: int = 256) -> tuple[float, float]:
    """Relative mean difference between the two sites of each diagonal, ((0,0)-(1,1), (0,1)-(1,0)).

    Uses a grid of up to ``max_rows`` x ``max_rows`` evenly spaced 2x2 blocks (65 536: the mean of a block's
    difference is known to a fraction of a percent), so that it costs a read of a 12 MP frame well under a
    millisecond.

    Examples
    --------
    >>> bayer = np.tile(np.array([[200, 500], [500, 300]], np.uint16), (8, 8))  # the greens on one diagonal
    >>> [round(d, 3) for d in site_disagreement(RawImage(bayer, "BGGR", 64, 1023, 10))]
    [0.269, 0.0]
    """
    rows, columns = raw.height // 2, raw.width // 2
    step_y, step_x = max(1, rows // max_rows), max(1, columns // max_rows)
    blocks = raw.bayer.reshape(rows, 2, columns, 2)[::step_y, :, ::step_x].astype(np.float32)
    # An unknown (NaN) black level is taken as 0 here: the two greens still agree far better than other sites.
    black = np.nan_to_num(np.asarray(raw.black_level, dtype=np.float32), nan=0.0).reshape(2, 2)
    sites = [blocks[:, sy, :, sx] - black[sy, sx] for sy in (0, 1) for sx in (0, 1)]
    out = []
    for a, b in _DIAGONALS:
        scale = float(np.mean(np.abs(sites[a]) + np.abs(sites[b]))) or 1.0
        out.append(float(np.mean(np.abs(sites[a] - sites[b]))) / scale)
    return out[0], out[1]


def check_metadata(raw: RawImage) -> list[str]:
    """Problems found by comparing a raw image's declared pattern and black level with its data.

    The black-level check applies to every registry sensor: a file that declares 0 while the registry's level is
    above its darkest pixels; and to a DNG of any other sensor without a BlackLevel tag (the DNG default, 0) whose
    darkest pixels sit well above 0, giving their level. An unknown (NaN) black level is not checked here.

    Returns
    -------
    list of str
        One sentence per problem, each saying what to pass to override it; empty if all is well.

    Examples
    --------
    >>> bayer = np.tile(np.array([[200, 500], [500, 300]], np.uint16), (8, 8))  # the greens on one diagonal
    >>> check_metadata(RawImage(bayer, "BGGR", 64, 1023, 10))
    []
    >>> check_metadata(RawImage(bayer, "GBRG", 64, 1023, 10))
    ['the file declares Bayer order GBRG, but the greens sit on the other diagonal (...): pass --pattern RGGB or BGGR']
    """
    problems = []
    d = site_disagreement(raw)
    green = _GREEN_DIAGONAL[raw.pattern]
    other = 1 - green
    if d[green] > _EVIDENCE * d[other] and d[green] > 0.02:
        candidates = " or ".join(p for p, diag in _GREEN_DIAGONAL.items() if diag == other)
        said = "--pattern gives" if "declared_pattern" in raw.metadata else "the file declares"
        problems.append(
            f"{said} Bayer order {raw.pattern}, but the greens sit on the other diagonal (the sites it calls green "
            f"differ by {100 * d[green]:.1f} %, the other pair by {100 * d[other]:.1f} %): pass --pattern {candidates}"
        )
    sensor = SENSORS.get((raw.sensor or "").lower())
    # A zero black level where the registry knows better; an unknown (NaN) one is require_black_level's to report.
    if sensor is not None and not any(raw.black_level):
        expected = black_level_at(sensor, raw.bit_depth)
        low = float(np.percentile(raw.bayer[::8, ::8], 0.1))
        if low >= 0.5 * expected:
            problems.append(
                f"declares no black level, but the {sensor.name.upper()}'s is {expected:g} DN at {raw.bit_depth} bits "
                f"and no pixel is darker than {low:g} DN: pass --black-level {expected:g}"
            )
    elif raw.metadata.get("black_level_source") == "DNG default" and "declared_black_level" not in raw.metadata:
        problems.extend(_default_black_level(raw))
    return problems


def _default_black_level(raw: RawImage) -> list[str]:
    """A DNG without a BlackLevel tag is taken at the DNG default, 0: said when its darkest pixels sit well above.

    "Well above" is :data:`_DARK_FRACTION` of the white level: the Pi's sensors have pedestals of 1.6 % (OV5647) to
    6.3 % (the others) of their range, and a sensor whose black is 0 clips its darkest pixels at 0. The level is the
    0.1th percentile of each Bayer site, on every 8th pixel each way (a read of a 12 MP frame stays a few ms); on a lit
    frame it is an upper bound of the black level, which the message says.
    """
    sites = [raw.bayer[sy::2, sx::2][::4, ::4] for sy in (0, 1) for sx in (0, 1)]
    darkest = [float(np.percentile(site, 0.1)) for site in sites]
    low = min(darkest)
    if low < _DARK_FRACTION * raw.white_level:
        return []
    each = "" if len(set(darkest)) == 1 else f" ({', '.join(f'{d:g}' for d in darkest)} for the four sites)"
    return [
        f"black level 0 is the DNG default (the file has no BlackLevel tag), but no pixel is darker than {low:g} DN"
        f"{each}: if the sensor's black level is {low:g} DN (a dark frame shows it; on a lit frame it is lower), pass "
        f"--black-level {low:g}"
    ]
