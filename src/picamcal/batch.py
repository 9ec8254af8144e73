"""Correct many images at once: a process pool on this machine, or an existing dask.distributed cluster.

One function, :func:`run_batch`, takes files, folders or glob patterns (:func:`expand_inputs`) and
writes one image per input in one of :data:`picamcal.output.OUTPUT_FORMATS` (float32 linear RGB TIFF by
default, as ``picamcal correct`` always did; uint16 linear TIFF; colour-managed sRGB PNG or JPEG), or one
chunked float32 OME-Zarr stack. The same per-file function runs in a local process pool or on a dask cluster, so the
outputs are the same bytes either way.

What it guarantees:

- **Bounded memory.** At most two tasks per worker are in flight; inputs are read by the workers, one at
  a time, never all up front; a task returns a few words, not its image.
- **Calibration loaded once per worker** (a module-level cache keyed by the file's path and SHA-256).
- **No half-written output.** Every file is written to a temporary name and renamed; zarr chunks likewise
  (zarr's local store writes each chunk to a temporary name). Temporaries left by a killed batch are
  removed by the next run (:func:`picamcal._atomic.remove_stale_temporaries`).
- **Nothing left running.** The pool's workers end when this process ends, even by ``kill -9``; then the
  forkserver and multiprocessing's resource tracker, which wait for them, end too.
- **Resumable.** Existing outputs are skipped unless ``overwrite``; the zarr stack records its finished
  frames in its attributes. Running the same command again finishes an interrupted batch.
- **A bad file does not stop the others,** whichever it is, the first included: a corrupt file, or one of
  another size or sensor than the calibration's. Its reason is in :attr:`BatchResult.failed`. Problems with
  the whole batch (the calibration, the options, the output folder, the scheduler) raise a
  :class:`~picamcal.errors.PicamcalError` before any work.

The zarr stack follows OME-NGFF 0.5 (zarr format 3): a group whose ``ome`` attributes hold one
``multiscales`` entry (one resolution level, axes ``t, c, y, x``) and ``omero`` channel hints; the
array ``0`` has shape (frames, 3, H, W) float32, chunks of one frame and channel and at most
1024 x 1024 pixels, so no chunk is shared by two frames and concurrent workers never write the same
chunk. Frames not (yet) written read as NaN.
"""

from __future__ import annotations

import errno
import glob
import json
import multiprocessing
import os
import re
import socket
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import (
    has_live_temporary,
    make_temporary,
    refuse_foreign,
    refuse_inputs_as_output,
    remove_stale_temporaries,
)
from .calibration import MODES, Calibration, load_calibration
from .correct import correct, correct_processed
from .errors import OutputError, PicamcalError, PicamcalWarning
from .output import (
    OUTPUT_FORMATS,
    OUTPUT_SUFFIXES,
    SRGB_FORMATS,
    TIFF_FORMATS,
    ColourMatrix,
    camera_to_srgb,
    is_picamcal_output,
    output_bytes,
    write_corrected,
)
from .raw import PATTERNS, read_raw
from .raw.npz import is_raw_npz
from .raw.processed import ProcessedImage, linearise, read_processed
from .records import sha256_file

#: Suffixes of the files taken from a folder of raw images (DNG, legacy JPEG+raw, picamera2 .npy, picamcal .npz).
RAW_SUFFIXES = (".dng", ".jpg", ".jpeg", ".npy", ".npz")
#: Suffixes of the files taken from a folder of headless raw dumps (``raw_format`` given: rpicam-raw's frames).
HEADLESS_SUFFIXES = (".raw", ".bin")
#: Suffixes of the files taken from a folder of processed images (``processed=True``).
PROCESSED_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
#: Output compressions: ``zstd`` (TIFF: with the floating-point predictor; needs imagecodecs).
COMPRESSIONS = ("zstd",)
#: The OME-NGFF version of the zarr stack's metadata.
OME_NGFF_VERSION = "0.5"

_GLOB_CHARS = re.compile(r"[*?[]")
#: errno values that mean the output place itself is unusable: every further file would fail the same way.
_PLACE_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM}
_ZARR_TILE = 1024
#: The suffix of the temporary that says a run is writing a zarr stack.
_WRITING = ".writing"
_RECORD_INTERVAL_S = 1.0


@dataclass
class BatchResult:
    """What a batch did, each list in input order.

    Attributes
    ----------
    done : list of Path
        Inputs corrected and written by this run.
    skipped : list of Path
        Inputs whose output existed already (written by an earlier, perhaps interrupted, run).
    failed : list of (Path, str)
        Inputs that could not be corrected, with the reason in one line.
    """

    done: list[Path] = field(default_factory=list)
    skipped: list[Path] = field(default_factory=list)
    failed: list[tuple[Path, str]] = field(default_factory=list)


@dataclass(frozen=True)
class _Settings:
    """Everything a worker needs besides the file: small and picklable (sent with every task)."""

    calibration: str  # absolute path
    calibration_sha256: str
    mode: str
    binned: bool
    processed: bool
    input_encoding: str  # as given: recorded in the outputs' metadata
    decode: str  # the same encoding with an absolute tuning path, for workers with another working folder
    read_options: dict[str, Any]  # keyword arguments of read_raw: pattern, black_level, raw_format, size, ...
    white: str | None
    tuning: str | None
    compression: str | None
    output_format: str  # one of picamcal.output.OUTPUT_FORMATS
    overwrite: bool
    zarr_array: str | None  # absolute path of the stack's array, or None for TIFF files
    mosaic: tuple[int, int] | None = None  # (columns, rows): frame i is the tile at row, column = divmod(i, columns)


