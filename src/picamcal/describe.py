"""What a file is: the record ``picamcal inspect`` prints."""

from __future__ import annotations

import functools
import math
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import entry_kind, passed_over_message
from .calibrate import MAX_CLIPPED_FRACTION
from .errors import PicamcalError, PicamcalWarning, RawFormatError
from .manifest import FRAME_FORMAT, MANIFEST_FORMAT
from .raw import HEADLESS_SUFFIXES, PROCESSED_SUFFIXES, RAW_SUFFIXES, RawImage, read_raw
from .raw.model import raw_geometry, require_black_level
from .raw.picamera2 import SIDECAR_FORMAT
from .raw.processed import read_processed

_METADATA_KEYS = ("exposure_time_s", "analogue_gain", "digital_gain", "iso", "make", "model", "legacy_mode")
#: A raw frame whose median signal over black is below this fraction of the range from black to white is a dark
#: frame: at black but for its noise (a dark frame's median sits within a few DN of black; a white reference
#: calibrate takes is at least :data:`picamcal.calibrate.REFUSE_WHITE_FRACTION` of the range).
DARK_FRACTION = 0.01


def describe(path: str | Path, read: Callable[[Path], RawImage] = read_raw) -> dict[str, Any]:
    """A JSON-serialisable description of a raw or processed image file.

    Raw files give format, sensor, size, Bayer pattern, bit depth, black and white levels, the exposure metadata,
    the signal (``signal_dn``: the median DN over black, None where the black level is unknown; ``dark``: whether
    it is below :data:`DARK_FRACTION` of the range, a dark frame), the fraction of pixels at the white level
    (``clipped_fraction``) and ``notes``: what looks wrong, each with what to do (an unknown black level; more pixels
    clipped than calibrate takes in a white reference, :data:`picamcal.calibrate.MAX_CLIPPED_FRACTION`). A file that
    is not raw but is an image (a JPEG without a raw block, a PNG) is described as processed. Anything else raises
    the reader's error.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, render
    >>> _ = picamcal.write_dng("white.dng", render(make_camera("imx219", size=(64, 48)), "white", rng=1))
    >>> record = describe("white.dng")
    >>> record["format"], record["sensor"], record["width"], record["height"], record["pattern"], record["bit_depth"]
    ('dng', 'imx219', 64, 48, 'BGGR', 10)
    >>> record["clipped_fraction"], record["notes"], record["dark"], record["signal_dn"] > 100
    (0.0, [], False, True)
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
    geometry = raw_geometry(raw)
    record.update(sensor_mode=geometry.describe(), geometry=geometry.to_record())
    clipped = int(np.count_nonzero(raw.bayer >= raw.white_level)) / raw.bayer.size
    signal = signal_over_black(raw)
    dark = signal is not None and signal < DARK_FRACTION * (raw.white_level - float(np.median(raw.black_level)))
    record.update(signal_dn=signal, dark=dark, clipped_fraction=clipped, notes=[])
    if not all(np.isfinite(raw.black_level)):
        record["notes"].append(_unknown_black_level(raw))
    if clipped > MAX_CLIPPED_FRACTION:
        record["notes"].append(
            f"{100 * clipped:.3g} % of its pixels are at the white level ({raw.white_level}): as a white reference "
            f"calibrate refuses it (it takes up to {100 * MAX_CLIPPED_FRACTION:g} %); reduce the exposure"
        )
    return record


def signal_over_black(raw: RawImage) -> float | None:
    """The median of a raw frame's pixels over their site's black level, in DN; None where the level is unknown.

    Taken on every 4th 2x2 block each way (all four sites, a sixteenth of the pixels: a 12 MP frame's costs a few
    milliseconds; the median of so many is known to a fraction of a DN).

    Examples
    --------
    >>> bayer = np.full((8, 8), 164, np.uint16)
    >>> signal_over_black(RawImage(bayer, "BGGR", 64, 1023, 10))
    100.0
    >>> signal_over_black(RawImage(bayer, "BGGR", float("nan"), 1023, 10)) is None
    True
    """
    if not np.all(np.isfinite(raw.black_level)):
        return None
    sites = [
        raw.bayer[sy::2, sx::2][::4, ::4].astype(np.float32) - np.float32(raw.black_level[2 * sy + sx])
        for sy in (0, 1)
        for sx in (0, 1)
    ]
    return float(np.median(np.concatenate([site.ravel() for site in sites])))


def _unknown_black_level(raw: RawImage) -> str:
    """Why a raw image's black level is unknown, and what gives it (the fix :func:`require_black_level` names)."""
    why = "headless dumps carry none" if raw.metadata.get("format") == "headless" else "the file records none"
    try:
        require_black_level(raw)
    except RawFormatError as exc:
        return f"black level unknown: {why}; {exc.problem.rsplit('; ', 1)[-1]}"
    return f"black level unknown: {why}"


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


