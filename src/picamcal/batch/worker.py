"""The task every worker runs: correct some files and write their outputs; and what a worker keeps between tasks.

A task is :func:`process_jobs` with the batch's :class:`Settings` (small and picklable, sent with every task)
and a few :class:`Job` values; it returns an :class:`Outcome` of a few words for each, never an image. The files
of a task are read, corrected and written at once (:mod:`picamcal.batch.pipeline`). What a worker loads once (the
calibration, a white reference, a tuning file) is kept in a module-level cache keyed by what identifies it, the
calibration by its path and SHA-256.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from ..calibration import Calibration
from ..calibration.resample import calibration_for_raw
from ..correct import correct, correct_processed
from ..errors import OutputError, PicamcalError, PicamcalWarning
from ..export.isp import processed_geometry, processed_inputs
from ..export.tables import load_flat_field
from ..export.tuning import load_tuning
from ..geometry import named_mode
from ..kernels import fits
from ..limits import SizeBound
from ..modes import Mode
from ..output import SRGB_FORMATS, ColourMatrix, camera_to_srgb, write_corrected
from ..output.colour import srgb_encoding
from ..output.ome_zarr import write_frame
from ..output.provenance import read_record
from ..raw import RawImage, flat_field_gain_map, read_raw, write_dng, write_linear_dng
from ..raw.model import raw_geometry
from ..raw.processed import ProcessedImage, read_processed
from ..records import sha256_file
from . import claims
from .disk import PLACE_ERRORS
from .pipeline import CANCEL_GRACE_S, Finished, Slot, SlotPool, overlapped
from .record import MADE_WITH, differences, made_with

_T = TypeVar("_T")


@dataclass(frozen=True)
class Settings:
    """Everything a worker needs besides the file: small and picklable (sent with every task)."""

    calibration: str  # absolute path
    calibration_sha256: str
    mode: str  # a picamcal.modes.Mode value
    binned: bool
    processed: bool
    input_encoding: str  # as given: recorded in the outputs' metadata
    decode: str  # the same encoding with an absolute tuning path, for workers with another working folder
    read_options: dict[str, Any]  # keyword arguments of read_raw: pattern, black_level, raw_format, size, ...
    white: str | None
    tuning: str | None
    compression: str | None
    output_format: str  # one of picamcal.output.BATCH_FORMATS
    overwrite: bool
    zarr_array: str | None  # absolute path of the stack's array, or None for image files
    mosaic: tuple[int, int] | None = None  # (columns, rows): frame i is the tile at row, column = divmod(i, columns)
    stop_event: str | None = None  # on a dask cluster: the name of the distributed.Event that stops the batch
    geometry: dict[str, Any] = field(default_factory=dict)  # raw_geometry's sensor_crop and sensor_mode, as given
    record: dict[str, Any] = field(default_factory=dict)  # what the outputs record (picamcal.batch.record)
    started_ns: int = 0  # when the run began (time.time_ns()): an output newer than that was written meanwhile
    run: str = ""  # names this run in the claims of its outputs (picamcal.batch.claims), the same in every worker


@dataclass(frozen=True)
class Job:
    """One input: its position (the frame number in a zarr stack), its absolute path, and its output file's."""

    index: int
    source: str
    target: str | None  # None for a zarr frame


@dataclass(frozen=True)
class Outcome:
    """What a task did: nothing wrong (``error`` None), or why it failed, in one line."""

    index: int
    error: str | None = None
    place_error: str | None = None  # the output place is unusable (disk full, read-only): stop the batch
    warnings: tuple[str, ...] = ()
    lost: bool = False  # the task was lost with its worker or cluster, not failed by the file itself
    elsewhere: str | None = None  # not this run's to write: "claimed", "written" or "kept" (see Existing)
    kept: tuple[str, ...] = ()  # with "kept": how the settings of the output found differ (record.differences)


