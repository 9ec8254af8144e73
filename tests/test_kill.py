"""kill -9 of calibrate, correct (with workers), report and correct --zarr while they work; SIGINT and SIGTERM
of a correct batch (the pool, this process, a zarr stack, a dask cluster).

Each run carries a tag in its environment, which every process it starts inherits (the forkserver, the
resource tracker, the pool's workers): after the kill no process with that tag may be left, no file may be
half-written under its final name, and running the same command again finishes the work and leaves no
temporary. The kill lands when a temporary of the run appears (the work is under way), not after a fixed time.

An interrupted batch (SIGINT as Ctrl-C sends it, to the whole process group; SIGTERM as ``kill`` sends it, to
the command alone, or as ``timeout`` and systemd do, to the whole group) must start no new file, leave no
temporary and no process, and end with one line saying how many files it wrote and that running it again
resumes, with exit status 130 or 143. The signal lands when some outputs are finished, not after a fixed time.
The count it says is exactly the outputs on disk: on a dask cluster, whose workers outlive the command, the writes
under way at the signal end after it, and a test slows them past the grace so that this race is certain.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import numpy as np
import psutil
import pytest
import tifffile

from conftest import simulated_calibration
from picamcal import load_calibration
from picamcal.batch import BatchOptions, run_batch
from picamcal.batch.pipeline import OUTPUT_SLOTS, READ_AHEAD

SIZE = (640, 480)  # big enough that the work lasts while the test looks for its temporaries
FRAMES = 10
TAG = "PICAMCAL_KILL_TEST"
#: How long the processes of a killed run may take to end (they end at once; this only bounds a failing test).
GONE_WITHIN_S = 30.0


def as_from_a_terminal() -> None:
    """In the child, before it runs: SIGINT as a terminal gives it, whatever this test run inherited (started in the
    background, by nohup or ``&``, SIGINT is ignored, and picamcal, rightly, leaves an ignored signal ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def command(*args: str) -> list[str]:
    return [sys.executable, "-c", "from picamcal.cli import main; main()", *args]


def start(*args: str) -> tuple[subprocess.Popen, str]:
    """Start a picamcal command whose processes all carry a tag of their own in their environment."""
    tag = uuid.uuid4().hex
    process = subprocess.Popen(
        command(*args),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, TAG: tag},
    )
    return process, tag


def processes_of(tag: str) -> list[psutil.Process]:
    """The live processes carrying ``tag`` (zombies have ended: only their exit status is left)."""
    found = []
    for process in psutil.process_iter():
        try:
            if process.environ().get(TAG) == tag and process.status() != psutil.STATUS_ZOMBIE:
                found.append(process)
        except psutil.Error:  # ended meanwhile, or not ours to read
            continue
    return found


def cmdline(process: psutil.Process) -> str:
    try:
        return " ".join(process.cmdline())
    except psutil.Error:  # ended meanwhile
        return ""


def kill_when(process: subprocess.Popen, under_way: Callable[[], bool], pause: float = 0.01) -> bool:
    """kill -9 the command as soon as ``under_way()``, asked every ``pause`` seconds (0: without a break, for a
    moment of milliseconds); False if the command finished first (the moment was missed)."""
    while process.poll() is None:
        if under_way():
            os.kill(process.pid, signal.SIGKILL)
            process.wait()
            return True
        time.sleep(pause)
    return False


def assert_nothing_left_running(tag: str) -> None:
    deadline = time.monotonic() + GONE_WITHIN_S
    while (left := processes_of(tag)) and time.monotonic() < deadline:
        time.sleep(0.1)
    descriptions = [cmdline(p)[:160] for p in left]
    for process in left:  # ours (they carry the tag): do not leave them running when the test fails
        with contextlib.suppress(psutil.Error):
            process.kill()
    assert descriptions == [], "processes outlived the killed run"


#: picamcal's temporary names (docs/outputs.md), and zarr's chunk temporaries.
TEMPORARY = re.compile(r"\.picamcal-[0-9a-f]{8}-[0-9]+-[0-9a-f]{8}\.tmp|\.partial$")