@dataclass(frozen=True)
class _Job:
    index: int  # position in the inputs; the frame number in a zarr stack
    source: str  # absolute path
    target: str | None  # absolute TIFF path, None for a zarr frame


@dataclass(frozen=True)
class _Outcome:
    index: int
    error: str | None = None
    place_error: str | None = None  # the output place is unusable (disk full, read-only): stop the batch
    warnings: tuple[str, ...] = ()


# ------------------------------------------------------------------------------------------------ inputs
def expand_inputs(items: Iterable[str | os.PathLike[str]], suffixes: Sequence[str] = RAW_SUFFIXES) -> list[Path]:
    """Turn files, folders and glob patterns into a list of files, in order, without duplicates.

    A file is taken as it is. A folder gives its files whose suffix is one of ``suffixes`` (any case;
    not its sub-folders, not hidden files), sorted by name. A glob pattern (``*``, ``?``, ``[``; ``**``
    crosses folders) gives its matches sorted, folders among them expanded as folders: useful when the
    shell cannot expand it (too many files, or quoted). A file reached twice is kept the first time.

    Parameters
    ----------
    items : iterable of path-like
        Files, folders or glob patterns.
    suffixes : sequence of str
        Suffixes taken from folders: :data:`RAW_SUFFIXES` or :data:`PROCESSED_SUFFIXES`.

    Returns
    -------
    list of Path

    Raises
    ------
    PicamcalError
        A pattern matches nothing, or a folder holds no such file. A named file that is missing is kept: it
        fails on its own when the batch reads it, and the other files are still done.

    Examples
    --------
    >>> expand_inputs(["run1", "extra/*.dng", "run1/target.dng"])  # doctest: +SKIP
    [PosixPath('run1/black.dng'), ..., PosixPath('run1/white.dng'), PosixPath('extra/a.dng')]
    """
    wanted = tuple(s.lower() for s in suffixes)
    found: list[Path] = []
    seen: set[Path] = set()
    for item in items:
        path = Path(item)
        if path.is_dir():
            files = _folder_files(path, wanted)
        elif _GLOB_CHARS.search(str(item)) and not path.exists():
            files = []
            for match in sorted(glob.glob(str(item), recursive=True)):
                files.extend(_folder_files(Path(match), wanted) if Path(match).is_dir() else [Path(match)])
            if not files:
                raise PicamcalError("no files match this pattern", item)
        else:  # a file, or what is named as one: one that is missing or unreadable fails on its own in the batch
            files = [path]
        for file in files:
            key = Path(os.path.realpath(file))
            if key not in seen:
                seen.add(key)
                found.append(file)
    return found


def _folder_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    # A folder's .npz files that are not raw images (the calibration itself, say) are passed over.
    files = sorted(
        p
        for p in folder.iterdir()
        if p.suffix.lower() in suffixes
        and not p.name.startswith(".")
        and p.is_file()
        and (p.suffix.lower() != ".npz" or is_raw_npz(p))
    )
    if not files:
        raise PicamcalError(f"no {', '.join(suffixes)} files in this folder", folder)
    return files


