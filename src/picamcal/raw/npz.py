"""picamcal's own lossless raw container: a ``.npz`` holding the mosaic and a JSON record.

Arrays: ``bayer`` (uint16, H x W) and ``metadata`` (a 0-d unicode array holding JSON with
``format`` ``"picamcal-raw"``, ``version``, ``pattern``, ``black_level``, ``white_level``,
``bit_depth``, ``sensor`` and the image ``metadata``). Read with ``allow_pickle=False``.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from .._files import json_default
from ..errors import RawFormatError
from .model import RawImage

FORMAT_NAME = "picamcal-raw"
VERSION = 1


def write_npz(path: str | os.PathLike[str], raw: RawImage, overwrite: bool = True) -> Path:
    """Save a RawImage losslessly as a picamcal raw ``.npz`` (compressed, written atomically).

    Examples
    --------
    >>> write_npz("frame.npz", raw)  # doctest: +SKIP
    """
    path = Path(path)
    record = {
        "format": FORMAT_NAME,
        "version": VERSION,
        "pattern": raw.pattern,
        "black_level": list(raw.black_level),
        "white_level": int(raw.white_level),
        "bit_depth": int(raw.bit_depth),
        "sensor": raw.sensor,
        "metadata": {k: v for k, v in raw.metadata.items() if k not in ("path", "format")},
    }
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, bayer=raw.bayer, metadata=np.array(json.dumps(record, default=json_default)))
    return path


def is_raw_npz(path: str | os.PathLike[str]) -> bool:
    """True if an ``.npz`` file is a picamcal raw image (not, say, a calibration), from its member names only.

    Examples
    --------
    >>> is_raw_npz("frame.npz"), is_raw_npz("cal.npz")  # doctest: +SKIP
    (True, False)
    """
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
    except (OSError, zipfile.BadZipFile):
        return False
    return {"bayer.npy", "metadata.npy"} <= names and "unmixing.npy" not in names


def read_npz(path: str | os.PathLike[str]) -> RawImage:
    """Read a picamcal raw ``.npz`` written by :func:`write_npz`.

    Examples
    --------
    >>> read_npz("frame.npz").pattern  # doctest: +SKIP
    'BGGR'
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            if "bayer" not in data or "metadata" not in data:
                raise RawFormatError("an .npz file but not a picamcal raw image (no 'bayer' array)", path)
            bayer = np.array(data["bayer"])
            record = json.loads(str(data["metadata"]))
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise RawFormatError(f"corrupt picamcal raw file ({exc})", path) from exc
    if not isinstance(record, dict) or record.get("format") != FORMAT_NAME:
        raise RawFormatError("an .npz file but not a picamcal raw image", path)
    if record.get("version") != VERSION:
        raise RawFormatError(f"unsupported picamcal raw version {record.get('version')!r}", path)
    meta = dict(record.get("metadata") or {})
    meta.update(format="npz", path=str(path))
    try:
        return RawImage(
            bayer,
            record["pattern"],
            tuple(record["black_level"]),
            int(record["white_level"]),
            int(record["bit_depth"]),
            record.get("sensor"),
            meta,
        )
    except RawFormatError as exc:
        raise RawFormatError(exc.problem, path) from None
    except (KeyError, TypeError, ValueError) as exc:
        raise RawFormatError(f"corrupt picamcal raw record ({exc})", path) from exc