@dataclass(frozen=True)
class Existing:
    """An output found in place, not to be written by this run: ``written`` (made with this run's settings) or
    ``kept`` (made with others, ``kept`` saying how they differ)."""

    kind: str
    kept: tuple[str, ...] = ()


class NotThisRuns(Exception):
    """The job's output is not this run's to write: another run holds its claim (``"claimed"``), or it is in place
    (``"written"`` since the run planned it, or ``"kept"``: made with other settings)."""

    def __init__(self, kind: str, kept: tuple[str, ...] = ()) -> None:
        super().__init__(kind)
        self.kind, self.kept = kind, kept


def existing_output(target: str, settings: Settings) -> Existing | None:
    """What is at ``target`` for this run: None if nothing, or an output this run replaces (``overwrite``, and
    older than the run); else an :class:`Existing`.

    Raises
    ------
    OutputError
        A file is there that picamcal did not write: never replaced.
    """
    try:
        stat = os.stat(target)
    except OSError:
        return None
    if settings.overwrite and stat.st_mtime_ns < settings.started_ns:
        return None  # there before the run began: replaced, as asked (planning refused anything not picamcal's)
    try:
        record = read_record(target)
    except Exception:  # whatever the bytes: a file that cannot be read as an image is not one of ours
        record = None
    if record is None:
        raise OutputError(
            "exists and is not an image picamcal wrote: picamcal replaces only what it wrote itself; choose another "
            "--out",
            target,
        )
    found = tuple(differences(record.get(MADE_WITH), settings.record))
    return Existing("kept", found) if found else Existing("written")


#: Per worker process: what was loaded once (calibration, white reference, tuning), keyed by what identifies it.
_CACHE: dict[tuple, Any] = {}
#: Per worker process: the output slots, kept from one task to the next.
_SLOTS = SlotPool()
#: Per pool worker process: what says that the batch was interrupted (set by :func:`set_stop`).
_STOP: Any = None
#: Seconds between two looks at a dask cluster's stop event (each is a round trip to the scheduler).
_DASK_LOOK_S = 0.2
#: Per worker process: how many tasks of each batch (:attr:`Settings.run`) it is running (:func:`tasks_running`).
_RUNNING: Counter[str] = Counter()
_RUNNING_LOCK = threading.Lock()
#: Seconds a task on a cluster, once the batch is interrupted, waits for the write under way: as long as it takes
#: (a day stands for that; a write takes seconds).
_CLUSTER_WRITE_WAIT_S = 86_400.0


#: Per pool worker process: Ctrl-C reached it (the terminal sends it to the whole process group).
_SIGNALLED = False


def set_stop(event: Any) -> None:
    """Give this worker process the event (``is_set()``) by which the batch's own process stops its tasks: no new
    file is started once it is set."""
    global _STOP
    _STOP = event


def stop_on_signal(signum: int, frame: Any) -> None:
    """A pool worker's SIGINT handler: start no other file at once, rather than when the batch's own process has
    seen Ctrl-C too and set the event (a moment later, longer on a busy machine); that process decides what happens
    to the files in flight. Only a flag: a handler must not take the event's lock, which the interrupted code may
    hold."""
    global _SIGNALLED
    _SIGNALLED = True


def _stopped() -> bool:
    return _SIGNALLED or (_STOP is not None and _STOP.is_set())


def _cached(key: tuple, load: Callable[[], _T]) -> _T:
    if key not in _CACHE:
        if len(_CACHE) > 8:  # a long-lived dask worker serving many batches
            _CACHE.clear()
        _CACHE[key] = load()
    return _CACHE[key]


def keep_calibration(settings: Settings, calibration: Calibration) -> None:
    """Hand this process's pipeline the calibration the batch has loaded already (in-process runs: one read)."""
    _cached(("calibration", settings.calibration, settings.calibration_sha256), lambda: calibration)


def forget() -> None:
    """Forget the calibrations, whites and tuning files loaded so far, and their correction fields, as a new process
    starts (benchmarks/bench_commands.py times a command's work so)."""
    from ..correct import _cached_fields

    _CACHE.clear()
    _cached_fields.cache_clear()