# ------------------------------------------------------------------------------------------------ the batch
def run_batch(
    calibration_path: str | os.PathLike[str],
    inputs: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str] | None = None,
    *,
    mode: str = "centre",
    binned: bool = False,
    workers: int | None = None,
    scheduler: str | None = None,
    overwrite: bool = False,
    compression: str | None = None,
    zarr_path: str | os.PathLike[str] | None = None,
    mosaic: tuple[int, int] | None = None,
    processed: bool = False,
    input_encoding: str | None = None,
    pattern: str | None = None,
    black_level: float | Sequence[float] | None = None,
    raw_format: str | None = None,
    raw_size: tuple[int, int] | None = None,
    stride: int | None = None,
    frame: int | None = None,
    sensor: str | None = None,
    output_format: str = "float32-tiff",
    white: str | os.PathLike[str] | None = None,
    tuning: str | os.PathLike[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
    scheduler_timeout: float = 10.0,
) -> BatchResult:
    """Correct many images in parallel; write ``out_dir/<stem>.tiff`` (``.png``, ``.jpg``) for each, or one zarr stack.

    Everything about the batch as a whole is checked before any work: the options, the calibration, the
    inputs, the scheduler, and that the output place can be written (a probe file the size of one output,
    removed again). After that a file that fails (unreadable, or not of the calibration's size, sensor and
    Bayer order) is recorded in :attr:`BatchResult.failed` and the others go on; only an output place that
    becomes unusable (disk full, read-only) stops the batch, with an :class:`~picamcal.errors.OutputError`.

    Parameters
    ----------
    calibration_path : path-like
        Calibration file (.npz) from :meth:`picamcal.Calibration.save`.
    inputs : path-like or iterable of path-like
        Files, folders or glob patterns (:func:`expand_inputs`; folders give :data:`RAW_SUFFIXES` files,
        or :data:`PROCESSED_SUFFIXES` ones with ``processed``).
    out_dir : path-like, optional
        Folder for ``<stem><suffix>`` files in ``output_format`` (:func:`picamcal.output.write_corrected`, the
        suffix from :data:`picamcal.output.OUTPUT_SUFFIXES`). Give either this or ``zarr_path``.
    mode : {"centre", "flat", "pure", "balance"}
        Correction mode (:func:`picamcal.correct`).
    binned : bool
        Write the bin-resolution image (raw inputs only).
    workers : int, optional
        Local worker processes; default one per available core (and no pool for a single file); 0 works in
        this process, without a pool. Each worker loads the calibration once.
    scheduler : str, optional
        Address of a running dask.distributed scheduler (``tcp://host:port``) to run on instead. Its
        workers need the calibration, inputs and output place at the same paths (a shared filesystem).
    overwrite : bool
        Replace existing outputs; otherwise they are skipped, which is how an interrupted batch resumes.
        When every output exists already there is nothing to do and that is an ``OutputError``.
    compression : {None, "zstd"}
        Compress TIFF files (zstd with a predictor; needs imagecodecs) or zarr chunks; not the PNG and JPEG
        formats, which have their own.
    zarr_path : path-like, optional
        Write one OME-Zarr stack here instead of TIFF files (see the module docstring).
    mosaic : (columns, rows), optional
        With ``zarr_path``: place the frames side by side as the tiles of one mosaic, in row-major order
        (frame i at row ``i // columns``, column ``i % columns``), instead of stacking them; tiles do not
        overlap, one chunk per tile and channel.
    processed : bool
        The inputs are ISP-processed images (JPEG, PNG, TIFF), corrected with
        :func:`picamcal.correct.correct_processed`.
    input_encoding : str, optional
        With ``processed``: how to undo the tone curve (:func:`picamcal.raw.processed.linearise`);
        default the ``tuning`` file's curve if given, else ``srgb``.
    pattern, black_level : optional
        Override the raw files' Bayer order and black level (:func:`picamcal.read_raw`).
    raw_format, raw_size, stride, frame, sensor : optional
        Read headless raw dumps (``rpicam-raw``): their libcamera format name, (width, height), row stride in
        bytes, frame number and sensor (:func:`picamcal.read_raw`'s ``raw_format``, ``size``, ...).
    output_format : str
        One of :data:`picamcal.output.OUTPUT_FORMATS` (default ``float32-tiff``); a zarr stack is float32 only.
        The sRGB formats of raw inputs use the colour matrix of :func:`picamcal.output.camera_to_srgb` (the
        ``tuning`` file's, else the image's own, else the identity; the identity in ``pure`` mode, whose
        output is the calibration's primaries); processed inputs are in the ISP's sRGB space already.
    white : path-like, optional
        With ``processed``: a processed white reference (residual flat field).
    tuning : path-like, optional
        With ``processed``: the libcamera tuning file the camera ran with (its lens shading and CCM). With raw
        inputs and an sRGB ``output_format``: the source of the colour matrix (its ``rpi.ccm``).
    progress : callable, optional
        Called as ``progress(finished, total)`` when the work starts and after each file, ``total``
        counting the files to do (not the skipped ones).
    scheduler_timeout : float
        Seconds to wait for the scheduler (and for it to have a worker).

    Returns
    -------
    BatchResult

    Raises
    ------
    PicamcalError
        Before any work, for anything wrong with the batch as a whole; ``OutputError`` if the output place
        cannot be written, at the start or when it fills up (the message says how far the batch got).

    Examples
    --------
    >>> result = run_batch("cal.npz", ["run1/*.dng"], "corrected", workers=4)  # doctest: +SKIP
    >>> len(result.done), result.failed  # doctest: +SKIP
    (12, [])
    >>> run_batch("cal.npz", ["run1"], zarr_path="run1.zarr", scheduler="tcp://10.0.0.2:8786")  # doctest: +SKIP
    """
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}: choose one of {', '.join(MODES)}")
    if (out_dir is None) == (zarr_path is None):
        raise ValueError("give either out_dir (TIFF files) or zarr_path (one stack)")
    if processed and binned:
        raise ValueError("binned is for raw images")
    if not processed and (white is not None or input_encoding is not None):
        raise ValueError("white and input_encoding go with processed")
    if workers is not None and workers < 0:
        raise ValueError("workers must be 0 or more")
    if compression is not None and compression not in COMPRESSIONS:
        raise PicamcalError(f"unknown compression {compression!r} (expected one of {', '.join(COMPRESSIONS)})")
    if output_format not in OUTPUT_FORMATS:
        raise PicamcalError(f"unknown output format {output_format!r} (expected one of {', '.join(OUTPUT_FORMATS)})")
    if zarr_path is not None and output_format != "float32-tiff":
        raise PicamcalError(f"a zarr stack holds float32 only: write {output_format} files to a folder (--out)")
    if compression is not None and zarr_path is None and output_format not in TIFF_FORMATS:
        raise PicamcalError(f"compression {compression} is for the TIFF formats: {output_format} has its own")
    if tuning is not None and not processed:
        if output_format not in SRGB_FORMATS:
            raise PicamcalError(
                f"with raw images a tuning file gives the colour matrix of the sRGB formats; {output_format} "
                f"stays in camera RGB (choose one of {', '.join(SRGB_FORMATS)}, or leave out the tuning file)",
                tuning,
            )
        if mode == "pure":
            raise PicamcalError(
                "mode pure writes the calibration's primaries, to which a camera's colour matrix does not apply "
                "(leave out the tuning file, or use mode centre)",
                tuning,
            )
        from .export.tuning import load_tuning

        camera_to_srgb({}, load_tuning(tuning), tuning_path=tuning)  # no rpi.ccm: fail here, before any work
    if pattern is not None and pattern not in PATTERNS:
        raise PicamcalError(f"unknown Bayer pattern {pattern!r} (expected one of {', '.join(PATTERNS)})")
    if input_encoding is None:
        input_encoding = f"tuning:{tuning}" if tuning is not None and processed else "srgb"
    decode = input_encoding
    if input_encoding.startswith("tuning:"):  # absolute, for workers with another working folder
        decode = f"tuning:{Path(input_encoding.removeprefix('tuning:')).absolute()}"
    linearise(np.zeros(1), decode)  # a bad encoding fails here, before any work
    if compression is not None and zarr_path is None:
        _require_imagecodecs()
    if mosaic is not None and (zarr_path is None or min(mosaic) < 1):
        raise ValueError("mosaic needs zarr_path and at least one column and one row")

    cal = load_calibration(calibration_path)
    cal.check_mode(mode)  # a flat-field calibration has no centre or pure mode: say so before any work
    if processed:
        _check_processed_references(white, tuning, decode)
    settings = _Settings(
        calibration=str(Path(calibration_path).absolute()),
        calibration_sha256=sha256_file(Path(calibration_path)),
        mode=mode,
        binned=binned,
        processed=processed,
        input_encoding=input_encoding,
        decode=decode,
        read_options={
            "pattern": pattern,
            "black_level": None if black_level is None else tuple(np.atleast_1d(black_level).astype(float).tolist()),
            "raw_format": raw_format,
            "size": raw_size,
            "stride": stride,
            "frame": frame,
            "sensor": sensor,
        },
        white=None if white is None else str(Path(white).absolute()),
        tuning=None if tuning is None else str(Path(tuning).absolute()),
        compression=compression,
        output_format=output_format,
        overwrite=overwrite,
        zarr_array=None if zarr_path is None else str(Path(zarr_path).absolute() / "0"),
        mosaic=None if mosaic is None else (int(mosaic[0]), int(mosaic[1])),
    )
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    inputs = list(inputs)
    items = [item for item in inputs if not _GLOB_CHARS.search(str(item))]
    sources = expand_inputs(
        inputs, PROCESSED_SUFFIXES if processed else HEADLESS_SUFFIXES if raw_format is not None else RAW_SUFFIXES
    )
    refuse_inputs_as_output(
        Path(zarr_path if zarr_path is not None else out_dir), [calibration_path, white, tuning, *items, *sources]
    )
    if mosaic is not None and len(sources) > mosaic[0] * mosaic[1]:
        raise PicamcalError(f"{len(sources)} frames do not fit a mosaic of {mosaic[0]} x {mosaic[1]} tiles")
    if zarr_path is None:
        jobs, skipped = _plan_tiffs(sources, Path(out_dir), overwrite, OUTPUT_SUFFIXES[output_format])
        stack = None
    else:
        stack = _ZarrStack(Path(zarr_path), sources, settings)
        jobs, skipped = stack.plan(overwrite)
    place = Path(zarr_path if zarr_path is not None else out_dir)
    if not jobs:  # everything done already: a finished batch run again has nothing to do
        return BatchResult(done=[], skipped=skipped, failed=[])
    frame_shape = _frame_shape(cal, sources, jobs, settings)

    client = _connect(scheduler, settings, scheduler_timeout) if scheduler is not None else None
    try:
        if stack is not None:
            stack.prepare(frame_shape, cal.bin_size if binned else 1, compression)
        else:
            _prepare_folder(place, _frame_bytes(frame_shape, output_format))
        if client is not None:
            runner: _InProcess | _Pool | _Dask = _Dask(settings, client)
        elif workers == 0 or (workers is None and len(jobs) == 1):  # a pool for one file is only overhead
            runner = _InProcess(settings)
        else:
            runner = _Pool(settings, max(1, min(workers or _available_cores(), len(jobs))))
        result = BatchResult(skipped=skipped)
        place_error = _drive(runner, jobs, sources, result, stack, progress)
    finally:
        if stack is not None:
            stack.release()
        if client is not None:
            client.close()
    order = {path: i for i, path in enumerate(sources)}
    result.done.sort(key=order.__getitem__)
    result.failed.sort(key=lambda item: order[item[0]])
    if place_error is not None:
        raise OutputError(
            f"{place_error}; stopped after {len(result.done)} of {len(jobs)} files (run again to resume)", place
        )
    return result