def temporaries(folder: Path) -> list[str]:
    """The temporaries anywhere under ``folder``."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if TEMPORARY.search(p.name))


def names(folder: Path, pattern: str) -> Callable[[], list[str]]:
    def found() -> list[str]:
        try:
            return [entry.name for entry in os.scandir(folder) if Path(entry.name).match(pattern)]
        except FileNotFoundError:
            return []

    return found


def ordinary_folder_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o777 & ~umask


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict[str, Path]:
    """References, their calibration, FRAMES copies of the target, and their outputs from a serial run."""
    root = tmp_path_factory.mktemp("kill")
    refs, _ = simulated_calibration(root, SIZE, seed=5)
    frames = root / "frames"
    frames.mkdir()
    for i in range(FRAMES):
        shutil.copyfile(refs["target"], frames / f"f{i:02d}.dng")
    result = run_batch(root / "cal.npz", [frames], BatchOptions(out_dir=root / "reference", workers=0))
    assert len(result.done) == FRAMES
    return {"sim": root / "sim", "cal": root / "cal.npz", "frames": frames, "reference": root / "reference"}


@pytest.mark.slow
def test_killed_calibrate_leaves_no_file_and_the_rerun_cleans_up(data, tmp_path):
    out = tmp_path / "cal.npz"
    args = ("calibrate", str(data["sim"]), "--out", str(out), "--bin-size", "2")  # a 17 MB file: saving takes a while
    for attempt in range(5):  # the save lasts some tens of milliseconds: try again if the kill missed it
        process, tag = start(*args)
        killed = kill_when(process, names(tmp_path, ".cal.picamcal-*.tmp.npz"), pause=0)
        assert_nothing_left_running(tag)
        if killed and not out.exists():
            print(f"killed while saving at attempt {attempt + 1}")
            break
        load_calibration(out)  # saved before the kill landed: then it is complete
        out.unlink()
    else:
        pytest.fail("the kill never landed while the calibration was being saved")
    assert len(temporaries(tmp_path)) == 1  # what kill -9 leaves: the temporary being written

    again = subprocess.run(command(*args, "--overwrite"), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert load_calibration(out).white.shape == (SIZE[1] // 2, SIZE[0] // 2, 3)
    assert temporaries(tmp_path) == []


@pytest.mark.slow
def test_killed_correct_with_workers_leaves_no_process_and_no_partial_file(data, tmp_path):
    out = tmp_path / "out"
    args = ("correct", str(data["cal"]), str(data["frames"]), "--out", str(out), "--workers", "2")
    process, tag = start(*args)
    seen: list[psutil.Process] = []

    def under_way() -> bool:  # a worker is writing, and the pool (forkserver and workers) is there to outlive
        if not names(out, ".f*.picamcal-*.tmp.tiff")():
            return False
        seen[:] = processes_of(tag)
        return sum("forkserver" in cmdline(p) for p in seen) >= 3

    assert kill_when(process, under_way, pause=0), "the batch finished before the kill"
    assert any("resource_tracker" in cmdline(p) for p in seen)
    assert_nothing_left_running(tag)
    finished = sorted(p.name for p in out.glob("*.tiff") if not p.name.startswith("."))
    assert len(finished) < FRAMES
    for name in finished:  # complete or absent, never half-written
        assert (out / name).read_bytes() == (data["reference"] / name).read_bytes()

    again = subprocess.run(command(*args), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"skipped {len(finished)} (done already)" in again.stderr
    assert temporaries(out) == []
    assert {p.name: p.read_bytes() for p in out.iterdir()} == {
        p.name: p.read_bytes() for p in data["reference"].iterdir()
    }


@pytest.mark.slow
def test_killed_report_leaves_no_folder_and_the_rerun_cleans_up(data, tmp_path):
    out = tmp_path / "report"
    args = ("report", str(data["cal"]), "--out", str(out))
    process, tag = start(*args)
    building = names(tmp_path, ".report.picamcal-*.tmp")

    def under_way() -> bool:  # the report's folder exists and the first figures are in it
        return bool(building()) and len(list((tmp_path / building()[0]).glob("*.png"))) >= 2

    assert kill_when(process, under_way), "the report was finished before the kill"
    assert_nothing_left_running(tag)
    assert not out.exists()  # the report is renamed into place only when complete
    assert len(temporaries(tmp_path)) >= 1

    again = subprocess.run(command(*args), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert (out / "index.html").is_file() and (out / ".picamcal-report").is_file()
    assert stat.S_IMODE(out.stat().st_mode) == ordinary_folder_mode()  # not a temporary folder's private 0700
    assert temporaries(tmp_path) == []


@pytest.mark.slow
def test_killed_zarr_batch_leaves_no_process_and_resumes(data, tmp_path):
    zarr = pytest.importorskip("zarr")
    stack = tmp_path / "frames.zarr"
    args = ("correct", str(data["cal"]), str(data["frames"]), "--zarr", str(stack), "--workers", "2")
    process, tag = start(*args)
    chunks = names(stack / "0" / "c", "*")

    def under_way() -> bool:  # frames are being written: their chunk folders appear
        return len(chunks()) >= 2

    assert kill_when(process, under_way), "the batch finished before the kill"
    assert_nothing_left_running(tag)
    assert names(tmp_path, ".frames.zarr.picamcal-*.tmp.writing")() != []  # the killed run's mark, for the next run
    reference = [
        np.moveaxis(tifffile.imread(data["reference"] / f"f{i:02d}.tiff"), -1, 0).astype(np.float32)
        for i in range(FRAMES)
    ]
    done = zarr.open_group(stack, mode="r").attrs["picamcal"]["done"]
    array = zarr.open_array(stack / "0", mode="r")
    assert len(done) < FRAMES
    for i in done:  # a frame recorded as done is complete
        np.testing.assert_array_equal(array[i], reference[i])

    again = subprocess.run(command(*args), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert zarr.open_group(stack, mode="r").attrs["picamcal"]["done"] == list(range(FRAMES))
    array = zarr.open_array(stack / "0", mode="r")
    for i in range(FRAMES):  # exact: the same calibration and raw data, the same float32 arithmetic
        np.testing.assert_array_equal(array[i], reference[i])
    assert temporaries(tmp_path) == []


# ---------------------------------------------------------------------------------------------- SIGINT and SIGTERM
#: Frames of an interrupted batch, written as 16-bit PNG: about 0.2 s each on the development PC, so that the
#: batch is still at work when its first outputs are finished.
INTERRUPTED_FRAMES = 16
INTERRUPTED_FORMAT = "srgb-png16"


@pytest.fixture(scope="module")
def pngs(data, tmp_path_factory) -> dict[str, Path]:
    """INTERRUPTED_FRAMES copies of the target, and their outputs from a serial run."""
    root = tmp_path_factory.mktemp("interrupted")
    frames = root / "frames"
    frames.mkdir()
    for i in range(INTERRUPTED_FRAMES):
        shutil.copyfile(data["frames"] / "f00.dng", frames / f"g{i:02d}.dng")
    options = BatchOptions(out_dir=root / "reference", output_format=INTERRUPTED_FORMAT, workers=0)
    assert len(run_batch(data["cal"], [frames], options).done) == INTERRUPTED_FRAMES
    return {"cal": data["cal"], "frames": frames, "reference": root / "reference"}


def finished_outputs(folder: Path) -> list[str]:
    try:
        return sorted(entry.name for entry in os.scandir(folder) if not entry.name.startswith("."))
    except FileNotFoundError:
        return []


def interrupt(
    args: tuple[str, ...], out: Path, signum: int, *, group: bool, after: int = 2
) -> tuple[int, str, list[str], str]:
    """Run ``picamcal ARGS`` in a session of its own (so that a signal to its group reaches no other process),
    send ``signum`` to it (or to its whole group) once ``after`` outputs are in ``out``; its exit status, stderr,
    the outputs finished when the signal was sent, and its tag."""
    tag = uuid.uuid4().hex
    process = subprocess.Popen(
        command(*args),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, TAG: tag},
        preexec_fn=as_from_a_terminal,
    )
    while process.poll() is None and len(finished_outputs(out)) < after:
        time.sleep(0.005)
    seen = finished_outputs(out)
    assert process.poll() is None, "the batch finished before the signal"
    (os.killpg if group else os.kill)(process.pid, signum)
    _, stderr = process.communicate(timeout=300)
    return process.returncode, stderr, seen, tag


def assert_stopped_cleanly(
    out: Path, reference: Path, stderr: str, seen: list[str], signum: int, workers: int, total: int
) -> list[str]:
    """The one line, and no file started after the signal, none half-written, no temporary; the outputs."""
    finished = finished_outputs(out)
    name = signal.Signals(signum).name
    assert stderr.splitlines()[-1:] == [
        f"picamcal: interrupted by {name}: wrote {len(finished)} of {total} image(s) to {out}; run the same command "
        "again to resume"
    ], stderr
    assert "Traceback" not in stderr
    # No new file started: besides those finished when the signal came, at most those each worker's pipeline held
    # (being read, read ahead, in its output slots: picamcal.batch.pipeline), which may be finished in the grace.
    in_flight = 1 + READ_AHEAD + OUTPUT_SLOTS
    assert set(seen) <= set(finished) and len(finished) <= len(seen) + in_flight * max(workers, 1) < total
    assert temporaries(out.parent) == []
    for name in finished:  # complete, never half-written
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name
    return finished


@pytest.mark.slow
@pytest.mark.parametrize(
    ("signum", "group", "workers"),
    [
        pytest.param(signal.SIGINT, True, 2, id="ctrl-c-pool"),
        pytest.param(signal.SIGTERM, False, 2, id="kill-pool"),
        pytest.param(signal.SIGTERM, True, 2, id="timeout-or-systemd-pool"),
        pytest.param(signal.SIGINT, True, 0, id="ctrl-c-in-process"),
        pytest.param(signal.SIGTERM, False, 0, id="kill-in-process"),
    ],
)
def test_an_interrupted_batch_stops_says_so_and_resumes(pngs, tmp_path, signum, group, workers):
    out = tmp_path / "out"
    args = ("correct", str(pngs["cal"]), str(pngs["frames"]), "--out", str(out), "--workers", str(workers))
    args += ("--output-format", INTERRUPTED_FORMAT)
    code, stderr, seen, tag = interrupt(args, out, signum, group=group)
    assert code == 128 + signum, stderr
    assert_nothing_left_running(tag)
    finished = assert_stopped_cleanly(out, pngs["reference"], stderr, seen, signum, workers, INTERRUPTED_FRAMES)

    again = subprocess.run(command(*args), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"wrote {INTERRUPTED_FRAMES - len(finished)} image(s)" in again.stderr
    assert f"skipped {len(finished)} (done already)" in again.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == {
        p.name: p.read_bytes() for p in pngs["reference"].iterdir()
    }


@pytest.mark.slow
def test_an_interrupted_zarr_batch_records_its_frames_and_leaves_no_chunk_temporary(pngs, tmp_path):
    zarr = pytest.importorskip("zarr")
    stack = tmp_path / "frames.zarr"
    args = ("correct", str(pngs["cal"]), str(pngs["frames"]), "--zarr", str(stack), "--workers", "2")
    tag = uuid.uuid4().hex
    process = subprocess.Popen(
        command(*args),
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, TAG: tag},
        preexec_fn=as_from_a_terminal,
    )
    chunks = names(stack / "0" / "c", "*")
    while process.poll() is None and len(chunks()) < 2:  # frames are being written: their chunk folders appear
        time.sleep(0.005)
    assert process.poll() is None, "the batch finished before the signal"
    os.killpg(process.pid, signal.SIGINT)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 130, stderr
    assert_nothing_left_running(tag)
    done = zarr.open_group(stack, mode="r").attrs["picamcal"]["done"]
    assert stderr.splitlines()[-1] == (
        f"picamcal: interrupted by SIGINT: wrote {len(done)} of {INTERRUPTED_FRAMES} image(s) to {stack}; run the "
        "same command again to resume"
    )
    assert 0 < len(done) < INTERRUPTED_FRAMES
    assert temporaries(tmp_path) == []  # neither the stack's mark nor a chunk's temporary
    again = subprocess.run(command(*args), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"skipped {len(done)} (done already)" in again.stderr
    assert zarr.open_group(stack, mode="r").attrs["picamcal"]["done"] == list(range(INTERRUPTED_FRAMES))


#: A dask cluster of two worker processes in the command's own process, running ``picamcal correct`` on it. Each
#: worker's reads are slowed by a second, longer than the batch takes to stop its tasks after the signal, so that the
#: files finished after it are those the bound below counts on any machine. (Unslowed, a file took 0.13 s on a fast
#: host: one run in five finished more than the bound.)
DASK_RUN = """
import sys, time
from distributed import Client, LocalCluster
from picamcal.cli import main

