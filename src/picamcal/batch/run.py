"""The batch: check everything about it, plan the outputs, run the tasks, and record what each did."""

from __future__ import annotations

import os
import shutil
import signal
import time
import uuid
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import (
    discard_own_temporaries,
    is_own_folder,
    refuse_foreign,
    refuse_inputs_as_output,
    remove_stale_temporaries,
)
from ..calibration import Calibration
from ..correct import choose_mode
from ..errors import OutputError, PicamcalError, PicamcalWarning
from ..export.tables import load_flat_field
from ..export.tuning import load_tuning
from ..modes import Mode, best_mode_reason
from ..output import OUTPUT_SUFFIXES, camera_to_srgb, is_picamcal_output, output_bytes
from ..output.ome_zarr import ZarrStack
from ..raw.processed import linearise, read_processed
from ..records import sha256_file
from . import claims
from .disk import missing_folders, prepare_folder, probe, remove_empty_folders
from .executors import Dask, InProcess, Pool, Runner, available_cores, connect
from .inputs import expand_inputs, is_pattern
from .options import BatchOptions
from .record import batch_settings, file_identity, summary
from .stopping import Interrupt
from .worker import Job, Outcome, Settings, existing_output, keep_calibration

PathArg = str | os.PathLike[str]


@dataclass
class BatchResult:
    """What a batch did, each list in input order.

    Attributes
    ----------
    done : list of Path
        Inputs corrected and written by this run.
    skipped : list of Path
        Inputs whose output existed already, made with this run's settings (written by an earlier, perhaps
        interrupted, run).
    kept : list of (Path, list of str)
        Inputs whose output existed already, made with other settings, and was kept (without ``overwrite``):
        with how those differ (:func:`picamcal.batch.record.differences`, ``"black level 0, now 64"``).
    by_another_run : list of Path
        Inputs whose output another run writing into the same folder at the same time wrote, with this run's
        settings (:mod:`picamcal.batch.claims`).
    failed : list of (Path, str)
        Inputs that could not be corrected, with the reason in one line.
    mode : Mode or None
        The mode the batch corrected in (None only for a result made by hand).
    mode_reason : str or None
        Why, when the options left the mode to the calibration (:func:`picamcal.modes.best_mode_reason`).
    """

    done: list[Path] = field(default_factory=list)
    skipped: list[Path] = field(default_factory=list)
    failed: list[tuple[Path, str]] = field(default_factory=list)
    mode: Mode | None = None
    mode_reason: str | None = None
    kept: list[tuple[Path, list[str]]] = field(default_factory=list)
    by_another_run: list[Path] = field(default_factory=list)

    def kept_message(self) -> str | None:
        """One line on the outputs kept although made with other settings; None if there are none.

        Examples
        --------
        >>> BatchResult(kept=[(Path("a.dng"), ["black level 0, now 64"])]).kept_message()
        'kept 1 output made with other settings (black level 0, now 64): use --overwrite to remake them'
        """
        if not self.kept:
            return None
        count = len(self.kept)
        return (
            f"kept {count} output{'s' if count > 1 else ''} made with other settings ({summary(self.kept)}): "
            "use --overwrite to remake them"
        )

    def failure_of_one_file(self) -> PicamcalError | None:
        """A batch of one file that failed: that file's failure, as the error a command of one file raises
        (the command line's one line and exit status 2); otherwise None.

        Examples
        --------
        >>> BatchResult(failed=[(Path("a.dng"), "no such file")]).failure_of_one_file()
        PicamcalError('a.dng: no such file')
        >>> BatchResult(done=[Path("b.dng")], failed=[(Path("a.dng"), "no such file")]).failure_of_one_file()
        """
        if len(self.failed) != 1 or self.done or self.skipped or self.kept or self.by_another_run:
            return None
        path, reason = self.failed[0]
        return PicamcalError(reason, path)


