"""DNG raw files: read through LibRaw (rawpy), written with tifffile.

Only this module knows the DNG tag layout. The reader takes the mosaic, CFA pattern, per-site black
levels and white level from LibRaw, and the exposure metadata from the TIFF tags. The writer makes a
minimal uncompressed DNG 1.4 that LibRaw reads back bit-exactly.
"""

from __future__ import annotations

import json
import os
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from .._atomic import atomic_path
from .._files import json_default
from ..errors import RawFormatError
from ..sensors import find_sensor_name
from .model import PATTERNS, RawImage

# DNG / TIFF-EP tag codes (Adobe DNG specification 1.4).
_CFA_REPEAT_DIM, _CFA_PATTERN = 33421, 33422
_EXPOSURE_TIME, _ISO = 33434, 34855
_DNG_VERSION, _DNG_BACKWARD, _UNIQUE_MODEL = 50706, 50707, 50708
_BLACK_REPEAT_DIM, _BLACK_LEVEL, _WHITE_LEVEL = 50713, 50714, 50717
_COLOR_MATRIX1, _AS_SHOT_NEUTRAL, _ILLUMINANT1 = 50721, 50728, 50778
_CFA_CODES = {"R": 0, "G": 1, "B": 2}
_METADATA_KEY = "picamcal"


def is_dng(head: bytes) -> bool:
    """True if the first bytes of a file are a TIFF header (DNG is a TIFF)."""
    return head[:4] in (b"II*\x00", b"MM\x00*")


def _tag_metadata(path: Path) -> dict[str, Any]:
    meta: dict[str, Any] = {}
    try:
        tif = tifffile.TiffFile(path)
        tags = tif.pages.first.tags
    except (tifffile.TiffFileError, IndexError, OSError, ValueError) as exc:
        raise RawFormatError(f"corrupt TIFF/DNG structure ({exc or type(exc).__name__})", path) from exc
    with tif:
        if _DNG_VERSION not in tags:
            raise RawFormatError("a TIFF file but not a DNG raw image (no DNGVersion tag)", path)
        for code, key in ((271, "make"), (272, "model"), (_UNIQUE_MODEL, "unique_camera_model")):
            if code in tags:
                meta[key] = str(tags[code].value).strip("\x00 ")
        if _EXPOSURE_TIME in tags:
            num, den = tags[_EXPOSURE_TIME].value
            meta["exposure_time_s"] = num / den if den else None
        if _ISO in tags:
            iso = tags[_ISO].value
            meta["iso"] = int(iso[0] if isinstance(iso, tuple) else iso)
        if _AS_SHOT_NEUTRAL in tags:
            v = tags[_AS_SHOT_NEUTRAL].value
            meta["as_shot_neutral"] = [v[i] / v[i + 1] for i in range(0, len(v), 2)]
        if 270 in tags:
            try:
                extra = json.loads(tags[270].value)
            except (TypeError, ValueError):
                extra = None
            if isinstance(extra, dict) and isinstance(extra.get(_METADATA_KEY), dict):
                meta.update(extra[_METADATA_KEY])
    return meta