def _require_imagecodecs() -> None:
    try:
        import imagecodecs
    except ImportError:
        raise PicamcalError("zstd compression of TIFF files needs the imagecodecs package") from None
    if not imagecodecs.ZSTD.available:
        raise PicamcalError("this imagecodecs was built without zstd")


def _check_processed_references(white: Any, tuning: Any, decode: str) -> None:
    """Read the white reference and tuning file once here, so that a bad one fails before any work."""
    if white is not None:
        read_processed(white, decode)
    if tuning is not None:
        from .export.tuning import load_tuning

        load_tuning(tuning)


def _plan_tiffs(
    sources: list[Path], out_dir: Path, overwrite: bool, suffix: str = ".tiff"
) -> tuple[list[_Job], list[Path]]:
    """One job per input whose file (``<stem><suffix>``) is still to write; refuse name clashes and outputs that
    would replace an input."""
    inputs = {Path(os.path.realpath(source)) for source in sources}
    writers: dict[str, Path] = {}
    jobs, skipped = [], []
    for index, source in enumerate(sources):
        target = out_dir / f"{source.stem}{suffix}"
        if target.name in writers:
            raise OutputError(f"two inputs would both write {target.name}; correct them separately", source)
        writers[target.name] = source
        if Path(os.path.realpath(target)) in inputs:
            raise OutputError("output would replace an input file; choose another --out", target)
        if target.exists() and not overwrite:
            skipped.append(source)
        else:
            refuse_foreign(target, is_picamcal_output, "an image picamcal wrote")
            jobs.append(_Job(index, str(source.absolute()), str(target.absolute())))
    return jobs, skipped