class BatchInterrupted(KeyboardInterrupt):
    """A batch stopped by SIGINT (Ctrl-C) or SIGTERM (:mod:`picamcal.batch.stopping`): it started no new file,
    finished or dropped the files in flight and removed their temporaries; running it again resumes.

    A :class:`KeyboardInterrupt`, so that a script that does not catch it stops as on Ctrl-C. Its text is the
    one line the command line prints.

    Attributes
    ----------
    result : BatchResult
        What the batch did before it stopped.
    total : int
        The files it had to do (those done already not counted).
    place : Path
        Its output folder or stack.
    signum : int
        The signal; the command line exits with status 128 + ``signum`` (130 for SIGINT, 143 for SIGTERM).

    Examples
    --------
    >>> import signal
    >>> str(BatchInterrupted(BatchResult(done=[Path("a.dng")]), 24, Path("out"), signal.SIGINT))
    'interrupted by SIGINT: wrote 1 of 24 image(s) to out; run the same command again to resume'
    """

    def __init__(self, result: BatchResult, total: int, place: Path, signum: int) -> None:
        super().__init__(result, total, place, signum)
        self.result, self.total, self.place, self.signum = result, total, place, signum

    def __str__(self) -> str:
        name = signal.Signals(self.signum).name
        if not self.total:
            return f"interrupted by {name} before any file was started: nothing written"
        failed = f" ({len(self.result.failed)} failed)" if self.result.failed else ""
        return (
            f"interrupted by {name}: wrote {len(self.result.done)} of {self.total} image(s) to {self.place}{failed}; "
            "run the same command again to resume"
        )