def _read_once(path: Path, reader: Any) -> Any:
    """``reader(path)`` read once as long as the file is unchanged (for what :func:`what_else` and :func:`survey`
    say of it), or None if it cannot be looked at."""
    try:
        stat = path.stat()
    except OSError:
        return None
    return _read_cached(reader, str(path), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=8)
def _read_cached(reader: Any, path: str, mtime_ns: int, size: int) -> Any:
    return reader(path)


def _load_or_none(path: str) -> Any:
    from .calibration import load_calibration

    try:
        return load_calibration(path)
    except PicamcalError:
        return None


def _calibration(path: Path) -> Any:
    """The calibration at ``path``, or None."""
    return _read_once(path, _load_or_none)


def _shading_table(path: Path) -> dict[str, Any] | None:
    """:func:`picamcal.export.tables.inspect_table` of the file."""
    from .export.tables import inspect_table

    return _read_once(path, inspect_table)


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
    table = _shading_table(path)
    if table is not None and table["readable"]:  # a lens shading table a user has: what export-tuning takes
        return table["format"]
    if path.suffix.lower() == ".npz" and not is_raw_npz(path):
        cal = _calibration(path)
        if cal is None:
            import zipfile

            return (
                "NumPy .npz archive (not a raw image, a calibration or an OpenFlexure lens shading table)"
                if zipfile.is_zipfile(path)
                else None
            )
        about = [f"{cal.sensor or 'unknown sensor'} {cal.width}x{cal.height}"]
        if cal.kind == "flat":
            about.append("a flat field from a white")
        if cal.light:
            about.append(f"light: {cal.light}")  # the workflow whose accuracy the report expects
        return f"picamcal calibration ({', '.join(about)})"
    if head not in (b"{", b"["):
        return None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        from ._json import read_libcamera_yaml

        try:  # a tuning file with what libcamera's YAML parser takes and JSON does not (a trailing comma)
            record = read_libcamera_yaml(path, PicamcalError, "JSON")
        except PicamcalError:
            return None
        if not isinstance(record, dict) or "algorithms" not in record:
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


#: What :func:`survey` calls a file that is no image and nothing else picamcal knows (notes, a README, a CSV).
NOT_AN_IMAGE = "not an image"
#: Suffixes of the images picamcal reads: a file with one of them that cannot be read is an image gone wrong.
IMAGE_SUFFIXES = frozenset((*RAW_SUFFIXES, *PROCESSED_SUFFIXES, *HEADLESS_SUFFIXES))


def survey(path: str | Path, read: Callable[[Path], RawImage] = read_raw) -> dict[str, Any]:
    """:func:`describe` for any file, never raising: what is not an image is named, what cannot be read says why.

    The record has ``"readable": False`` and an ``"error"`` for a file picamcal cannot read; a file that is not
    an image but that picamcal knows (a calibration, a JSON sidecar, a manifest, a tuning file) is readable,
    with its ``"format"`` saying what it is; any other file that is not an image (no image's suffix, no image's
    content: notes, a ``MANIFEST.md``) is readable too, as :data:`NOT_AN_IMAGE`, the reader's error its ``"reason"``.

    Examples
    --------
    >>> _ = Path("manifest.json").write_text('{"format": "picamcal-acquisition", "version": 1}')
    >>> survey("manifest.json")["format"]
    'acquisition manifest (picamcal acquire)'
    >>> _ = Path("notes.txt").write_text("focus at 3 mm")
    >>> record = survey("notes.txt")
    >>> record["readable"], record["format"], record["reason"]
    (True, 'not an image', 'not a raw image format picamcal reads (DNG, JPEG+raw, picamera2 .npy or picamcal .npz)')
    >>> _ = Path("broken.dng").write_text("focus at 3 mm")
    >>> survey("broken.dng")["readable"]
    False
    """
    path = Path(path)
    table = _shading_table(path) if path.is_file() else None
    if table is not None:  # a lens shading table, or one that does not read (why)
        return {"path": str(path), "raw": False, **table}
    other = what_else(path) if path.is_file() else None
    if other is not None:
        record = {"path": str(path), "format": other, "raw": False, "readable": True}
        cal = _calibration(path) if other.startswith("picamcal calibration") else None
        if cal is not None and cal.geometry is not None:
            record.update(sensor_mode=cal.geometry.describe(), geometry=cal.geometry.to_record())
        return record
    try:
        return {**describe(path, read), "readable": True}
    except PicamcalError as exc:
        if path.is_file() and path.suffix.lower() not in IMAGE_SUFFIXES and exc.path in (None, str(path)):
            return {"path": str(path), "format": NOT_AN_IMAGE, "raw": False, "readable": True, "reason": exc.problem}
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
    passed_over: dict[Path, list[str]] = {}
    images = (*RAW_SUFFIXES, *HEADLESS_SUFFIXES, *PROCESSED_SUFFIXES)
    for item in items:
        if item.is_dir():
            for entry in sorted(p for p in item.iterdir() if not p.name.startswith(".")):
                if entry.is_file():
                    found.append(entry)
                elif entry.suffix.lower() in images:  # a dangling link or a FIFO named as an image: said, not read
                    passed_over.setdefault(item, []).append(f"{entry.name} ({entry_kind(entry)})")
        else:
            found.append(item)
    if passed_over:
        warnings.warn(passed_over_message(passed_over), PicamcalWarning, stacklevel=2)
    return found


