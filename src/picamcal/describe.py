"""What a file is: the record ``picamcal inspect`` prints."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .errors import PicamcalError, RawFormatError
from .manifest import FRAME_FORMAT, MANIFEST_FORMAT
from .raw import RawImage, read_raw
from .raw.picamera2 import SIDECAR_FORMAT
from .raw.processed import read_processed

_METADATA_KEYS = ("exposure_time_s", "analogue_gain", "digital_gain", "iso", "make", "model", "legacy_mode")


def describe(path: str | Path, read: Callable[[Path], RawImage] = read_raw) -> dict[str, Any]:
    """A JSON-serialisable description of a raw or processed image file.

    Raw files give format, sensor, size, Bayer pattern, bit depth, black and white levels and the
    exposure metadata; a file that is not raw but is an image (a JPEG without a raw block, a PNG) is
    described as processed. Anything else raises the reader's error.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, render
    >>> _ = picamcal.write_dng("white.dng", render(make_camera("imx219", size=(64, 48)), "white", rng=1))
    >>> record = describe("white.dng")
    >>> record["format"], record["sensor"], record["width"], record["height"], record["pattern"], record["bit_depth"]
    ('dng', 'imx219', 64, 48, 'BGGR', 10)
    """
    path = Path(path)
    try:
        raw = read(path)
    except RawFormatError as raw_error:
        try:
            image = read_processed(path, "linear")
        except RawFormatError:
            raise raw_error from None
        return {
            "path": str(path),
            "format": f"processed {image.metadata['format']}",
            "raw": False,
            "width": image.width,
            "height": image.height,
            "bit_depth": image.bit_depth,
            "note": str(raw_error.problem),
            **{k: _plain(image.metadata[k]) for k in _METADATA_KEYS if k in image.metadata},
        }
    record: dict[str, Any] = {
        "path": str(path),
        "format": raw.metadata.get("format", "?"),
        "raw": True,
        "sensor": raw.sensor,
        "width": raw.width,
        "height": raw.height,
        "pattern": raw.pattern,
        "bit_depth": raw.bit_depth,
        "black_level": list(raw.black_level),
        "white_level": raw.white_level,
    }
    keys = (*_METADATA_KEYS, "declared_pattern", "frames")
    record.update({k: _plain(raw.metadata[k]) for k in keys if k in raw.metadata})
    return record


def _plain(value: Any) -> Any:
    """A file's metadata value as plain JSON types (numbers, text, lists): what a file says is shown, whatever it is.

    Examples
    --------
    >>> _plain([np.float32(0.5), b"RP_imx219"])
    [0.5, "b'RP_imx219'"]
    """
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (np.generic, np.ndarray)):
        return _plain(value.tolist())
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    return str(value)


_JSON_KINDS = {
    SIDECAR_FORMAT: "JSON sidecar of a picamera2 raw buffer",
    MANIFEST_FORMAT: "acquisition manifest (picamcal acquire)",
    FRAME_FORMAT: "JSON sidecar of an acquired frame",
}
#: JSON files larger than this are not parsed to say what they are.
_MAX_JSON_BYTES = 16 << 20


def what_else(path: Path) -> str | None:
    """What a file that is not an image is, when picamcal knows: a calibration, a sidecar, a tuning file, ...

    Examples
    --------
    >>> _ = Path("manifest.json").write_text('{"format": "picamcal-acquisition", "version": 1}')
    >>> what_else(Path("manifest.json"))
    'acquisition manifest (picamcal acquire)'
    >>> _ = Path("notes.txt").write_text("focus at 3 mm")
    >>> what_else(Path("notes.txt")) is None
    True
    """
    import json

    from .raw.npz import is_raw_npz

    try:
        with open(path, "rb") as f:
            head = f.read(1) if os.fstat(f.fileno()).st_size <= _MAX_JSON_BYTES else b""
    except OSError:
        return None
    if path.suffix.lower() == ".npz" and not is_raw_npz(path):
        from .calibration import load_calibration

        try:
            cal = load_calibration(path)
        except PicamcalError:
            import zipfile

            return "NumPy .npz archive (not a raw image or a calibration)" if zipfile.is_zipfile(path) else None
        return f"picamcal calibration ({cal.sensor or 'unknown sensor'} {cal.width}x{cal.height})"
    if head not in (b"{", b"["):
        return None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(record, dict):
        return "JSON file"
    if isinstance(record.get("format"), str) and record["format"] in _JSON_KINDS:
        return _JSON_KINDS[record["format"]]
    if "algorithms" in record and "target" in record:
        return f"libcamera tuning file ({record['target']})"
    if "wheels" in record:
        return "colour-wheel target layout"
    return "JSON file"


def survey(path: str | Path, read: Callable[[Path], RawImage] = read_raw) -> dict[str, Any]:
    """:func:`describe` for any file, never raising: what is not an image is named, what cannot be read says why.

    The record has ``"readable": False`` and an ``"error"`` for a file picamcal cannot read; a file that is not
    an image but that picamcal knows (a calibration, a JSON sidecar, a manifest, a tuning file) is readable,
    with its ``"format"`` saying what it is.

    Examples
    --------
    >>> _ = Path("manifest.json").write_text('{"format": "picamcal-acquisition", "version": 1}')
    >>> survey("manifest.json")["format"]
    'acquisition manifest (picamcal acquire)'
    >>> _ = Path("notes.txt").write_text("focus at 3 mm")
    >>> record = survey("notes.txt")
    >>> record["readable"], record["error"]
    (False, 'not a raw image format picamcal reads (DNG, JPEG+raw, picamera2 .npy or picamcal .npz)')
    """
    path = Path(path)
    other = what_else(path) if path.is_file() else None
    if other is not None:
        return {"path": str(path), "format": other, "raw": False, "readable": True}
    try:
        return {**describe(path, read), "readable": True}
    except PicamcalError as exc:
        record = {"path": str(path), "format": "-", "raw": False, "readable": False, "error": exc.problem}
        if exc.path not in (None, str(path)):  # the problem is in another file, e.g. the sidecar
            record["error_path"] = exc.path
        return record


def files_of(items: list[Path]) -> list[Path]:
    """Files to inspect: each file as given, and every file of each folder (sorted, not hidden, not recursive).

    Examples
    --------
    >>> Path("run1").mkdir()
    >>> for name in ("white.dng", "black.dng", ".hidden"):
    ...     _ = (Path("run1") / name).write_bytes(b"")
    >>> [path.as_posix() for path in files_of([Path("run1"), Path("extra.dng")])]
    ['run1/black.dng', 'run1/white.dng', 'extra.dng']
    """
    found: list[Path] = []
    for item in items:
        if item.is_dir():
            found.extend(sorted(p for p in item.iterdir() if not p.name.startswith(".") and p.is_file()))
        else:
            found.append(item)
    return found