def calibration_of(settings: Settings) -> Calibration:
    """The batch's calibration, loaded once per worker, refused if the file is not the one the batch started with."""

    def load() -> Calibration:
        path = Path(settings.calibration)
        if not path.is_file():
            raise PicamcalError("no such calibration file", path)
        if sha256_file(path) != settings.calibration_sha256:
            raise PicamcalError("is not the calibration the batch started with (it changed, or is another file)", path)
        return load_flat_field(path, settings.read_options.get("sensor"))  # a calibration, or a table's flat field

    return _cached(("calibration", settings.calibration, settings.calibration_sha256), load)


def check_worker(settings: Settings) -> str | None:
    """Run on each dask worker before any work: load (and cache) the calibration; what is wrong, or None."""
    try:
        calibration_of(settings)
    except PicamcalError as exc:
        return exc.problem
    return None


def process_jobs(settings: Settings, jobs: Sequence[Job]) -> list[Outcome]:
    """Correct some files and write their outputs: the task every worker runs (a top-level function, picklable).

    Never raises for a problem with a file: each file's outcome says what went wrong, in one line. The files go
    through :func:`outcomes`, reading, correcting and writing overlapped. Once the batch is interrupted (the
    pool's event, :func:`set_stop`, or the cluster's, ``settings.stop_event``), no new file is started and the
    files not done have no outcome. On a cluster the task ends only once the write under way has ended, however
    long it takes: a dask worker lives on after the batch, and a write left to a thread of its own would put an
    output in place after the batch counted what it wrote (a pool's worker ends with the batch, and its write
    with it). While it runs, :func:`tasks_running` counts it.
    """
    with _running(settings.run):
        if settings.stop_event is not None:
            cancel = _dask_stop(settings.stop_event)
            return list(outcomes(settings, jobs, cancel=cancel, grace=_CLUSTER_WRITE_WAIT_S))
        return list(outcomes(settings, jobs, cancel=_stopped))


@contextlib.contextmanager
def _running(run: str) -> Iterator[None]:
    """Count a task of the batch ``run`` as running in this process while the block runs."""
    with _RUNNING_LOCK:
        _RUNNING[run] += 1
    try:
        yield
    finally:
        with _RUNNING_LOCK:
            _RUNNING[run] -= 1
            if _RUNNING[run] <= 0:
                del _RUNNING[run]


def tasks_running(run: str) -> int:
    """How many tasks of the batch ``run`` (:attr:`Settings.run`) this process is running, their writes included.

    An interrupted batch asks every dask worker (``client.run``) after it cancelled its tasks, for a task that was
    executing goes on until it ends (:meth:`picamcal.batch.executors.Dask.abandon`).

    Examples
    --------
    >>> tasks_running("a batch that never ran here")
    0
    """
    with _RUNNING_LOCK:
        return _RUNNING.get(run, 0)


def _dask_stop(name: str) -> Callable[[], bool]:
    """Whether the cluster's event ``name`` is set, asked of the scheduler at most every :data:`_DASK_LOOK_S`."""
    from distributed import Event, get_client

    event = Event(name, client=get_client())  # the worker's client, known in the task's thread only
    seen = {"at": 0.0, "set": False}
    lock = threading.Lock()

    def is_set() -> bool:
        with lock:
            if not seen["set"] and time.monotonic() - seen["at"] > _DASK_LOOK_S:
                seen.update(at=time.monotonic(), set=event.is_set())
            return bool(seen["set"])

    return is_set