def _nothing(folder: Path) -> str:
    """What a folder holds when it holds no file to list: nothing, or only hidden entries and folders (named)."""
    try:
        names = sorted(entry.name for entry in os.scandir(folder))
    except OSError:
        names = []
    if not names:
        return "it is empty"
    listed = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
    return f"it holds only hidden files and folders ({listed}), which are not read"


def inspect_files(items: list[Path], read: Callable[[Path], RawImage] = read_raw) -> list[dict[str, Any]]:
    """What ``picamcal inspect`` lists: :func:`survey` of each file as given and of every file of each folder, each
    record with the ``"warnings"`` reading it gave (without the file's name, which the listing shows).

    Raises
    ------
    PicamcalError
        A folder with no images: empty, or holding only files that are not images (:data:`NOT_AN_IMAGE`); or one
        file given alone that cannot be read or is not an image (as every command says of its one file).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, render
    >>> Path("run1").mkdir()
    >>> _ = picamcal.write_dng("run1/white.dng", render(make_camera("imx219", size=(64, 48)), "white", rng=1))
    >>> _ = Path("run1/MANIFEST.md").write_text("# white, 1 ms")
    >>> [(Path(r["path"]).name, r["format"], r["readable"]) for r in inspect_files([Path("run1")])]
    [('MANIFEST.md', 'not an image', True), ('white.dng', 'dng', True)]
    >>> Path("empty").mkdir()
    >>> inspect_files([Path("empty")])
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: empty: no images in this folder: it is empty
    """
    records: list[dict[str, Any]] = []
    for item in items:
        found = []
        for path in files_of([item]):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                record = survey(path, read)
            record["warnings"] = [
                str(w.message).removeprefix(f"{path}: ") for w in caught if issubclass(w.category, PicamcalWarning)
            ]
            found.append(record)
        others = [Path(r["path"]).name for r in found if r["format"] == NOT_AN_IMAGE]
        if item.is_dir() and len(others) == len(found):
            listed = ", ".join(others[:3]) + (f" and {len(others) - 3} more" if len(others) > 3 else "")
            what = (
                f"only {len(others)} other file{'s' if len(others) > 1 else ''}: {listed}" if others else _nothing(item)
            )
            raise PicamcalError(f"no images in this folder: {what}", item)
        records += found
    if len(items) == 1 and not items[0].is_dir():
        record = records[0]
        if not record["readable"]:
            raise PicamcalError(record["error"], record.get("error_path", items[0]))
        if record["format"] == NOT_AN_IMAGE:
            raise PicamcalError(record["reason"], items[0])
    return records


#: The columns of ``picamcal inspect``'s table (and a ``frames`` column where a file has several).
INSPECT_COLUMNS = ("file", "format", "sensor", "size", "sensor mode", "pattern", "bits", "black", "white", "signal",
                   "exposure", "gain")  # fmt: skip