def slow_reads(seconds):
    from picamcal.batch import worker

    read = worker._Stages.read

    def slow(self, job):
        time.sleep(seconds)
        return read(self, job)

    worker._Stages.read = slow

if __name__ == "__main__":
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            client.run(slow_reads, 1.0)
        main([*sys.argv[1:], "--scheduler", cluster.scheduler_address])
"""


@pytest.mark.slow
def test_an_interrupted_batch_on_a_dask_cluster_stops_its_tasks(pngs, tmp_path):
    pytest.importorskip("distributed")
    script = tmp_path / "dask_run.py"
    script.write_text(DASK_RUN)
    out = tmp_path / "out"
    args = ("correct", str(pngs["cal"]), str(pngs["frames"]), "--out", str(out), "--output-format", INTERRUPTED_FORMAT)
    tag = uuid.uuid4().hex
    process = subprocess.Popen(
        [sys.executable, str(script), *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, TAG: tag},
        preexec_fn=as_from_a_terminal,
    )
    while process.poll() is None and len(finished_outputs(out)) < 2:
        time.sleep(0.005)
    seen = finished_outputs(out)
    assert process.poll() is None, "the batch finished before the signal"
    os.kill(process.pid, signal.SIGINT)  # the command alone: the cluster's workers see the batch's own stop
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 130, stderr
    assert_nothing_left_running(tag)
    finished = finished_outputs(out)
    lines = [line for line in stderr.splitlines() if line.startswith("picamcal: ")]
    assert lines == [
        f"picamcal: interrupted by SIGINT: wrote {len(finished)} of {INTERRUPTED_FRAMES} image(s) to {out}; run the "
        "same command again to resume"
    ], stderr
    # No new file once the tasks see the stop: besides the files finished when the signal came, at most those each
    # of the two workers' pipelines held (being read, read ahead, in its output slots), as for a pool; a worker
    # asks the scheduler every 0.2 s, and the command sets the stop a moment after the signal, longer on a busy
    # machine (on a slow host one run finished 7 files of 16 with 2 finished at the signal; DASK_RUN slows the reads so
    # that few files start meanwhile). The command waits for the writes under way on the cluster, however busy the
    # machine: the count it says is what is on disk.
    in_flight = 1 + READ_AHEAD + OUTPUT_SLOTS
    assert set(seen) <= set(finished) and len(finished) <= len(seen) + in_flight * 2 < INTERRUPTED_FRAMES
    assert temporaries(out) == []
    for name in finished:
        assert (out / name).read_bytes() == (pngs["reference"] / name).read_bytes(), name


#: Seconds every output's write lasts on the slowed cluster below: well past the batch's grace (stopping.GRACE_S), so
#: that the signal surely lands while writes are under way that end after the grace.
SLOW_WRITE_S = 3.0


@pytest.fixture
def cluster():
    """A dask cluster of two worker processes, this test process's, which outlives the commands run on it as a shared
    cluster does, and a client of it. This module's functions go to its workers by value (they cannot import it)."""
    distributed = pytest.importorskip("distributed")
    cloudpickle = pytest.importorskip("cloudpickle")
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    try:
        with (
            distributed.LocalCluster(
                n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None
            ) as cluster,
            distributed.Client(cluster) as client,
        ):
            yield cluster, client
    finally:
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def slow_writes(folder: str, seconds: float) -> None:
    """In a dask worker (``client.run``): every output's write first says so in ``folder`` (a file of the output's
    name), then begins ``seconds`` later (:func:`usual_writes` undoes it)."""
    from picamcal.batch import worker

    write = worker._write

    def slow(settings, job, *args, **kwargs):
        Path(folder, Path(job.target).name).touch()
        time.sleep(seconds)
        return write(settings, job, *args, **kwargs)

    slow.__wrapped__ = write
    worker._write = slow