def outcomes(
    settings: Settings,
    jobs: Sequence[Job],
    cancel: Callable[[], bool] | None = None,
    grace: float = CANCEL_GRACE_S,
) -> Iterator[Outcome]:
    """Each job's outcome as it finishes, the jobs read, corrected and written at once
    (:func:`picamcal.batch.pipeline.overlapped`); after a failure of the output place itself (a full disk), or
    once ``cancel()`` is true (the batch was interrupted), nothing more is started and the jobs not done have
    no outcome. A cancelled run waits ``grace`` seconds for the write under way, then leaves it to its thread."""
    try:
        calibration_of(settings)  # once, here, before the stages' threads would each load it
    except PicamcalError as exc:
        yield from (Outcome(job.index, str(exc)) for job in jobs)
        return
    stages = _Stages(settings)
    try:
        with _SLOTS.taken() as slots:
            for finished in overlapped(
                jobs,
                stages.read,
                stages.correct,
                stages.write,
                fatal=_is_place_error,
                slots=slots,
                cancel=cancel,
                grace=grace,
            ):
                stages.release(finished.job)  # written, failed or not this run's: the claim goes
                yield _outcome(finished)
    finally:  # the jobs dropped (an interrupt, a full disk): their claims go too
        for job in jobs:
            stages.release(job)


def _outcome(finished: Finished[Job]) -> Outcome:
    job, exc = finished.job, finished.error
    messages = tuple(str(w.message) for w in finished.warnings if issubclass(w.category, PicamcalWarning))
    if exc is None:
        return Outcome(job.index, warnings=messages)
    if isinstance(exc, NotThisRuns):
        return Outcome(job.index, warnings=messages, elsewhere=exc.kind, kept=exc.kept)
    if isinstance(exc, PicamcalError):
        error = exc.problem if exc.path == job.source else str(exc)
    else:  # a surprise in one file must not stop the others
        error = f"{type(exc).__name__}: {exc}"
    place_error = exc.problem if isinstance(exc, OutputError) and _is_place_error(exc) else None
    return Outcome(job.index, error, place_error, messages)


def _is_place_error(exc: Exception) -> bool:
    """Whether ``exc`` says that the output place itself is unusable (disk full, read-only)."""
    cause = exc.__cause__
    return isinstance(exc, OutputError) and isinstance(cause, OSError) and cause.errno in PLACE_ERRORS


