"""Batches that meet bad files, long names and the temporaries of killed runs.

A bad or mismatched file, the first of its folder included, fails alone: the good files are corrected and
each bad one is one line naming it (exit status 1). Temporary names fit in a file name whatever the output's
name. The temporaries a killed run left are removed by the next run; a live run's, another machine's and
every other file are kept.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile

from conftest import simulated_calibration
from picamcal import load_calibration
from picamcal._atomic import make_temporary, remove_stale_temporaries, temporary_name
from picamcal.batch import BatchOptions, run_batch
from picamcal.raw import write_dng
from picamcal.simulate import make_camera, simulate_target

SIZE = (320, 240)
#: The longest stem whose outputs (``.tiff``, ``.npz``) still fit a 255-byte file name with a margin.
LONG_STEM = "s" * 241


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", "from picamcal.cli import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def failure_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("picamcal: failed: ")]


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict[str, Path]:
    """A calibration, three good frames with their outputs from a serial run, a frame of another size and a
    truncated one."""
    root = tmp_path_factory.mktemp("resilience")
    simulated_calibration(root, SIZE, seed=3)
    good = root / "good"
    good.mkdir()
    camera = make_camera("imx219", size=SIZE)
    for i in range(3):
        write_dng(good / f"f{i}.dng", simulate_target(camera, seed=10 + i)[0])
    assert len(run_batch(root / "cal.npz", [good], BatchOptions(out_dir=root / "reference", workers=0)).done) == 3
    small, _ = simulate_target(make_camera("imx219", size=(160, 120)), seed=1)
    write_dng(root / "small.dng", small)
    (root / "truncated.dng").write_bytes((good / "f0.dng").read_bytes()[:3000])
    return {"root": root, "cal": root / "cal.npz", "good": good, "reference": root / "reference"}


def folder_with(data: dict[str, Path], folder: Path, bad: dict[str, Path]) -> Path:
    """The good frames, and ``bad`` files under the given names (``a...`` sorts first)."""
    shutil.copytree(data["good"], folder)
    for name, source in bad.items():
        shutil.copyfile(source, folder / name)
    return folder


@pytest.mark.slow
def test_a_first_file_of_another_size_does_not_stop_the_good_ones(data, tmp_path):
    frames = folder_with(data, tmp_path / "frames", {"a_small.dng": data["root"] / "small.dng"})
    out = tmp_path / "out"
    result = run("correct", str(data["cal"]), str(frames), "--out", str(out), "--workers", "2")
    assert result.returncode == 1, result.stderr
    assert "wrote 3 image(s)" in result.stderr and "failed 1" in result.stderr
    assert failure_lines(result.stderr) == [
        f"picamcal: failed: {frames / 'a_small.dng'}: image does not match the calibration: size 160x120, "
        "calibration is for 320x240: the image is of a 160x120 sensor, the calibration of a 320x240 one; give the "
        "image's sensor area (--sensor-crop X,Y,WIDTH,HEIGHT) or calibrate in the image's mode"
    ]
    assert {p.name: p.read_bytes() for p in out.iterdir()} == {
        p.name: p.read_bytes() for p in data["reference"].iterdir()
    }


@pytest.mark.slow
def test_a_first_file_that_is_corrupt_does_not_stop_the_good_ones(data, tmp_path):
    bad = {"a_truncated.dng": data["root"] / "truncated.dng", "f1b_small.dng": data["root"] / "small.dng"}
    frames = folder_with(data, tmp_path / "frames", bad)
    out = tmp_path / "out"
    result = run("correct", str(data["cal"]), str(frames), "--out", str(out), "--workers", "0")
    assert result.returncode == 1, result.stderr
    assert "wrote 3 image(s)" in result.stderr and "failed 2" in result.stderr
    lines = failure_lines(result.stderr)
    assert len(lines) == 2, result.stderr  # one line for each bad file, in the folder's order, naming it
    assert lines[0].startswith(f"picamcal: failed: {frames / 'a_truncated.dng'}: ")
    assert lines[1].startswith(f"picamcal: failed: {frames / 'f1b_small.dng'}: image does not match the calibration")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == {
        p.name: p.read_bytes() for p in data["reference"].iterdir()
    }


@pytest.mark.slow
def test_a_241_character_stem_is_written_and_its_temporary_name_fits(data, tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    shutil.copyfile(data["good"] / "f0.dng", frames / f"{LONG_STEM}.dng")
    out = tmp_path / "out"
    result = run("correct", str(data["cal"]), str(frames), "--out", str(out), "--workers", "0")
    assert result.returncode == 0, result.stderr
    assert [p.name for p in out.iterdir()] == [f"{LONG_STEM}.tiff"]
    np.testing.assert_array_equal(  # the same pixels as the frame's output under its short name
        tifffile.imread(out / f"{LONG_STEM}.tiff"), tifffile.imread(data["reference"] / "f0.tiff")
    )
    load_calibration(data["cal"]).save(tmp_path / f"{LONG_STEM}.npz")
    assert load_calibration(tmp_path / f"{LONG_STEM}.npz").width == SIZE[0]

    for name in (f"{LONG_STEM}.tiff", LONG_STEM, "é" * 125 + ".npz", "x" * 255):
        for suffix in (None, "", ".writing"):
            temporary = temporary_name(tmp_path / name, suffix)
            assert len(os.fsencode(temporary.name)) <= 255, temporary.name
            temporary.name.encode("utf-8")  # whole characters: a cut one would not encode
            assert temporary.name.startswith(f".{name[:20]}")  # recognisable: it starts with the output's name
    folder = make_temporary(tmp_path / LONG_STEM, folder=True)
    assert folder.is_dir()


CHILD_EXITS, CHILD_STAYS = "exits", "stays"


def temporary_of_a_process(target: Path, *, until: str, folder: bool = False, suffix: str | None = None):
    """A temporary made by a real other process (forked: quick), which ends at once or stays until killed."""
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: make the temporary, report its name, then end or wait
        try:
            path = make_temporary(target, folder=folder, suffix=suffix)
            if folder:
                (path / "index.html").write_text("half a report")
            os.write(write, os.fsencode(path) + b"\n")
            while until == CHILD_STAYS:  # until the test kills it
                time.sleep(60)
        finally:
            os._exit(0)
    os.close(write)
    name = b""
    while not name.endswith(b"\n"):
        name += os.read(read, 4096)
    os.close(read)
    return Path(os.fsdecode(name.strip())), pid


@pytest.mark.slow
def test_stale_temporaries_of_ended_processes_are_removed_and_nothing_else(data, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    dead, pid = temporary_of_a_process(out / "f0.tiff", until=CHILD_EXITS)
    os.waitpid(pid, 0)
    zombie, zombie_pid = temporary_of_a_process(out / "f1.tiff", until=CHILD_EXITS)
    os.waitid(os.P_PID, zombie_pid, os.WEXITED | os.WNOWAIT)  # ended, not yet reaped: a zombie
    dead_folder, pid = temporary_of_a_process(out / "report", until=CHILD_EXITS, folder=True)
    os.waitpid(pid, 0)
    live, live_pid = temporary_of_a_process(out / "f2.tiff", until=CHILD_STAYS)
    host = dead.name.split(".picamcal-")[1][:8]
    elsewhere = dead.with_name(
        dead.name.replace(f".picamcal-{host}-", f".picamcal-{'0' * 8 if host != '0' * 8 else 'f' * 8}-")
    )
    elsewhere.write_bytes(b"")  # a dead process id, but of another machine: it means nothing here
    others = [".f0.abcd1234.tmp.tiff", "notes.picamcal-tmp.txt", f"{dead.name[1:]}", ".picamcal-report"]
    for name in others:
        (out / name).write_text("not picamcal's temporary")
    try:
        result = run("correct", str(data["cal"]), str(data["good"] / "f0.dng"), "--out", str(out), "--workers", "0")
        assert result.returncode == 0, result.stderr
        assert sorted(p.name for p in out.iterdir()) == sorted([live.name, elsewhere.name, *others, "f0.tiff"])
    finally:
        os.kill(live_pid, 9)
        os.waitpid(live_pid, 0)
        os.waitpid(zombie_pid, 0)
    assert dead_folder.name.endswith(".tmp") and not dead_folder.exists()
    assert remove_stale_temporaries(out) == [live]  # its process has ended now
    assert zombie.name not in hidden(out)


def test_a_zarr_stack_keeps_the_chunk_temporaries_of_a_live_run(data, tmp_path):
    zarr = pytest.importorskip("zarr")
    stack = tmp_path / "frames.zarr"
    run_batch(data["cal"], [data["good"]], BatchOptions(zarr_path=stack, workers=0))

    def forget_the_last_frame_and_leave_a_partial() -> Path:
        group = zarr.open_group(stack, mode="r+")
        group.attrs["picamcal"] = dict(group.attrs["picamcal"], done=[0, 1])
        partial = stack / "0" / "c" / "2" / "0" / "0" / "0.0123456789abcdef.partial"
        partial.write_bytes(b"half a chunk")
        return partial

    partial = forget_the_last_frame_and_leave_a_partial()
    marker, live_pid = temporary_of_a_process(stack, until=CHILD_STAYS, suffix=".writing")
    try:
        resumed = run_batch(data["cal"], [data["good"]], BatchOptions(zarr_path=stack, workers=0))
        assert len(resumed.done) == 1 and partial.exists() and marker.exists()  # another run may be writing it
    finally:
        os.kill(live_pid, 9)
        os.waitpid(live_pid, 0)
    partial = forget_the_last_frame_and_leave_a_partial()
    resumed = run_batch(data["cal"], [data["good"]], BatchOptions(zarr_path=stack, workers=0))
    assert len(resumed.done) == 1 and not partial.exists() and not marker.exists()  # a killed run's
    assert hidden(tmp_path) == [] and list(stack.rglob("*.partial")) == []