def _frame_shape(cal: Calibration, sources: list[Path], jobs: list[_Job], settings: _Settings) -> tuple[int, ...]:
    """The outputs' shape: the calibration's for raw images (no file decides it, so that no bad or mismatched
    file, the first included, can refuse the others: each fails alone), the first readable image's for
    processed ones, which may be of another size than the calibration."""
    if settings.processed:
        for job in jobs:
            try:
                image = read_processed(sources[job.index], settings.decode)
            except PicamcalError:
                continue
            return image.rgb.shape
        return (cal.height, cal.width, 3)
    return (*cal.white.shape[:2], 3) if settings.binned else (cal.height, cal.width, 3)


def _frame_bytes(shape: Sequence[int], output_format: str = "float32-tiff") -> int:
    return output_bytes(output_format, tuple(shape))


def _prepare_folder(out_dir: Path, frame_bytes: int) -> None:
    """Create the output folder, remove the temporaries killed runs left, and check it takes one output."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError("exists and is not a folder", out_dir) from None
    except OSError as exc:
        raise OutputError(f"cannot create the output folder: {exc.strerror or exc}", out_dir) from exc
    remove_stale_temporaries(out_dir)
    _probe(out_dir, frame_bytes)


def _probe(folder: Path, nbytes: int) -> None:
    """Write (reserve) one output's worth of bytes in ``folder`` and remove it: read-only or full fails here."""
    try:
        name = make_temporary(folder / "probe")
    except OutputError as exc:  # about the folder, not the probe's name
        raise OutputError(exc.problem, folder) from exc.__cause__
    fd = os.open(name, os.O_WRONLY)
    try:
        if hasattr(os, "posix_fallocate"):
            try:
                os.posix_fallocate(fd, 0, max(nbytes, 1))
            except OSError as exc:
                # Filesystems without fallocate say EOPNOTSUPP or EINVAL: then only the writes will tell.
                if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
                    raise OutputError(
                        f"no room for one output ({nbytes / 1e6:.1f} MB): {exc.strerror or exc}", folder
                    ) from exc
    finally:
        os.close(fd)
        os.unlink(name)


# ------------------------------------------------------------------------------------------------ zarr
class _ZarrStack:
    """The OME-Zarr stack: planning (which frames are done), creation, and the record of finished frames.

    Only this process writes the group's attributes; workers write only their frames' chunks. While a run
    writes, a temporary of this process beside the stack says so (``.<name>.picamcal-...tmp.writing``,
    :func:`picamcal._atomic.make_temporary`; beside it, as zarr takes whatever is inside for its own), so that
    another run removes zarr's chunk temporaries (``*.partial``) only when they are a killed run's.
    """

    def __init__(self, path: Path, sources: list[Path], settings: _Settings) -> None:
        self.path = path
        self.sources = [str(s.absolute()) for s in sources]
        self.settings = settings
        self.signature = {
            "calibration_sha256": settings.calibration_sha256,
            "mode": settings.mode,
            "binned": settings.binned,
            "processed": settings.processed,
            "input_encoding": settings.input_encoding if settings.processed else None,
            "read_options": {k: list(v) if isinstance(v, tuple) else v for k, v in settings.read_options.items()},
            "white": settings.white,
            "tuning": settings.tuning,
            "mosaic": list(settings.mosaic) if settings.mosaic else None,
        }
        self.done: set[int] = set()
        self.resuming = False
        self.recorded_at = 0.0
        self.group: Any = None
        self.marker: Path | None = None

    def _existing_record(self) -> dict[str, Any] | None:
        try:
            return json.loads((self.path / "zarr.json").read_text())["attributes"]["picamcal"]
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def plan(self, overwrite: bool) -> tuple[list[_Job], list[Path]]:
        _require_zarr()
        if self.path.exists():
            if not self.path.is_dir():
                raise OutputError("exists and is not a zarr store (a folder)", self.path)
            record = self._existing_record()
            if record is None and any(self.path.iterdir()):
                raise OutputError("exists and is not a picamcal zarr stack; choose another --zarr", self.path)
            if record is not None and not overwrite:
                if record.get("sources") != self.sources or record.get("settings") != self.signature:
                    raise OutputError(
                        "holds a stack of other inputs or settings (use --overwrite to replace it)", self.path
                    )
                self.done = {int(i) for i in record.get("done", [])}
                self.resuming = True
        jobs = [_Job(i, s, None) for i, s in enumerate(self.sources) if i not in self.done]
        skipped = [Path(s) for i, s in enumerate(self.sources) if i in self.done]
        return jobs, skipped

    def prepare(self, frame_shape: tuple[int, ...], scale: int, compression: str | None) -> None:
        import zarr

        height, width = frame_shape[:2]
        try:
            if self.resuming:
                self.group = zarr.open_group(self.path, mode="r+")
                remove_stale_temporaries(self.path.parent)
                if not has_live_temporary(self.path, _WRITING):  # no run writes here: a killed one left these
                    for partial in self.path.rglob("*.partial"):
                        partial.unlink(missing_ok=True)
            else:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.group = zarr.open_group(self.path, mode="w", zarr_format=3)
                if self.settings.mosaic is None:
                    shape = (len(self.sources), 3, height, width)
                    chunks = (1, 1, min(height, _ZARR_TILE), min(width, _ZARR_TILE))
                else:  # one chunk per tile and channel, so that no two workers ever write the same chunk
                    columns, rows = self.settings.mosaic
                    shape, chunks = (1, 3, rows * height, columns * width), (1, 1, height, width)
                self.group.create_array(
                    "0",
                    shape=shape,
                    chunks=chunks,
                    dtype="float32",
                    fill_value=np.nan,
                    compressors=zarr.codecs.ZstdCodec() if compression == "zstd" else None,
                    dimension_names=["t", "c", "y", "x"],
                )
                self.group.attrs.update({"ome": _ome_metadata(scale), "picamcal": self._record()})
        except OSError as exc:
            raise OutputError(f"cannot write here: {exc.strerror or exc}", self.path) from exc
        self.marker = make_temporary(self.path, suffix=_WRITING)
        _probe(self.path, _frame_bytes(frame_shape))

    def release(self) -> None:
        """Say that this run no longer writes the stack."""
        if self.marker is not None:
            self.marker.unlink(missing_ok=True)

    def _record(self) -> dict[str, Any]:
        return {
            "calibration": Path(self.settings.calibration).name,
            "settings": self.signature,
            "sources": self.sources,
            "done": sorted(self.done),
        }

    def finished(self, index: int) -> None:
        self.done.add(index)
        if time.monotonic() - self.recorded_at > _RECORD_INTERVAL_S:
            self.write_record()

    def write_record(self) -> None:
        """Record the finished frames (zarr rewrites the group's zarr.json atomically: temporary name, rename)."""
        try:
            self.group.attrs.update({"picamcal": self._record()})
        except OSError as exc:
            raise OutputError(f"cannot record the finished frames: {exc.strerror or exc}", self.path) from exc
        self.recorded_at = time.monotonic()


