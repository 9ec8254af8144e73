"""Correct many images at once: a process pool on this machine, or an existing dask.distributed cluster.

One function, :func:`run_batch`, takes files, folders or glob patterns (:func:`expand_inputs`) and one
:class:`BatchOptions` value, and writes one image per input in one of :data:`picamcal.output.OUTPUT_FORMATS`
(float32 linear RGB TIFF by default; uint16 linear TIFF; colour-managed sRGB PNG or JPEG), or one chunked
float32 OME-Zarr stack (:mod:`picamcal.output.ome_zarr`). The same per-file task runs in this process, in a
local process pool or on a dask cluster, so the outputs are the same bytes either way.

The modules: :mod:`~picamcal.batch.options` (the options, checked once), :mod:`~picamcal.batch.inputs`
(files, folders and patterns), :mod:`~picamcal.batch.disk` (the output place and its room),
:mod:`~picamcal.batch.stopping` (SIGINT and SIGTERM), :mod:`~picamcal.batch.record` (the settings each output
records), :mod:`~picamcal.batch.claims` (batches writing into one folder at once),
:mod:`~picamcal.batch.worker` (the task and what a worker keeps), :mod:`~picamcal.batch.pipeline` (a
worker's reading, correcting and writing overlapped), :mod:`~picamcal.batch.executors` (this process, a pool,
dask) and :mod:`~picamcal.batch.run` (:func:`run_batch` itself).

What it guarantees:

- **Overlapped stages.** Each worker reads the next file and writes the last one while it corrects one, in
  threads (file reads and LibRaw's decoding, the kernel, compression and file writes release the GIL), so that a
  file costs about its slowest stage rather than the sum (:mod:`~picamcal.batch.pipeline`). A pool or cluster gets the
  files in tasks of a few consecutive files (:func:`~picamcal.batch.executors.chunks`).
- **Bounded memory.** A worker holds at most two corrected images and two decoded inputs
  (:data:`~picamcal.batch.pipeline.OUTPUT_SLOTS`, :data:`~picamcal.batch.pipeline.READ_AHEAD`), whatever the
  number of files; at most two tasks per worker are in flight; inputs are read by the workers, never all up
  front; a task returns a few words per file, not its images.
- **Calibration loaded once per worker** (a module-level cache keyed by the file's path and SHA-256).
- **No half-written output.** Every file is written to a temporary name and renamed; zarr chunks likewise
  (zarr's local store writes each chunk to a temporary name). Temporaries left by a killed batch are
  removed by the next run (:func:`picamcal._atomic.remove_stale_temporaries`).
- **Nothing left running.** The pool's workers end when this process ends, even by ``kill -9``; then the
  forkserver and multiprocessing's resource tracker, which wait for them, end too.
- **Resumable.** Existing outputs made with the same settings are skipped unless ``overwrite``; the zarr stack
  records its finished frames in its attributes. Running the same command again finishes an interrupted batch.
- **Honest about what is in place.** Every output records the settings that made it
  (:mod:`~picamcal.batch.record`); one made with other settings is kept and reported (``BatchResult.kept``,
  naming what differs) unless ``overwrite``, which replaces only what picamcal wrote.
- **Shared with other runs.** Batches writing into one folder at once claim each output before reading its input
  (:mod:`~picamcal.batch.claims`): each output is written by one of them, each waits for the others' and reports
  them (``BatchResult.by_another_run``); a killed run's claims are taken over.
- **Stopped cleanly.** On SIGINT (Ctrl-C) or SIGTERM no new file is started, the files in flight are finished
  or dropped within about a second, their temporaries are removed, and :class:`BatchInterrupted` says how many
  were written (:mod:`~picamcal.batch.stopping`).
- **Outputs beside the inputs.** The output folder may lie inside a folder of inputs when it is new or
  picamcal's own; folder scans and patterns never take its files as inputs.
- **A bad file does not stop the others,** whichever it is, the first included: a corrupt file, or one of
  another size or sensor than the calibration's. Its reason is in :attr:`BatchResult.failed`. Problems with
  the whole batch (the options, the calibration, the output folder, the scheduler) raise a
  :class:`~picamcal.errors.PicamcalError` before any work.

Examples
--------
>>> from picamcal.batch import BatchOptions, run_batch
>>> from picamcal.simulate import simulate_run
>>> refs = simulate_run("run1", "imx219", size=(320, 240), seed=1)
>>> cal = picamcal.calibrate(**{r: picamcal.read_raw(refs[r]) for r in ("white", "red", "green", "blue")})
>>> cal.save("cal.npz")
PosixPath('cal.npz')
>>> options = BatchOptions(zarr_path="frames.zarr", mode="flat", workers=0)
>>> len(run_batch("cal.npz", ["run1/target.dng", "run1/white.dng"], options).done)
2
"""

from __future__ import annotations

from ..output.ome_zarr import OME_NGFF_VERSION
from .inputs import expand_inputs
from .options import COMPRESSIONS, BatchOptionError, BatchOptions
from .run import BatchInterrupted, BatchResult, run_batch

__all__ = [
    "COMPRESSIONS",
    "OME_NGFF_VERSION",
    "BatchInterrupted",
    "BatchOptionError",
    "BatchOptions",
    "BatchResult",
    "expand_inputs",
    "run_batch",
]
