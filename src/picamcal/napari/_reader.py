"""napari's reader of picamcal's files (npe2 command ``picamcal.get_reader``): raw frames, calibrations, folders.

napari asks :func:`get_reader` about every file whose name matches the manifest's patterns (``*.dng``, ``*.jpg``,
``*.npy``, ``*.npz``, ``*.raw``, ...) and about folders. It answers from the file's first bytes, as
:func:`picamcal.read_raw` tells formats apart (:func:`recognise`: a few bytes, a zip's member names, the four bytes
where a legacy raw block starts), so that asking costs nothing; a file that is none of picamcal's (a plain JPEG
photo, a NumPy array without picamera2's sidecar, another program's ``.npz``) gets None, quietly, and another
reader takes it.

What it returns reads the file: a raw frame as its linear RGB and its mosaic (:func:`._layers.raw_layers`), a
calibration as its maps (:func:`._layers.calibration_layers`), a folder of frames (or the files napari opens as a
stack) as one stack of each (:func:`._layers.stack_layers`). A headless dump, and a frame whose black level nothing
gives, ask for their options in a dialog (:mod:`._dialog`). A file of picamcal's that cannot be read shows picamcal's
one-line error (the command line's) in napari's notification area and opens nothing: the reader returns npe2's
"nothing to show" (``[(None,)]``), so napari neither tries another reader nor raises a traceback at the user. The
warnings reading gives are shown there too, and kept in the layers' metadata.
"""

from __future__ import annotations

import os
import warnings
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..errors import PicamcalError, PicamcalWarning, RawFormatError
from ._layers import calibration_layers, check_stack_frame, raw_layers, stack_layers

__all__ = ["CALIBRATION", "HEADLESS", "NOTHING", "RAW", "get_reader", "read", "recognise"]

#: What :func:`recognise` makes of a file: a raw frame :func:`picamcal.read_raw` reads by itself, a picamcal
#: calibration, or a headless dump (which needs its options).
RAW, CALIBRATION, HEADLESS = "raw", "calibration", "headless"
#: npe2's "read, and nothing to show": after an error shown in the notification area, or a dialog cancelled.
NOTHING: list[tuple[Any, ...]] = [(None,)]
#: The zip members that make an ``.npz`` a calibration (:mod:`picamcal.calibration.archive`).
_CALIBRATION_MEMBERS = {"metadata.npy", "site_white.npy"}
_HEAD_BYTES = 8

ReaderFunction = Callable[[str | Sequence[str]], list[tuple[Any, ...]]]


def recognise(path: str | os.PathLike[str]) -> str | None:
    """What picamcal makes of a file from its first bytes: :data:`RAW`, :data:`CALIBRATION`, :data:`HEADLESS`, or
    None for a file that is not one of picamcal's (or cannot be looked at).

    Never reads more than a few kilobytes: the first 8 bytes (a TIFF, JPEG, zip or ``.npy`` signature, as
    :func:`picamcal.read_raw` tells them apart); for a TIFF not named ``.dng``, its first IFD (a DNG has
    DNGVersion); for a JPEG, the 4 bytes where a legacy raw block of each known size would start (a JPEG without
    one is a photo); for a zip, its member names (picamcal's raw ``.npz`` or a calibration); for a ``.npy``, whether
    picamera2's JSON sidecar is beside it. A file with no signature named ``.raw`` or ``.bin`` is a headless dump.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> _ = picamcal.write_dng("white.dng", white)
    >>> _ = Path("notes.txt").write_text("focus at 3 mm")
    >>> _ = Path("frame.raw").write_bytes(bytes(1000))
    >>> recognise("white.dng"), recognise("notes.txt"), recognise("frame.raw"), recognise("missing.dng")
    ('raw', None, 'headless', None)
    """
    from ..raw import HEADLESS_SUFFIXES
    from ..raw.brcm import is_brcm, is_jpeg
    from ..raw.dng import is_dng
    from ..raw.npy import is_npy
    from ..raw.npz import is_npz

    path = Path(path)
    try:
        if not path.is_file():
            return None
        with open(path, "rb") as f:
            head = f.read(_HEAD_BYTES)
    except OSError:
        return None
    if not head:
        return None
    if is_dng(head):
        return RAW if path.suffix.lower() == ".dng" or _has_dng_version(path) else None
    if is_jpeg(head):
        return RAW if _has_raw_block(path) else None
    if is_brcm(head):  # a legacy raw block on its own
        return RAW
    if is_npz(head):
        return _zip_kind(path)
    if is_npy(head):
        return RAW if path.with_suffix(".json").is_file() else None
    return HEADLESS if path.suffix.lower() in HEADLESS_SUFFIXES else None