def read_dng(path: str | os.PathLike[str]) -> RawImage:
    """Read a DNG file's Bayer mosaic and metadata.

    Parameters
    ----------
    path : path-like
        A DNG file (picamera2's ``save_dng``, PiDNG, any camera's DNG, or :func:`write_dng`).

    Returns
    -------
    RawImage
        Mosaic of the visible area, the CFA pattern and per-site black levels as LibRaw reports them.

    Examples
    --------
    >>> raw = read_dng("white.dng")  # doctest: +SKIP
    >>> raw.pattern, raw.black_level  # doctest: +SKIP
    ('BGGR', (64.0, 64.0, 64.0, 64.0))
    """
    import rawpy

    path = Path(path)
    meta = _tag_metadata(path)
    try:
        with rawpy.imread(str(path)) as rp:
            if rp.raw_pattern is None or rp.num_colors != 3:
                raise RawFormatError("not a Bayer raw image (LibRaw finds no 2x2 colour filter pattern)", path)
            bayer = np.array(rp.raw_image_visible, dtype=np.uint16, copy=True)
            desc = rp.color_desc.decode("ascii")
            # The colours of the visible area's first 2x2 block (raw_pattern refers to the uncropped sensor).
            cfa = rp.raw_colors_visible[:2, :2]
            pattern = "".join(desc[i] for i in cfa.ravel())
            per_channel = list(rp.black_level_per_channel)
            black = tuple(float(per_channel[i]) for i in cfa.ravel())
            white = int(rp.white_level)
    except (rawpy.LibRawError, OSError) as exc:
        raise RawFormatError(f"LibRaw cannot read it as a raw image ({type(exc).__name__}: {exc})", path) from exc
    if pattern not in PATTERNS:
        raise RawFormatError(f"unsupported colour filter pattern {pattern!r}", path)
    if bayer.shape[0] % 2 or bayer.shape[1] % 2:
        bayer = bayer[: bayer.shape[0] // 2 * 2, : bayer.shape[1] // 2 * 2]
    meta["format"] = "dng"
    meta["path"] = str(path)
    sensor = (
        meta.pop("sensor", None)
        or find_sensor_name(meta.get("unique_camera_model"))
        or find_sensor_name(meta.get("model"))
    )
    return RawImage(bayer, pattern, black, white, max(int(white).bit_length(), 8), sensor, meta)  # type: ignore[arg-type]


def _rational(value: float) -> tuple[int, int]:
    f = Fraction(value).limit_denominator(1_000_000)
    return f.numerator, f.denominator


def write_dng(path: str | os.PathLike[str], raw: RawImage, overwrite: bool = True) -> Path:
    """Write a RawImage as an uncompressed DNG 1.4 file that LibRaw reads back bit-exactly.

    The sensor name goes in ``UniqueCameraModel``, the exposure in ``ExposureTime`` and ``ISO``,
    and the remaining JSON-serialisable metadata in ``ImageDescription``. The file is written to a
    temporary name and renamed.

    Examples
    --------
    >>> from picamcal.simulate import simulate_references  # doctest: +SKIP
    >>> write_dng("white.dng", simulate_references("imx219")["white"])  # doctest: +SKIP
    """
    path = Path(path)
    meta = {k: v for k, v in raw.metadata.items() if k not in ("path", "format")}
    model = raw.sensor or str(meta.get("model", "unknown"))
    tags: list[tuple[int, int, int, Any, bool]] = [
        (_CFA_REPEAT_DIM, 3, 2, (2, 2), True),
        (_CFA_PATTERN, 1, 4, bytes(_CFA_CODES[c] for c in raw.pattern), True),
        (_DNG_VERSION, 1, 4, bytes((1, 4, 0, 0)), True),
        (_DNG_BACKWARD, 1, 4, bytes((1, 1, 0, 0)), True),
        (_UNIQUE_MODEL, 2, 0, model, True),
        (_BLACK_REPEAT_DIM, 3, 2, (2, 2), True),
        (_BLACK_LEVEL, 5, 4, tuple(v for b in raw.black_level for v in _rational(b)), True),
        (_WHITE_LEVEL, 4, 1, int(raw.white_level), True),
        # An identity ColorMatrix1 with a D65 illuminant: the mosaic is camera RGB, not calibrated colour.
        (_COLOR_MATRIX1, 10, 9, tuple(v for i in range(9) for v in ((1, 1) if i % 4 == 0 else (0, 1))), True),
        (_AS_SHOT_NEUTRAL, 5, 3, (1, 1, 1, 1, 1, 1), True),
        (_ILLUMINANT1, 3, 1, 21, True),
        (271, 2, 0, str(meta.get("make", "Raspberry Pi")), True),
        (272, 2, 0, model, True),
    ]
    if meta.get("exposure_time_s"):
        tags.append((_EXPOSURE_TIME, 5, 1, _rational(float(meta["exposure_time_s"])), True))
    if meta.get("analogue_gain"):
        tags.append((_ISO, 3, 1, round(100 * float(meta["analogue_gain"])), True))
    description = json.dumps({_METADATA_KEY: {"sensor": raw.sensor, **meta}}, default=json_default)
    with atomic_path(path, overwrite=overwrite) as tmp:
        tifffile.imwrite(
            tmp,
            raw.bayer,
            photometric=32803,  # CFA
            compression=None,
            planarconfig=None,
            description=description,
            software="picamcal",
            metadata=None,
            extratags=tags,
        )
    return path
