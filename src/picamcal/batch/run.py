"""The batch: check everything about it, plan the outputs, run the tasks, and record what each did."""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import refuse_foreign, refuse_inputs_as_output
from ..calibration import Calibration, load_calibration
from ..errors import OutputError, PicamcalError, PicamcalWarning
from ..export.tuning import load_tuning
from ..output import OUTPUT_SUFFIXES, camera_to_srgb, is_picamcal_output, output_bytes
from ..output.ome_zarr import ZarrStack
from ..raw.processed import linearise, read_processed
from ..records import sha256_file
from .disk import prepare_folder, probe
from .executors import Dask, InProcess, Pool, Runner, available_cores, connect
from .inputs import expand_inputs, is_pattern
from .options import BatchOptions
from .worker import Job, Settings

PathArg = str | os.PathLike[str]


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


def run_batch(
    calibration_path: PathArg,
    inputs: PathArg | Iterable[PathArg],
    options: BatchOptions,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> BatchResult:
    """Correct many images in parallel; write an image file for each (``out_dir/<stem>.tiff``, ...) or one zarr stack.

    Everything about the batch as a whole is checked before any work: the options (when ``options`` was
    made), the calibration, the tuning file and white reference, the inputs, the scheduler, and that the
    output place can be written (a probe file the size of one output, removed again). After that a file that
    fails (unreadable, or not of the calibration's size, sensor and Bayer order) is recorded in
    :attr:`BatchResult.failed` and the others go on; only an output place that becomes unusable (disk full,
    read-only) stops the batch, with an :class:`~picamcal.errors.OutputError`.

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
    decode = _check_files(options)
    cal = load_calibration(calibration_path)
    cal.check_mode(options.mode)  # a flat-field calibration has no centre or pure mode: say so before any work
    if options.output_format == "dng-gainmap":  # a flat field beyond the opcode's gains: say so before any work
        from ..raw import flat_field_gain_map

        flat_field_gain_map(cal)
    if options.processed:
        _check_processed_references(options.white, options.tuning, decode)
    settings = _settings(calibration_path, options, decode)
    items = [inputs] if isinstance(inputs, (str, os.PathLike)) else list(inputs)
    sources = expand_inputs(items, options.input_suffixes)
    named = [item for item in items if not is_pattern(item)]
    refuse_inputs_as_output(options.place, [calibration_path, options.white, options.tuning, *named, *sources])
    if options.mosaic is not None and len(sources) > options.mosaic[0] * options.mosaic[1]:
        columns, rows = options.mosaic
        raise PicamcalError(f"{len(sources)} frames do not fit a mosaic of {columns} x {rows} tiles")
    stack = None
    if options.zarr_path is None:
        jobs, skipped = _plan_files(sources, options.place, options.overwrite, OUTPUT_SUFFIXES[options.output_format])
    else:
        absolute = [str(source.absolute()) for source in sources]
        calibration_name = Path(settings.calibration).name
        stack = ZarrStack(options.place, absolute, _signature(settings), calibration_name, options.mosaic)
        todo = stack.plan(options.overwrite)
        jobs = [Job(i, absolute[i], None) for i in todo]
        skipped = [source for i, source in enumerate(sources) if i in stack.done]
    if not jobs:  # everything done already: a finished batch run again has nothing to do
        return BatchResult(done=[], skipped=skipped, failed=[])
    frame_shape = _frame_shape(cal, sources, jobs, settings)

    client = None if options.scheduler is None else connect(options.scheduler, settings, options.scheduler_timeout)
    try:
        if stack is not None:
            stack.prepare(frame_shape, cal.bin_size if options.binned else 1, options.compression)
            probe(options.place, output_bytes("float32-tiff", frame_shape))
        else:
            prepare_folder(options.place, output_bytes(options.output_format, frame_shape))
        runner: Runner
        if client is not None:
            runner = Dask(settings, client)
        elif options.workers == 0 or (options.workers is None and len(jobs) == 1):  # a pool for one file: overhead
            runner = InProcess(settings)
        else:
            runner = Pool(settings, max(1, min(options.workers or available_cores(), len(jobs))))
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
            f"{place_error}; stopped after {len(result.done)} of {len(jobs)} files (run again to resume)",
            options.place,
        )
    return result


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


def _settings(calibration_path: PathArg, options: BatchOptions, decode: str) -> Settings:
    """What the workers need, with absolute paths (a dask worker has another working folder)."""
    return Settings(
        calibration=str(Path(calibration_path).absolute()),
        calibration_sha256=sha256_file(Path(calibration_path)),
        mode=str(options.mode),
        binned=options.binned,
        processed=options.processed,
        input_encoding=options.encoding,
        decode=decode,
        read_options=options.read_options,
        white=None if options.white is None else str(Path(options.white).absolute()),
        tuning=None if options.tuning is None else str(Path(options.tuning).absolute()),
        compression=options.compression,
        output_format=options.output_format,
        overwrite=options.overwrite,
        zarr_array=None if options.zarr_path is None else str(Path(options.zarr_path).absolute() / "0"),
        mosaic=options.mosaic,
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


def _plan_files(sources: list[Path], out_dir: Path, overwrite: bool, suffix: str) -> tuple[list[Job], list[Path]]:
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
            jobs.append(Job(index, str(source.absolute()), str(target.absolute())))
    return jobs, skipped


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
) -> str | None:
    """Run the jobs and record each outcome. Returns why the output place became unusable, if it did (then no
    more work was started)."""
    place_error = None
    count = 0
    if progress is not None:
        progress(0, len(jobs))
    by_index = {job.index: job for job in jobs}
    outcomes = runner.outcomes(jobs, lambda: place_error is not None)
    try:
        for outcome in outcomes:
            job = by_index[outcome.index]
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
        outcomes.close()  # a pipeline in this process stops its stages if the loop ended early
        runner.close()
        if stack is not None:
            stack.write_record()
    return place_error


__all__ = ["BatchResult", "run_batch"]