def _has_dng_version(path: Path) -> bool:
    """Whether a TIFF's first IFD has a DNGVersion tag (what makes it a DNG), reading that IFD alone."""
    from ..raw.dng.tags import BYTE, DNG_VERSION
    from ..raw.dng.tiff import TiffFile

    try:
        with open(path, "rb") as f:
            tiff = TiffFile(f, os.fstat(f.fileno()).st_size, path)
            return tiff.tag(tiff.ifd(tiff.first_ifd, "IFD 0"), DNG_VERSION, (BYTE,), 4) is not None
    except (OSError, PicamcalError):
        return False


def _has_raw_block(path: Path) -> bool:
    """Whether a JPEG ends with a legacy raw (BRCM) block of a known size: where :func:`picamcal.read_raw` looks."""
    from ..raw.brcm import _IDENT, _block_sizes

    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            for block in _block_sizes():
                if block <= size:
                    f.seek(size - block)
                    if f.read(len(_IDENT)) == _IDENT:
                        return True
    except OSError:
        return False
    return False


def _zip_kind(path: Path) -> str | None:
    """A zip's kind from its member names: picamcal's raw ``.npz``, a calibration, or None (another program's). A
    zip whose directory cannot be read (truncated) named ``.npz`` is taken as picamcal's raw, for its error."""
    from ..raw.npz import is_raw_npz

    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
    except (OSError, zipfile.BadZipFile, ValueError, EOFError):
        return RAW if path.suffix.lower() == ".npz" else None
    if _CALIBRATION_MEMBERS <= names:
        return CALIBRATION
    return RAW if is_raw_npz(path) else None


def _folder_frames(folder: Path, first_only: bool = False) -> list[Path]:
    """The raw frames of a folder, sorted by name: its files that :func:`recognise` takes as :data:`RAW` (not its
    calibrations, headless dumps, sidecars, plain photos); with ``first_only``, at most the first."""
    frames = []
    try:
        entries = sorted(p for p in folder.iterdir() if not p.name.startswith("."))
    except OSError:
        return []
    for entry in entries:
        if recognise(entry) == RAW:
            frames.append(entry)
            if first_only:
                break
    return frames


def get_reader(path: str | Sequence[str]) -> ReaderFunction | None:
    """napari's question: a reader for ``path`` if it is picamcal's, else None (quietly, for another reader).

    ``path`` is a file, a folder (its raw frames as a stack) or a list of files napari opens as a stack (all raw
    frames). Deciding reads a few bytes of each file (:func:`recognise`), and of a folder's files only up to its
    first raw frame.

    Examples
    --------
    >>> _ = Path("notes.txt").write_text("focus at 3 mm")
    >>> get_reader("notes.txt") is None
    True
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> reader = get_reader(str(picamcal.write_dng("white.dng", white)))
    >>> [kwargs["name"] for _, kwargs, _ in reader("white.dng")]
    ['white', 'white (raw)']
    """
    if not isinstance(path, (str, os.PathLike)):
        paths = [Path(p) for p in path]
        if len(paths) == 1:
            return get_reader(str(paths[0]))
        return read if paths and all(recognise(p) == RAW for p in paths) else None
    target = Path(path)
    if target.is_dir():
        return read if _folder_frames(target, first_only=True) else None
    return read if recognise(target) is not None else None


def read(path: str | Sequence[str]) -> list[tuple[Any, ...]]:
    """Read what :func:`get_reader` took: the layers, or :data:`NOTHING` after an error (shown in napari's
    notification area as picamcal's one line) or a cancelled dialog. The warnings reading gave are shown there too.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> Path("run").mkdir()
    >>> for role in ("white", "red"):
    ...     _ = picamcal.write_dng(f"run/{role}.dng", refs[role])
    >>> [(kwargs["name"], data.shape) for data, kwargs, _ in read("run")]  # a folder: one stack of each
    [('run', (2, 240, 320, 3)), ('run (raw)', (2, 240, 320))]
    """
    said: list[str] = []
    try:
        if not isinstance(path, (str, os.PathLike)):
            paths = [Path(p) for p in path]
            return _read_stack(paths, paths[0].parent.name or paths[0].stem, said)
        target = Path(path)
        if target.is_dir():
            return _read_stack(_folder_frames(target), target.name, said)
        return _read_file(target, said)
    except _Cancelled:
        return NOTHING
    except PicamcalError as exc:
        show("error", str(exc))
        return NOTHING
    finally:
        for text in said:
            show("warning", text)