def run_batch(
    calibration_path: PathArg,
    inputs: PathArg | Iterable[PathArg],
    options: BatchOptions,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> BatchResult:
    """Correct many images in parallel; write an image file for each (``out_dir/<stem>.tiff``, ...) or one zarr stack.

    Everything about the batch as a whole is checked before any work: the options (when ``options`` was
    made), the calibration and the mode (without one, the best the calibration does:
    :func:`picamcal.correct.choose_mode`), the tuning file and white reference, the inputs, the scheduler, and
    that the output place can be written (a probe file the size of one output, removed again). After that a
    file that fails (unreadable, or not of the calibration's size, sensor and Bayer order) is recorded in
    :attr:`BatchResult.failed` and the others go on; only an output place that becomes unusable (disk full,
    read-only) stops the batch, with an :class:`~picamcal.errors.OutputError`. A batch that writes nothing
    leaves no output folder it created.

    The output place may lie inside a folder of inputs (``scans/corrected`` for ``scans/``) when it is new or
    picamcal's own (:func:`picamcal._atomic.is_own_folder`); it is never read as input, from a folder or a
    pattern. SIGINT and SIGTERM stop the batch within about a second (:mod:`picamcal.batch.stopping`): no
    new file is started, the files in flight are finished or dropped, their temporaries removed, and
    :class:`BatchInterrupted` is raised.

    Parameters
    ----------
    calibration_path : path-like
        Calibration file (.npz) from :meth:`picamcal.Calibration.save`.
    inputs : path-like or iterable of path-like
        Files, folders or glob patterns (:func:`expand_inputs`; folders give the files of
        :attr:`BatchOptions.input_suffixes`).
    options : BatchOptions
        Where and how: the output folder or zarr stack, mode, format, workers or scheduler, reading options.
    progress : callable, optional
        Called as ``progress(finished, total)`` when the work starts and after each file, ``total``
        counting the files to do (not the skipped ones).

    Returns
    -------
    BatchResult

    Raises
    ------
    TypeError
        ``options`` is not a :class:`BatchOptions`.
    PicamcalError
        Before any work, for anything wrong with the batch as a whole; ``OutputError`` if the output place
        cannot be written, at the start or when it fills up (the message says how far the batch got).
    BatchInterrupted
        SIGINT or SIGTERM stopped it (a KeyboardInterrupt); it says how far the batch got.

    Examples
    --------
    >>> from picamcal.simulate import simulate_run
    >>> refs = simulate_run("run1", "imx219", size=(320, 240), seed=1)
    >>> cal = picamcal.calibrate(**{r: picamcal.read_raw(refs[r]) for r in ("white", "red", "green", "blue")})
    >>> cal.save("cal.npz")
    PosixPath('cal.npz')
    >>> result = run_batch("cal.npz", ["run1/t*.dng", "run1/white.dng"], BatchOptions(out_dir="corrected", workers=0))
    >>> [p.name for p in result.done], result.failed
    (['target.dng', 'white.dng'], [])
    >>> again = run_batch("cal.npz", ["run1/target.dng"], BatchOptions(out_dir="corrected", workers=0))
    >>> again.done, [p.name for p in again.skipped]  # done already: an interrupted batch resumes
    ([], ['target.dng'])
    """
    if not isinstance(options, BatchOptions):  # the call of picamcal 0.1, run_batch(cal, inputs, out_dir, ...)
        raise TypeError(f"run_batch takes BatchOptions(out_dir=..., ...), not a {type(options).__name__}")
    with Interrupt() as interrupt:
        try:
            return _run(calibration_path, inputs, options, progress, interrupt)
        except KeyboardInterrupt as exc:  # a signal before the work started: nothing was written
            if isinstance(exc, BatchInterrupted) or interrupt.signum is None:
                raise
            raise BatchInterrupted(BatchResult(), 0, options.place, interrupt.signum) from None


def _run(
    calibration_path: PathArg,
    inputs: PathArg | Iterable[PathArg],
    options: BatchOptions,
    progress: Callable[[int, int], None] | None,
    interrupt: Interrupt,
) -> BatchResult:
    decode = _check_files(options)
    # A lens shading table a user has (OpenFlexure's, a tuning file) is its flat field, for the raw frames' sensor.
    cal = load_flat_field(calibration_path, options.sensor)
    mode = choose_mode(cal, options.mode)  # a flat-field calibration has no centre or pure mode: say so before work
    if options.output_format == "dng-gainmap":  # a flat field beyond the opcode's gains: say so before any work
        from ..raw import flat_field_gain_map

        flat_field_gain_map(cal)
    if options.processed:
        _check_processed_references(options.white, options.tuning, decode)
    settings = _settings(calibration_path, options, decode, mode)
    items = [inputs] if isinstance(inputs, (str, os.PathLike)) else list(inputs)
    sources = expand_inputs(items, options.input_suffixes, skip=options.place)
    named = [item for item in items if not is_pattern(item)]
    read = [calibration_path, options.white, options.tuning, *named, *sources]
    refuse_inputs_as_output(options.place, read, own_folder=_own_place(options))
    if options.mosaic is not None and len(sources) > options.mosaic[0] * options.mosaic[1]:
        columns, rows = options.mosaic
        raise PicamcalError(f"{len(sources)} frames do not fit a mosaic of {columns} x {rows} tiles")
    stack = None
    kept: list[tuple[Path, list[str]]] = []
    failed: list[tuple[Path, str]] = []
    if options.zarr_path is None:
        jobs, skipped, kept, failed = _plan_files(
            sources, options.place, settings, OUTPUT_SUFFIXES[options.output_format]
        )
    else:
        absolute = [str(source.absolute()) for source in sources]
        calibration_name = Path(settings.calibration).name
        stack = ZarrStack(options.place, absolute, _signature(settings), calibration_name, options.mosaic)
        todo = stack.plan(options.overwrite)
        jobs = [Job(i, absolute[i], None) for i in todo]
        skipped = [source for i, source in enumerate(sources) if i in stack.done]
    reason = best_mode_reason(cal.has_unmixing) if options.mode is None else None
    result = BatchResult(skipped=skipped, kept=kept, failed=failed, mode=mode, mode_reason=reason)
    if not jobs:  # everything done already: a finished batch run again has nothing to do
        return result
    frame_shape = _frame_shape(cal, sources, jobs, settings)

    client = None if options.scheduler is None else connect(options.scheduler, settings, options.scheduler_timeout)
    created: list[Path] = []
    place_error = None
    left_to_others: set[int] = set()  # the jobs whose output another run claimed: its to write
    try:
        if stack is not None:
            created = [] if stack.resuming else missing_folders(options.place)
            stack.prepare(frame_shape, cal.bin_size if options.binned else 1, options.compression)
            probe(options.place, output_bytes("float32-tiff", frame_shape))
        else:
            created = prepare_folder(options.place, output_bytes(options.output_format, frame_shape))
        runner: Runner
        if client is not None:
            runner = Dask(settings, client)
        elif options.workers == 0 or (options.workers is None and len(jobs) == 1):  # a pool for one file: overhead
            runner = InProcess(settings)
            keep_calibration(settings, cal)
        else:
            runner = Pool(settings, max(1, min(options.workers or available_cores(), len(jobs))))
        interrupt.working()
        started_ns = time.time_ns() - 20_000_000  # file times come from a coarser clock, a few ms behind
        try:
            place_error = _drive(runner, jobs, sources, result, stack, progress, interrupt, settings, left_to_others)
        finally:
            runner.close()
    finally:
        if stack is not None:
            stack.release()
            if interrupt.is_set():
                stack.remove_partials()  # the chunks the killed workers were writing
        if client is not None:
            client.close()
        if interrupt.is_set() and stack is None:  # the writes dropped: a killed worker's, or one left to a thread
            remove_stale_temporaries(options.place)
            discard_own_temporaries(options.place)
            claims.remove_stale_claims(options.place)
        if not result.done:  # a stack this run made holds no frame: it goes too, if no other run writes it now
            if stack is not None and options.place in created and stack.unused():
                shutil.rmtree(options.place, ignore_errors=True)
            remove_empty_folders(created)
    if interrupt.is_set() and stack is None:  # a killed worker's task reports none of the files it wrote
        _count_written([job for job in jobs if job.index not in left_to_others], sources, result, started_ns)
    order = {path: i for i, path in enumerate(sources)}
    result.done.sort(key=order.__getitem__)
    result.failed.sort(key=lambda item: order[item[0]])
    if interrupt.signum is not None:
        raise BatchInterrupted(result, len(jobs), options.place, interrupt.signum)
    if place_error is not None:
        raise OutputError(
            f"{place_error}; stopped after {len(result.done)} of {len(jobs)} files (run again to resume)",
            options.place,
        )
    return result


def _count_written(jobs: Sequence[Job], sources: list[Path], result: BatchResult, since_ns: int) -> None:
    """Add to ``result.done`` the files an interrupted batch wrote whose task was dropped before it reported them:
    their outputs are in place (renamed there whole, or not at all), written since the work began."""
    reported = {
        *result.done,
        *(path for path, _ in result.failed),
        *result.by_another_run,
        *(p for p, _ in result.kept),
    }
    for job in jobs:
        source = sources[job.index]
        if source in reported or job.target is None:
            continue
        try:
            written = os.stat(job.target, follow_symlinks=False).st_mtime_ns >= since_ns
        except OSError:  # not written
            continue
        if written:
            result.done.append(source)


def _own_place(options: BatchOptions) -> Callable[[Path], bool]:
    """Whether an existing output place inside a folder of inputs is picamcal's own: a folder of its images (a
    zarr stack of another kind is refused by the stack's own plan)."""
    if options.zarr_path is not None:
        return lambda place: True
    return lambda place: is_own_folder(place, is_picamcal_output)


def _check_files(options: BatchOptions) -> str:
    """The checks of the options that need files or packages (the tuning file's colour matrix, the input
    encoding, imagecodecs); returns the encoding as workers decode it (a tuning file's path made absolute)."""
    if options.tuning is not None and not options.processed:
        camera_to_srgb({}, load_tuning(options.tuning), tuning_path=options.tuning)  # no rpi.ccm: fail before work
    decode = options.encoding
    if decode.startswith("tuning:"):  # absolute, for workers with another working folder
        decode = f"tuning:{Path(decode.removeprefix('tuning:')).absolute()}"
    linearise(np.zeros(1), decode)  # a bad encoding fails here, before any work
    if options.compression is not None and options.zarr_path is None:
        _require_imagecodecs()
    return decode


def _settings(calibration_path: PathArg, options: BatchOptions, decode: str, mode: Mode) -> Settings:
    """What the workers need, with absolute paths (a dask worker has another working folder), and what the outputs
    record of how they were made (:func:`picamcal.batch.record.batch_settings`)."""
    calibration_sha256 = sha256_file(Path(calibration_path))
    geometry = {"sensor_crop": options.sensor_crop, "sensor_mode": options.sensor_mode}
    record = batch_settings(
        calibration=calibration_path,
        calibration_sha256=calibration_sha256,
        mode=str(mode),
        binned=options.binned,
        processed=options.processed,
        output_format=options.output_format,
        compression=options.compression,
        read_options=options.read_options,
        geometry=geometry,
        input_encoding=options.encoding,
        white=file_identity(options.white),
        tuning=file_identity(options.tuning),
    )
    return Settings(
        calibration=str(Path(calibration_path).absolute()),
        calibration_sha256=calibration_sha256,
        mode=str(mode),
        binned=options.binned,
        processed=options.processed,
        input_encoding=options.encoding,
        decode=decode,
        read_options=options.read_options,
        geometry=geometry,
        white=None if options.white is None else str(Path(options.white).absolute()),
        tuning=None if options.tuning is None else str(Path(options.tuning).absolute()),
        compression=options.compression,
        output_format=options.output_format,
        overwrite=options.overwrite,
        zarr_array=None if options.zarr_path is None else str(Path(options.zarr_path).absolute() / "0"),
        mosaic=options.mosaic,
        record=record,
        started_ns=time.time_ns(),  # an output of a moment before, stamped by a coarser clock, counts as older
        run=uuid.uuid4().hex,
    )


def _signature(settings: Settings) -> dict[str, Any]:
    """What decides a zarr stack's frames besides its sources: a stack made with others is not resumed."""
    return {
        "calibration_sha256": settings.calibration_sha256,
        "mode": settings.mode,
        "binned": settings.binned,
        "processed": settings.processed,
        "input_encoding": settings.input_encoding if settings.processed else None,
        "read_options": {k: list(v) if isinstance(v, tuple) else v for k, v in settings.read_options.items()},
        "white": settings.white,
        "tuning": settings.tuning,
        "mosaic": list(settings.mosaic) if settings.mosaic else None,
        # only when given: the stacks of the runs before the geometry was recorded resume
        **(
            {"geometry": {key: settings.record[key] for key in ("sensor_crop", "sensor_mode")}}
            if any(settings.geometry.values())
            else {}
        ),
    }


def _require_imagecodecs() -> None:
    try:
        import imagecodecs
    except ImportError:
        raise PicamcalError("zstd compression of TIFF files needs the imagecodecs package") from None
    if not imagecodecs.ZSTD.available:
        raise PicamcalError("this imagecodecs was built without zstd")


def _check_processed_references(white: PathArg | None, tuning: PathArg | None, decode: str) -> None:
    """Read the white reference and tuning file once here, so that a bad one fails before any work."""
    if white is not None:
        read_processed(white, decode)
    if tuning is not None:
        load_tuning(tuning)


def _plan_files(
    sources: list[Path], out_dir: Path, settings: Settings, suffix: str
) -> tuple[list[Job], list[Path], list[tuple[Path, list[str]]], list[tuple[Path, str]]]:
    """One job per input whose file (``<stem><suffix>``) is still to write; the inputs whose output is in place,
    made with these settings (skipped) or with others (kept, and how they differ); the inputs whose output's name is
    taken by a file picamcal did not write (failed). Refuse name clashes and outputs that would replace an input,
    and, to ``overwrite``, a file picamcal did not write."""
    inputs = {Path(os.path.realpath(source)) for source in sources}
    writers: dict[str, Path] = {}
    jobs, skipped, kept, failed = [], [], [], []
    for index, source in enumerate(sources):
        target = out_dir / f"{source.stem}{suffix}"
        if target.name in writers:
            raise OutputError(f"two inputs would both write {target.name}; correct them separately", source)
        writers[target.name] = source
        if Path(os.path.realpath(target)) in inputs:
            raise OutputError("output would replace an input file; choose another --out", target)
        if settings.overwrite:
            refuse_foreign(target, is_picamcal_output, "an image picamcal wrote")
        try:
            existing = existing_output(str(target), settings)
        except OutputError as exc:
            failed.append((source, f"its output {exc}"))
            continue
        if existing is None:
            jobs.append(Job(index, str(source.absolute()), str(target.absolute())))
        elif existing.kind == "written":
            skipped.append(source)
        else:
            kept.append((source, list(existing.kept)))
    return jobs, skipped, kept, failed


def _frame_shape(cal: Calibration, sources: list[Path], jobs: list[Job], settings: Settings) -> tuple[int, ...]:
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


def _drive(
    runner: Runner,
    jobs: Sequence[Job],
    sources: list[Path],
    result: BatchResult,
    stack: ZarrStack | None,
    progress: Callable[[int, int], None] | None,
    interrupt: Interrupt,
    settings: Settings,
    left_to_others: set[int],
) -> str | None:
    """Run the jobs and record each outcome. Returns why the output place became unusable, if it did (then no
    more work was started). Interrupted, the files whose task was lost (its worker killed) are neither done nor
    failed: a re-run does them.

    An output another run writing into the same folder has claimed (:mod:`picamcal.batch.claims`) is left to it;
    once that run is done with it, the output is either in place (written by the other run) or still to write
    (the other run failed or was stopped), and then this run does it. ``left_to_others`` gets the index of every job
    whose output another run claimed."""
    place_error = None
    finished = 0
    if progress is not None:
        progress(0, len(jobs))
    by_index = {job.index: job for job in jobs}
    todo, claimed = list(jobs), []

    def place_failed() -> bool:
        return place_error is not None

    while todo:
        outcomes = runner.outcomes(todo, place_failed, interrupt)
        try:
            for outcome in outcomes:
                if outcome.lost and interrupt.is_set():
                    continue
                job = by_index[outcome.index]
                if outcome.elsewhere == "claimed":
                    claimed.append(job)
                    left_to_others.add(job.index)
                    continue
                place_error = place_error or _record(outcome, job, sources[job.index], result, stack)
                finished += 1
                if progress is not None:
                    progress(finished, len(jobs))
        finally:
            outcomes.close()  # a pipeline in this process stops its stages if the loop ended early
            if stack is not None:
                stack.write_record()
        todo = []
        while claimed and not todo and not interrupt.is_set() and place_error is None:
            todo, claimed = _claims_let_go(claimed, sources, result, settings)
            finished = len(jobs) - len(claimed) - len(todo)
            if progress is not None:
                progress(finished, len(jobs))
    return place_error


def _record(outcome: Outcome, job: Job, source: Path, result: BatchResult, stack: ZarrStack | None) -> str | None:
    """Put one job's outcome into ``result``; returns why the output place is unusable, if the outcome says so."""
    for message in outcome.warnings:
        warnings.warn(message.replace(job.source, str(source), 1), PicamcalWarning, stacklevel=3)
    if outcome.error is not None:
        result.failed.append((source, outcome.error))
        return outcome.place_error
    if outcome.elsewhere == "written":
        result.by_another_run.append(source)
    elif outcome.elsewhere == "kept":
        result.kept.append((source, list(outcome.kept)))
    else:
        result.done.append(source)
        if stack is not None:
            stack.finished(job.index)
    return None


#: Seconds between two looks at the claims of another run that this run waits for.
_CLAIM_LOOK_S = 0.05


def _claims_let_go(
    claimed: list[Job], sources: list[Path], result: BatchResult, settings: Settings
) -> tuple[list[Job], list[Job]]:
    """Wait a moment for the claims of other runs on ``claimed`` outputs; put those let go and in place into
    ``result``; return the jobs let go whose output is still to write (this run's to do), and those still claimed."""
    time.sleep(_CLAIM_LOOK_S)
    todo, still = [], []
    for job in claimed:
        assert job.target is not None  # only files are claimed
        if claims.is_claimed(job.target):
            still.append(job)
            continue
        source = sources[job.index]
        try:
            existing = existing_output(job.target, settings)
        except OutputError as exc:
            result.failed.append((source, f"its output {exc}"))
            continue
        if existing is None:
            todo.append(job)
        else:
            _record(Outcome(job.index, elsewhere=existing.kind, kept=existing.kept), job, source, result, None)
    return todo, still


__all__ = ["BatchInterrupted", "BatchResult", "run_batch"]