def _require_zarr() -> None:
    try:
        import zarr
    except ImportError:
        raise PicamcalError("zarr output needs the zarr package (version 3)") from None
    if int(zarr.__version__.split(".")[0]) < 3:
        raise PicamcalError(f"zarr output needs zarr 3 or later (this is {zarr.__version__})")


def _ome_metadata(scale: int) -> dict[str, Any]:
    """OME-NGFF 0.5 ``ome`` attributes: one multiscale level ``0`` with axes t, c, y, x, and RGB channel hints."""
    colours = {"R": "FF0000", "G": "00FF00", "B": "0000FF"}
    return {
        "version": OME_NGFF_VERSION,
        "multiscales": [
            {
                "name": "picamcal",
                "axes": [
                    {"name": "t", "type": "time"},
                    {"name": "c", "type": "channel"},
                    {"name": "y", "type": "space"},
                    {"name": "x", "type": "space"},
                ],
                "datasets": [
                    {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1.0, 1.0, scale, scale]}]}
                ],
            }
        ],
        "omero": {
            "channels": [
                {"label": label, "color": colour, "active": True, "window": {"min": 0, "max": 1, "start": 0, "end": 1}}
                for label, colour in colours.items()
            ],
            "rdefs": {"model": "color"},
        },
    }


# ------------------------------------------------------------------------------------------------ running
def _available_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def _pool_context() -> multiprocessing.context.BaseContext:
    """forkserver where there is one: workers start clean (fork would copy this process's threads and locks,
    unsafe with numba, zarr's event loop or a GUI), and fast (forked from a server that preloaded picamcal)."""
    if "forkserver" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("forkserver")
        # The demosaicing library's import (it brings colour-science) is most of a worker's start-up.
        context.set_forkserver_preload(["picamcal.batch", "colour_demosaicing"])
        return context
    return multiprocessing.get_context("spawn")


class _InProcess:
    """``workers=0``: each job runs here, at once, when it is submitted."""

    window = 1

    def __init__(self, settings: _Settings) -> None:
        self.settings = settings

    def submit(self, job: _Job) -> Future:
        future: Future = Future()
        future.set_result(_process(self.settings, job))
        return future

    def finished(self, futures: list[Future]) -> Iterable[Future]:
        return futures

    def close(self) -> None:
        pass