def usual_writes() -> None:
    from picamcal.batch import worker

    worker._write = worker._write.__wrapped__


def pipeline_threads() -> list[str]:
    """In a dask worker (``client.run``): the threads of picamcal's pipelines still at work (a write among them)."""
    import threading

    return [thread.name for thread in threading.enumerate() if thread.name in ("picamcal-read", "picamcal-write")]


@pytest.mark.slow
def test_a_write_on_a_cluster_that_outlasts_the_grace_is_counted_and_the_count_is_what_is_on_disk(
    pngs, tmp_path, cluster
):
    """A dask worker outlives the batch (a shared cluster): a write under way there when the batch is interrupted
    ends after the batch's grace, and the batch's count must include it, whatever the load. The slowed writes
    (picamcal.batch.worker._write, replaced in each worker) make the race certain rather than a matter of timing.
    Once no pipeline runs on the workers any more (nothing can land after), the count must be the outputs on disk."""
    cluster, client = cluster
    out = tmp_path / "out"
    writing = tmp_path / "writing"  # where the slowed writes name the outputs they write
    writing.mkdir()
    client.run(slow_writes, str(writing), SLOW_WRITE_S)
    args = ("correct", str(pngs["cal"]), str(pngs["frames"]), "--out", str(out))
    args += ("--output-format", INTERRUPTED_FORMAT, "--scheduler", cluster.scheduler_address)
    tag = uuid.uuid4().hex
    process = subprocess.Popen(
        command(*args),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, TAG: tag},
        preexec_fn=as_from_a_terminal,
    )
    # The signal lands once an output is finished and another's write is under way (begun, not in place).
    under_way: set[str] = set()
    while process.poll() is None and not (
        (seen := finished_outputs(out)) and (under_way := set(os.listdir(writing)) - set(seen))
    ):
        time.sleep(0.005)
    assert process.poll() is None, "the batch finished before the signal"
    os.kill(process.pid, signal.SIGINT)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 130, stderr
    assert_nothing_left_running(tag)
    deadline = time.monotonic() + GONE_WITHIN_S  # a write the batch did not wait for would still land: wait
    while any(client.run(pipeline_threads).values()) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(client.run(pipeline_threads).values()), "the workers' pipelines outlived the batch"
    finished = assert_stopped_cleanly(out, pngs["reference"], stderr, seen, signal.SIGINT, 2, INTERRUPTED_FRAMES)
    assert under_way <= set(finished)  # the writes under way at the signal ended, and were counted
    assert "warning" not in stderr, stderr

    client.run(usual_writes)
    again = subprocess.run(command(*args), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"wrote {INTERRUPTED_FRAMES - len(finished)} image(s)" in again.stderr
    assert f"skipped {len(finished)} (done already)" in again.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == {
        p.name: p.read_bytes() for p in pngs["reference"].iterdir()
    }