def inspection_table(records: list[dict[str, Any]]) -> tuple[list[str], list[list[str]], list[str], set[str]]:
    """``picamcal inspect``'s table and the lines under it, for the records of :func:`inspect_files`: the columns,
    the rows (each cell as the command prints it), the lines (what could not be read, what is not raw, each note
    and warning once with the files that gave it) and which of those lines are warnings.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, render
    >>> _ = picamcal.write_dng("white.dng", render(make_camera("imx219", size=(64, 48)), "white", rng=1))
    >>> columns, rows, lines, _ = inspection_table(inspect_files([Path("white.dng")]))
    >>> dict(zip(columns, rows[0]))["size"], dict(zip(columns, rows[0]))["pattern"], lines
    ('64x48', 'BGGR', [])
    """
    several = any("frames" in r for r in records)
    columns = [*INSPECT_COLUMNS, *(["frames"] if several else [])]
    rows = []
    for r in records:
        if "width" not in r:  # not an image (a sidecar, a calibration, notes), or unreadable
            rows.append([Path(r["path"]).name, r["format"] if r["readable"] else "unreadable"])
            continue
        row = [
            Path(r["path"]).name,
            r["format"],
            r.get("sensor") or ("?" if r["raw"] else "-"),
            f"{r['width']}x{r['height']}",
            _mode_cell(r.get("geometry")),
            r.get("pattern", "-"),
            r["bit_depth"],
            _levels_cell(r.get("black_level")) if r["raw"] else "-",
            r.get("white_level", "-"),
            _signal_cell(r),
            _figure_cell(r.get("exposure_time_s"), 1e3, " ms"),
            _gain_cell(r),
            *([r.get("frames", "-")] if several else []),
        ]
        rows.append([str(cell) for cell in row])
    lines: list[str] = []
    said: dict[str, list[str]] = {}  # each note or warning, with the files that gave it, in the order first given
    for r in records:
        name = Path(r["path"]).name
        if "error" in r:
            lines.append(f"{name}: cannot read: {r['error']}")
        if "note" in r:
            lines.append(f"{name}: not raw: {r['note']}")
        if "width" not in r and "sensor_mode" in r:  # a calibration: where on the sensor it was taken
            lines.append(f"{name}: sensor mode {r['sensor_mode']}")
        for warning in [*r.get("notes", []), *r["warnings"]]:
            said.setdefault(warning, []).append(name)
    # Once each: a folder of frames of one size gives every one the same "taken as the imx296".
    warned = set()
    for warning, names in said.items():
        who = names[0] if len(names) == 1 else f"{names[0]} and {len(names) - 1} more"
        warned.add(f"{who}: {warning}")
        lines.append(f"{who}: {warning}")
    return columns, rows, lines, warned


def _mode_cell(geometry: dict[str, Any] | None) -> str:
    """A frame's sensor mode in a few characters: ``full``, ``full /2`` (binned 2 x 2), ``1920x1080@680,692``;
    ``?`` when nothing said it (the whole sensor assumed)."""
    if not geometry:
        return "-"
    x, y, w, h = geometry["crop"]
    where = "full" if [x, y, w, h] == [0, 0, *geometry["sensor_size"]] else f"{w}x{h}@{x},{y}"
    binned = f" /{geometry['binning']}" if geometry["binning"] > 1 else ""
    return f"{where}{binned}" + (" ?" if geometry["source"] == "assumed" else "")


def _levels_cell(levels: list[float] | None) -> str:
    if not levels:
        return "-"
    if not all(math.isfinite(v) for v in levels):  # the notes below the table say why
        return "unknown"
    return f"{levels[0]:g}" if len(set(levels)) == 1 else ",".join(f"{v:g}" for v in levels)


def _signal_cell(record: dict[str, Any]) -> str:
    """The median DN over black, ``dark`` for a dark frame; ``?`` where the black level is unknown."""
    if not record["raw"]:
        return "-"
    signal = record.get("signal_dn")
    if signal is None:
        return "?"
    text = f"{signal:.0f}" if abs(signal) >= 10 else f"{signal:.1f}"
    return f"{text} dark" if record.get("dark") else text


def _gain_cell(record: dict[str, Any]) -> str:
    """The analogue gain, else the ISO the file gives (legacy JPEG+raw and DNG files say that instead)."""
    if record.get("analogue_gain"):
        return _figure_cell(record["analogue_gain"])
    return f"ISO {_figure_cell(record['iso'])}" if record.get("iso") else "-"


def _figure_cell(value: Any, scale: float = 1.0, unit: str = "") -> str:
    """A number of a file's metadata as the table shows it: "-" when absent or zero, as it is when not a number."""
    if not value:
        return "-"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{scale * value:.3g}{unit}"
    return str(value)