class _Stages:
    """The three stages of a batch's files (:func:`picamcal.batch.pipeline.overlapped`) with its settings."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.calibration = calibration_of(settings)
        self.claimed: set[str] = set()  # the outputs this run claimed and has not released (picamcal.batch.claims)

    def claim(self, job: Job) -> None:
        """Claim the job's output before any work on it (:mod:`picamcal.batch.claims`); raise :class:`NotThisRuns`
        if another run holds it or it is in place by now (written by another run since this one planned it)."""
        if job.target is None:  # a zarr frame: the stack's own record says which are done
            return
        try:
            if not claims.take(job.target, self.settings.run):
                raise NotThisRuns("claimed")
        except OSError:  # a folder that cannot be written: the write says so
            return
        self.claimed.add(job.target)
        existing = existing_output(job.target, self.settings)
        if existing is not None:
            raise NotThisRuns(existing.kind, existing.kept)

    def release(self, job: Job) -> None:
        """Give up the claim of the job's output, if this run holds it."""
        if job.target is not None and job.target in self.claimed:
            self.claimed.discard(job.target)
            claims.release(job.target, self.settings.run)

    def read(self, job: Job) -> RawImage | ProcessedImage:
        """The decoded file, once its output is claimed (:meth:`claim`); a raw file's size is checked from its
        header, before a frame of another size is decoded."""
        self.claim(job)
        if self.settings.processed:
            return read_processed(Path(job.source), self.settings.decode)
        cal = self.calibration
        return read_raw(Path(job.source), **self.settings.read_options, expected_shape=frame_bound(cal))

    def correct(self, image: RawImage | ProcessedImage, slot: Slot) -> _Corrected:
        """The corrected image (into the slot's array when the kernel can reuse it), the metadata its colour
        matrix comes from (the raw's; none for processed images), what the output records of how it was made
        (:func:`picamcal.batch.record.made_with`), and the sRGB formats' colour matrix (once per frame: its
        warnings too)."""
        settings, cal = self.settings, self.calibration
        srgb = settings.output_format in SRGB_FORMATS
        if isinstance(image, ProcessedImage):
            matrix = _colour_matrix(settings, {}) if srgb else None
            return _correct_processed(image, cal, settings), {}, made_with(settings.record), matrix
        made = made_with(settings.record, image)
        matrix = _colour_matrix(settings, image.metadata) if srgb else None
        if settings.binned:
            geometry = raw_geometry(image, **settings.geometry) if any(settings.geometry.values()) else None
            rgb = correct(image, cal, mode=settings.mode, binned=True, geometry=geometry)
            return rgb, image.metadata, made, matrix
        if settings.output_format == "dng-gainmap":  # the frame goes out unchanged, the flat field as opcodes
            return image, image.metadata, made, matrix
        # uint16-tiff and sRGB codes straight from the kernel: no float32 image at full resolution to encode after
        encoding = None
        if matrix is not None:
            encoding = srgb_encoding(matrix, bits=16 if settings.output_format == "srgb-png16" else 8)
        dtype = np.dtype(np.uint16 if settings.output_format == "uint16-tiff" else np.float32)
        dtype = dtype if encoding is None else encoding.base.dtype
        out = slot.array if fits(slot.array, image.height, image.width, dtype) else None  # an earlier batch's size
        geometry = raw_geometry(image, **settings.geometry) if any(settings.geometry.values()) else None
        slot.array = correct(image, cal, settings.mode, out=out, dtype=dtype, encoding=encoding, geometry=geometry)
        return slot.array, image.metadata, made, matrix

    def write(self, job: Job, corrected: _Corrected) -> None:
        image, source_metadata, made, matrix = corrected
        if job.target is not None:
            claims.touch(job.target)  # still at work on it, for the runs of other machines
        if isinstance(image, RawImage):  # dng-gainmap: the flat field at the frame's own mode
            geometry = raw_geometry(image, **self.settings.geometry) if any(self.settings.geometry.values()) else None
            image = dataclasses.replace(image, metadata={**image.metadata, MADE_WITH: made})
            _write_gain_map_dng(self.settings, job, image, calibration_for_raw(self.calibration, image, geometry))
        elif self.settings.output_format == "linear-dng":
            _write_linear_dng(self.settings, job, image, {**source_metadata, MADE_WITH: made}, self.calibration)
        else:
            _write(self.settings, job, image, made, matrix)


#: What the correcting stage hands the writing one: the image (a raw frame for dng-gainmap; the codes of the sRGB
#: formats), the metadata of its colour, the output's ``made_with`` record, and the sRGB formats' colour matrix.
_Corrected = tuple[np.ndarray | RawImage, dict[str, Any], dict[str, Any], ColourMatrix | None]


def frame_bound(cal: Calibration) -> SizeBound:
    """The largest raw frame the calibration can correct: its sensor area, unbinned (a frame of any mode inside it
    is at most that; a forged header declaring more is refused before anything is decoded)."""
    assert cal.geometry is not None
    return SizeBound((max(cal.height, cal.geometry.crop[3]), max(cal.width, cal.geometry.crop[2])))