class _Pool:
    """A local process pool; replaced when a worker dies (out of memory, killed), and the files it held fail."""

    def __init__(self, settings: _Settings, size: int) -> None:
        self.settings = settings
        self.size = size
        self.window = 2 * size
        self.context = _pool_context()
        self.executor = self._executor()

    def _executor(self) -> ProcessPoolExecutor:
        threads = max(1, _available_cores() // self.size)
        return ProcessPoolExecutor(self.size, mp_context=self.context, initializer=_init_worker, initargs=(threads,))

    def submit(self, job: _Job) -> Future:
        try:
            return self.executor.submit(_process, self.settings, job)
        except BrokenProcessPool:
            self.executor.shutdown(wait=False, cancel_futures=True)
            self.executor = self._executor()
            return self.executor.submit(_process, self.settings, job)

    def finished(self, futures: list[Future]) -> Iterable[Future]:
        return wait(futures, return_when=FIRST_COMPLETED).done

    def close(self) -> None:
        self.executor.shutdown(wait=True, cancel_futures=True)


def _init_worker(threads: int) -> None:
    """End with the process that started the pool, and share the cores among the workers.

    numba's parallel kernels would otherwise use a thread per core in every worker. numba's own runtime
    setting, not NUMBA_NUM_THREADS: numba re-reads its environment when it compiles and refuses a value
    that differs from the threads it has started.
    """
    _exit_with_parent()
    try:
        import numba
    except ImportError:  # no numba (32-bit Raspberry Pi OS): the numpy path runs in one thread anyway
        return
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


def _exit_with_parent() -> None:
    """End this worker as soon as the process that started it ends, however it ends (``kill -9`` included).

    Nothing else would end it: a worker waits for tasks on a pipe it holds both ends of, and the forkserver
    and resource tracker wait for their pipes' writers, the workers among them, so all would run on.
    prctl(PR_SET_PDEATHSIG) does not serve: under forkserver a worker's parent is the forkserver. What
    multiprocessing gives instead is the parent's sentinel, a pipe only the starting process writes to: it
    reads as ended when that process is gone. A thread waits on it (no polling) and ends the process.
    """
    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def wait_then_exit() -> None:
        parent.join()
        os._exit(1)

    threading.Thread(target=wait_then_exit, name="picamcal-exit-with-parent", daemon=True).start()


class _Dask:
    """The same jobs on a dask.distributed cluster (the caller connects and closes the client)."""

    def __init__(self, settings: _Settings, client: Any) -> None:
        from distributed import as_completed

        self.settings = settings
        self.client = client
        self.window = 2 * max(1, sum(client.nthreads().values()))
        self.completed = as_completed(loop=client.loop)

    def submit(self, job: _Job) -> Any:
        future = self.client.submit(_process, self.settings, job, pure=False)
        self.completed.add(future)
        return future

    def finished(self, futures: list[Any]) -> Iterable[Any]:
        return self.completed.next_batch(block=True)

    def close(self) -> None:
        pass


def _drive(
    runner: _InProcess | _Pool | _Dask,
    jobs: list[_Job],
    sources: list[Path],
    result: BatchResult,
    stack: _ZarrStack | None,
    progress: Callable[[int, int], None] | None,
) -> str | None:
    """Run the jobs, submitting as others finish so that at most ``runner.window`` are in flight; record each
    outcome. Returns why the output place became unusable, if it did (then no more jobs were started)."""
    queue = iter(jobs)
    in_flight: dict[Any, _Job] = {}
    count = 0
    place_error = None
    if progress is not None:
        progress(0, len(jobs))
    try:
        while True:
            while place_error is None and len(in_flight) < runner.window and (job := next(queue, None)) is not None:
                in_flight[runner.submit(job)] = job
            if not in_flight:
                return place_error
            for future in runner.finished(list(in_flight)):
                job = in_flight.pop(future)
                outcome = _outcome_of(future, job)
                source = sources[job.index]
                for message in outcome.warnings:
                    warnings.warn(message.replace(job.source, str(source), 1), PicamcalWarning, stacklevel=2)
                if outcome.error is None:
                    result.done.append(source)
                    if stack is not None:
                        stack.finished(job.index)
                else:
                    result.failed.append((source, outcome.error))
                    place_error = place_error or outcome.place_error
                count += 1
                if progress is not None:
                    progress(count, len(jobs))
    finally:
        runner.close()
        if stack is not None:
            stack.write_record()


def _outcome_of(future: Any, job: _Job) -> _Outcome:
    """The task's outcome; a task that died with its worker (or was lost by the cluster) is a failure."""
    try:
        return future.result()
    except BrokenProcessPool:
        return _Outcome(job.index, "its worker process died (out of memory, or killed)")
    except Exception as exc:
        return _Outcome(job.index, f"the task was lost ({type(exc).__name__}: {exc})")


def _connect(address: str, settings: _Settings, timeout: float) -> Any:
    """A client of the scheduler at ``address``, checked: reachable, with workers that can read the calibration."""
    try:
        from distributed import Client
    except ImportError:
        raise PicamcalError("--scheduler needs the dask.distributed package") from None
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        protocol, location = parse_address(address)
        if protocol == "tcp":  # a refused connection is certain at once; the client would retry until its timeout
            socket.create_connection(parse_host_port(location), timeout=timeout).close()
        client = Client(address, timeout=timeout, set_as_default=False)
    except (OSError, ValueError, TypeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise PicamcalError(f"cannot reach the dask scheduler ({reason})", address) from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except (TimeoutError, OSError):
            raise PicamcalError(f"the dask cluster has no workers (waited {timeout:g} s)", address) from None
        for worker, problem in client.run(_check_worker, settings).items():
            if problem is not None:
                raise PicamcalError(
                    f"dask worker {worker} cannot use the calibration ({problem}); the workers need the same "
                    "files at the same paths",
                    settings.calibration,
                )
    except BaseException:
        client.close()
        raise
    return client


def _check_worker(settings: _Settings) -> str | None:
    """Run on each dask worker before any work: load (and cache) the calibration."""
    try:
        _calibration(settings)
    except PicamcalError as exc:
        return exc.problem
    return None


# ------------------------------------------------------------------------------------------------ the workers
#: Per worker process: what was loaded once (calibration, white reference, tuning), keyed by what identifies it.
_CACHE: dict[tuple, Any] = {}


def _cached(key: tuple, load: Callable[[], Any]) -> Any:
    if key not in _CACHE:
        if len(_CACHE) > 8:  # a long-lived dask worker serving many batches
            _CACHE.clear()
        _CACHE[key] = load()
    return _CACHE[key]


def _calibration(settings: _Settings) -> Calibration:
    def load() -> Calibration:
        path = Path(settings.calibration)
        if not path.is_file():
            raise PicamcalError("no such calibration file", path)
        if sha256_file(path) != settings.calibration_sha256:
            raise PicamcalError("is not the calibration the batch started with (it changed, or is another file)", path)
        return load_calibration(path)

    return _cached(("calibration", settings.calibration, settings.calibration_sha256), load)


def _process(settings: _Settings, job: _Job) -> _Outcome:
    """Correct one file and write its output: the task every worker runs (a top-level function, picklable).

    Never raises for a problem with the file: the outcome says what went wrong, in one line.
    """
    place_error = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            _write(settings, job, *_correct_file(settings, Path(job.source)))
            error = None
        except PicamcalError as exc:
            error = exc.problem if exc.path == job.source else str(exc)
            cause = exc.__cause__
            if isinstance(exc, OutputError) and isinstance(cause, OSError) and cause.errno in _PLACE_ERRORS:
                place_error = exc.problem
        except Exception as exc:  # a surprise in one file must not stop the others
            error = f"{type(exc).__name__}: {exc}"
    messages = tuple(str(w.message) for w in caught if issubclass(w.category, PicamcalWarning))
    return _Outcome(job.index, error, place_error, messages)


def _correct_file(settings: _Settings, source: Path) -> tuple[np.ndarray, dict[str, Any]]:
    """The corrected image, and the metadata its colour matrix comes from (the raw's; none for processed)."""
    cal = _calibration(settings)
    if settings.processed:
        return _correct_processed(read_processed(source, settings.decode), cal, settings), {}
    # The calibration's size is checked from the file's header, before a frame of another size is decoded.
    raw = read_raw(source, **settings.read_options, expected_shape=(cal.height, cal.width))
    return correct(raw, cal, mode=settings.mode, binned=settings.binned), raw.metadata


def _correct_processed(image: ProcessedImage, cal: Calibration, settings: _Settings) -> np.ndarray:
    """correct_processed, with the ISP's lens shading and CCM taken from the tuning file the camera ran with."""
    white = None
    if settings.white is not None:
        white = _cached(
            ("white", settings.white, settings.decode), lambda: read_processed(settings.white, settings.decode)
        )
    if settings.tuning is None:
        return correct_processed(image, cal, settings.mode, white=white)
    from .export.isp import alsc_section, isp_gains_for_image, tuning_ccm
    from .export.tuning import load_tuning

    tuning = _cached(("tuning", settings.tuning), lambda: load_tuning(settings.tuning))
    ct = float(alsc_section(tuning).get("default_ct", 4500))
    gains = isp_gains_for_image(tuning, (cal.width, cal.height), (image.width, image.height), ct=ct)
    return correct_processed(image, cal, settings.mode, white=white, ccm=tuning_ccm(tuning, ct), isp_gains=gains)


def _write(settings: _Settings, job: _Job, rgb: np.ndarray, source_metadata: dict[str, Any]) -> None:
    if settings.zarr_array is not None:
        _write_frame(settings.zarr_array, job, rgb, settings.mosaic)
        return
    info: dict[str, Any] = {
        "source": Path(job.source).name,
        "calibration": Path(settings.calibration).name,
        "mode": settings.mode,
        "binned": settings.binned,
    }
    if settings.processed:
        info["input_encoding"] = settings.input_encoding
    write_corrected(
        job.target,
        rgb,
        settings.output_format,
        info,
        colour_matrix=_colour_matrix(settings, source_metadata) if settings.output_format in SRGB_FORMATS else None,
        overwrite=settings.overwrite,
        compression=settings.compression,
    )


def _colour_matrix(settings: _Settings, source_metadata: dict[str, Any]) -> ColourMatrix:
    """The sRGB formats' colour matrix: none for processed images (already in the ISP's sRGB space) and for
    ``pure`` mode (the calibration's primaries, not the camera's), else :func:`picamcal.output.camera_to_srgb`."""
    if settings.processed:
        return ColourMatrix(np.eye(3), "none: a processed image is in the ISP's output (sRGB) space already")
    if settings.mode == "pure":
        return ColourMatrix(np.eye(3), "none: mode pure writes the calibration's primaries, taken as sRGB's")
    if settings.tuning is None:
        return camera_to_srgb(source_metadata)
    from .export.tuning import load_tuning

    tuning = _cached(("tuning", settings.tuning), lambda: load_tuning(settings.tuning))
    return camera_to_srgb(source_metadata, tuning, tuning_path=settings.tuning)


def _write_frame(array_path: str, job: _Job, rgb: np.ndarray, mosaic: tuple[int, int] | None = None) -> None:
    import zarr

    array = zarr.open_array(array_path, mode="r+")
    frame = np.moveaxis(np.asarray(rgb, dtype=np.float32), -1, 0)
    tile = array.chunks[2:] if mosaic is not None else array.shape[2:]
    if frame.shape[1:] != tuple(tile):
        raise PicamcalError(
            f"is {frame.shape[2]}x{frame.shape[1]}, the stack's frames are {tile[1]}x{tile[0]}", job.source
        )
    try:
        if mosaic is None:
            array[job.index] = frame
        else:
            row, column = divmod(job.index, mosaic[0])
            height, width = tile
            array[0, :, row * height : (row + 1) * height, column * width : (column + 1) * width] = frame
    except OSError as exc:
        raise OutputError(f"cannot write frame {job.index}: {exc.strerror or exc}", Path(array_path).parent) from exc


__all__ = [
    "COMPRESSIONS",
    "OME_NGFF_VERSION",
    "PROCESSED_SUFFIXES",
    "RAW_SUFFIXES",
    "BatchResult",
    "expand_inputs",
    "run_batch",
]