class _Cancelled(Exception):
    """The user cancelled a dialog the file needed: nothing is opened, nothing said."""


def show(kind: str, message: str) -> None:
    """Show ``message`` in napari's notification area: ``kind`` ``"error"``, ``"warning"`` or ``"info"``."""
    from napari.utils import notifications

    if kind == "error":
        notifications.show_error(message)
    elif kind == "warning":
        notifications.show_warning(message)
    else:
        notifications.show_info(message)


def _collecting(said: list[str], call: Callable[[], Any]) -> Any:
    """``call()``, the text of each PicamcalWarning it gives added to ``said`` (once); other warnings pass on."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return call()
        finally:
            others = []
            for warning in caught:
                if not issubclass(warning.category, PicamcalWarning):
                    others.append(warning)
                elif str(warning.message) not in said:
                    said.append(str(warning.message))
    for warning in others:  # outside catch_warnings: shown (or not) as the caller's filters say
        warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)


def _read_file(path: Path, said: list[str]) -> list[tuple[Any, ...]]:
    kind = recognise(path)
    if kind == CALIBRATION:
        from ..calibration import load_calibration

        calibration = _collecting(said, lambda: load_calibration(path))
        if not calibration.has_unmixing:
            show("info", f"{path}: a flat-field calibration (a white alone): its flat field only, no unmixing")
        return calibration_layers(calibration, path.stem)
    options: dict[str, Any] = {}
    if kind == HEADLESS:
        options = _ask_headless(path)
    raw = _read_raw(path, options, said)
    return raw_layers(raw, path.stem, warnings=said, read_options=options)


def _ask_headless(path: Path) -> dict[str, Any]:
    from ..raw import headless_hint
    from . import _dialog

    hint = headless_hint(path).removeprefix("; ")
    reason = f"{path.name}: no header says what its bytes are: {hint or 'a headless dump (rpicam-raw)?'}"
    answers = _dialog.ask_read_options(_dialog.Request(path, _dialog.HEADLESS, reason, _dialog.headless_defaults(path)))
    if answers is None:
        raise _Cancelled
    return answers


def _read_raw(path: Path, options: dict[str, Any], said: list[str]) -> Any:
    """read_raw with ``options``; a frame whose black level nothing gives asks for it (updating ``options``, so the
    frames after it in a stack take the same). Its warnings are added to ``said`` (:func:`_collecting`)."""
    from ..raw import read_raw
    from ..raw.model import require_black_level

    def reading() -> Any:
        return _collecting(said, lambda: read_raw(path, **options))

    raw = reading()
    try:
        require_black_level(raw)
    except RawFormatError as exc:
        options.update(_ask_black_level(path, exc.problem, required=True))
        return reading()
    if raw.metadata.get("black_level_source") == "DNG default" and "black_level" not in options:
        suggested = _suggested_black_level(raw, said)
        if suggested is not None:
            answers = _ask_black_level(path, suggested[1], required=False, default=suggested[0])
            if answers:
                options.update(answers)
                return reading()
    return raw


def _suggested_black_level(raw: Any, said: list[str]) -> tuple[str, str] | None:
    """The level a DNG without a BlackLevel tag is warned to take (``pass --black-level N``), and the warning (less
    the file's name, which the dialog gives)."""
    import re

    for text in said:
        if text.startswith(f"{raw.source}: ") and (found := re.search(r"--black-level (\S+)$", text)):
            return found[1], text.removeprefix(f"{raw.source}: ")
    return None


def _ask_black_level(path: Path, reason: str, *, required: bool, default: str = "") -> dict[str, Any]:
    from . import _dialog

    request = _dialog.Request(path, _dialog.BLACK_LEVEL, f"{path.name}: {reason}", {"black_level": default}, required)
    answers = _dialog.ask_read_options(request)
    if answers is None:
        if required:
            raise _Cancelled
        return {}
    return answers


def _read_stack(paths: list[Path], name: str, said: list[str]) -> list[tuple[Any, ...]]:
    """Frames of one size as one stack; the first of another size is refused, naming it, before the rest is read."""
    if not paths:
        raise PicamcalError("no raw frames to open as a stack")
    options: dict[str, Any] = {}
    raws: list[Any] = []
    for path in paths:
        raw = _read_raw(path, options, said)
        if raws:
            check_stack_frame(raw, raws[0])
        raws.append(raw)
    if len(raws) == 1:
        return raw_layers(raws[0], paths[0].stem, warnings=said, read_options=options)
    return stack_layers(raws, name, warnings=said, read_options=options)