def _correct_processed(image: ProcessedImage, cal: Calibration, settings: Settings) -> np.ndarray:
    """correct_processed, with the ISP's lens shading and CCM taken from the tuning file the camera ran with.

    Where the image lies on the sensor (:func:`picamcal.export.isp.processed_geometry`): ``--sensor-crop`` is the
    sensor area the image shows (picamera2's ScalerCrop, full-sensor pixels), ``--sensor-mode`` the camera's sensor
    mode (a mode of the calibration's sensor in the registry); what they leave out comes from the image's record
    (``apply-tuning`` writes both), else the calibration's own mode and, for a mode that was said, libcamera's default
    crop for the image's size, else the mode's whole crop."""
    white = None
    if settings.white is not None:
        white_path = settings.white
        white = _cached(("white", white_path, settings.decode), lambda: read_processed(white_path, settings.decode))
    named = settings.geometry.get("sensor_mode")
    mode = named_mode(cal.sensor, named) if named else None
    sensor_mode, crop = processed_geometry(cal, image, crop=settings.geometry.get("sensor_crop"), sensor_mode=mode)
    if settings.tuning is None:
        return correct_processed(image, cal, settings.mode, white=white, crop=crop, sensor_mode=sensor_mode)
    tuning = _tuning(settings.tuning)
    inputs = processed_inputs(tuning, cal, image, crop=crop, sensor_mode=sensor_mode)
    return correct_processed(image, cal, settings.mode, white=white, **inputs)


def _tuning(path: str) -> dict[str, Any]:
    return _cached(("tuning", path), lambda: load_tuning(path))


def _write(settings: Settings, job: Job, rgb: np.ndarray, made: dict[str, Any], matrix: ColourMatrix | None) -> None:
    if settings.zarr_array is not None:
        write_frame(settings.zarr_array, job.index, rgb, settings.mosaic, source=job.source)
        return
    info: dict[str, Any] = {
        "source": Path(job.source).name,
        "calibration": Path(settings.calibration).name,
        "mode": settings.mode,
        "binned": settings.binned,
    }
    if settings.processed:
        info["input_encoding"] = settings.input_encoding
    info[MADE_WITH] = made
    write_corrected(
        _target(job),
        rgb,
        settings.output_format,
        info,
        colour_matrix=matrix,
        overwrite=settings.overwrite,
        compression=settings.compression,
    )


def _target(job: Job) -> str:
    if job.target is None:
        raise OutputError("has no output file planned (a zarr frame sent to a folder batch)", job.source)
    return job.target


def _write_gain_map_dng(settings: Settings, job: Job, raw: RawImage, cal: Calibration) -> None:
    """``dng-gainmap``: the raw frame unchanged, the calibration's flat field as GainMap opcodes (docs/dng.md); the
    gain map is made once per worker."""
    key = ("gain map", settings.calibration, settings.calibration_sha256)
    write_dng(_target(job), raw, overwrite=settings.overwrite, gain_map=_cached(key, lambda: flat_field_gain_map(cal)))


def _write_linear_dng(
    settings: Settings, job: Job, rgb: np.ndarray, source_metadata: dict[str, Any], cal: Calibration
) -> None:
    """``linear-dng``: the corrected image as a LinearRaw DNG with the source's colour (docs/dng.md)."""
    write_linear_dng(
        _target(job),
        rgb,
        metadata={MADE_WITH: source_metadata[MADE_WITH]} if settings.processed else source_metadata,
        sensor=cal.sensor,
        to_camera=cal.centre_response if settings.mode == Mode.PURE else None,
        overwrite=settings.overwrite,
    )


def _colour_matrix(settings: Settings, source_metadata: dict[str, Any]) -> ColourMatrix:
    """The sRGB formats' colour matrix: none for processed images (already in the ISP's output, sRGB, space) and
    for ``pure`` mode (the calibration's primaries, not the camera's), else :func:`picamcal.output.camera_to_srgb`."""
    if settings.processed:
        return ColourMatrix(np.eye(3), "none: a processed image is in the ISP's output (sRGB) space already")
    if settings.mode == Mode.PURE:
        return ColourMatrix(np.eye(3), "none: mode pure writes the calibration's primaries, taken as sRGB's")
    if settings.tuning is None:
        return camera_to_srgb(source_metadata)
    return camera_to_srgb(source_metadata, _tuning(settings.tuning), tuning_path=settings.tuning)


__all__ = [
    "Job",
    "Outcome",
    "Settings",
    "calibration_of",
    "check_worker",
    "outcomes",
    "process_jobs",
    "set_stop",
    "stop_on_signal",
    "tasks_running",
]
