"""Batches: inputs, process pool and dask cluster, resuming, bad files, unwritable outputs, zarr stacks."""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import tifffile

from conftest import simulated_calibration
from picamcal import OutputError, PicamcalError, PicamcalWarning
from picamcal.batch import BatchOptionError, BatchOptions, expand_inputs, run_batch
from picamcal.cli import main
from picamcal.modes import Mode
from picamcal.raw import write_dng
from picamcal.simulate import make_camera, simulate_target

SIZE = (320, 240)


def cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from picamcal.cli import main; main()", *args]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(cli(*args), capture_output=True, text=True, timeout=300)


def outputs(folder: Path) -> list[Path]:
    """The TIFF files in a folder, not temporaries (hidden: ``.<stem>.picamcal-<host>-<pid>-<random>.tmp.tiff``)."""
    return [p for p in folder.glob("*.tiff") if not p.name.startswith(".")]


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def write_frames(folder: Path, count: int, first_seed: int = 0) -> list[Path]:
    """Simulated target frames, each with its own noise."""
    folder.mkdir(parents=True)
    camera = make_camera("imx219", size=SIZE)
    paths = []
    for i in range(count):
        raw, _ = simulate_target(camera, seed=first_seed + i)
        paths.append(folder / f"f{i:02d}.dng")
        write_dng(paths[-1], raw)
    return paths


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict[str, Path]:
    """A calibration, ten frames, and their outputs from a plain serial run (the reference for every other run)."""
    root = tmp_path_factory.mktemp("batch")
    simulated_calibration(root, SIZE, seed=3)
    write_frames(root / "frames", 10)
    result = run_batch(root / "cal.npz", [root / "frames"], BatchOptions(out_dir=root / "reference", workers=0))
    assert len(result.done) == 10 and not result.failed
    return {"cal": root / "cal.npz", "frames": root / "frames", "reference": root / "reference"}


# ---------------------------------------------------------------------------------------------- inputs
def test_expand_inputs_takes_files_folders_and_patterns_in_order_without_duplicates(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name in ("run/b.dng", "run/a.DNG", "run/notes.txt", "run/.hidden.dng", "run/sub/d.dng", "x.jpg"):
        Path(name).parent.mkdir(parents=True, exist_ok=True)
        Path(name).write_bytes(b"")
    from picamcal.raw import RawImage, write_npz

    write_npz("run/c.npz", RawImage(np.zeros((2, 2), np.uint16), "RGGB", (0,) * 4, 1023, 10))
    assert expand_inputs(["run"]) == [Path("run/a.DNG"), Path("run/b.dng"), Path("run/c.npz")]
    assert expand_inputs(["x.jpg", "run/*.dng", "run", "./run/b.dng"]) == [
        Path("x.jpg"),
        Path("run/b.dng"),  # the pattern is case-sensitive, as the shell's
        Path("run/a.DNG"),
        Path("run/c.npz"),
    ]
    assert expand_inputs(["run/**/*.dng"]) == [Path("run/b.dng"), Path("run/sub/d.dng")]
    assert expand_inputs(["run/su?"]) == [Path("run/sub/d.dng")]  # a pattern matching a folder gives its files
    assert expand_inputs(["run/notes.txt"]) == [Path("run/notes.txt")]  # a file named is taken as it is
    assert expand_inputs(["x.jpg"], suffixes=(".png",)) == [Path("x.jpg")]
    assert expand_inputs(["x.jpg", "nope.dng"]) == [Path("x.jpg"), Path("nope.dng")]  # fails alone when read
    with pytest.raises(PicamcalError, match=r"^run/\*\.tiff: no files match this pattern$"):
        expand_inputs(["run/*.tiff"])
    with pytest.raises(PicamcalError, match=r"^run/sub: no \.png files in this folder$"):
        expand_inputs(["run/sub"], suffixes=(".png",))


# ---------------------------------------------------------------------------------------------- options
#: Options that do not go together: (BatchOptions keywords, the field at fault, the library's message).
OPTION_MISTAKES = [
    ({"out_dir": "o", "white": "w.png"}, None, "white and input_encoding go with processed"),
    ({"out_dir": "o", "input_encoding": "srgb"}, None, "white and input_encoding go with processed"),
    (
        {"out_dir": "o", "tuning": "t.json"},
        "tuning",
        "tuning: without processed it gives the colour matrix of output_format srgb-png, srgb-png16, srgb-jpeg",
    ),
    ({"out_dir": "o", "processed": True, "binned": True}, None, "binned is for raw images"),
    ({}, None, "give out_dir FOLDER for image files, or zarr_path STACK.zarr for one stack"),
    (
        {"out_dir": "o", "zarr_path": "z.zarr"},
        None,
        "give out_dir FOLDER for image files, or zarr_path STACK.zarr for one stack",
    ),
    (
        {"out_dir": "o", "workers": 2, "scheduler": "tcp://h:1"},
        "workers",
        "workers: not with scheduler (the cluster has its own)",
    ),
    (
        {"out_dir": "o", "mosaic": (2, 2)},
        "mosaic",
        "mosaic: a mosaic is a tiling of one zarr_path stack: give zarr_path STACK.zarr",
    ),
    ({"zarr_path": "z.zarr", "mosaic": (0, 2)}, "mosaic", "mosaic: give at least one column and one row"),
    ({"out_dir": "o", "workers": -1}, "workers", "workers: must be 0 or more"),
    (
        {"out_dir": "o", "scheduler_timeout": 0},
        "scheduler_timeout",
        "scheduler_timeout: must be a positive number of seconds",
    ),
]


@pytest.mark.parametrize(("keywords", "option", "message"), OPTION_MISTAKES)
def test_options_that_do_not_go_together_are_refused_when_made(keywords, option, message, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(BatchOptionError) as caught:
        BatchOptions(**keywords)
    assert str(caught.value) == message and caught.value.option == option
    assert isinstance(caught.value, ValueError)  # what run_batch raised for these before it took one options value
    assert list(tmp_path.iterdir()) == []  # nothing is made, read or written


def test_options_are_normalised_once_and_unknown_names_refused():
    options = BatchOptions(zarr_path="stack.zarr", mode="flat", black_level=64, mosaic=[3, 2])
    assert options.mode is Mode.FLAT and options.place == Path("stack.zarr") and options.black_level == (64.0,)
    assert options.mosaic == (3, 2) and options.read_options["black_level"] == (64.0,)
    assert BatchOptions(out_dir="o", processed=True, tuning="t.json").encoding == "tuning:t.json"
    assert BatchOptions(out_dir="o", processed=True).input_suffixes == (".jpg", ".jpeg", ".png", ".tif", ".tiff")
    with pytest.warns(PicamcalWarning, match="'balance' is now called 'uncorrected'"):
        assert BatchOptions(out_dir="o", mode="balance").mode is Mode.UNCORRECTED
    with pytest.raises(ValueError, match="unknown mode 'sharp'"):
        BatchOptions(out_dir="o", mode="sharp")
    with pytest.raises(TypeError, match=r"run_batch takes BatchOptions\(out_dir=..., ...\), not a str"):
        run_batch("cal.npz", ["target.dng"], "out")  # the call before the options were one value
    for keywords, message in (
        ({"compression": "lz4"}, "unknown compression 'lz4' (expected one of zstd)"),
        ({"output_format": "srgb-pgn"}, "unknown output format 'srgb-pgn'"),
        ({"pattern": "XGGB"}, "unknown Bayer pattern 'XGGB'"),
        ({"output_format": "srgb-png", "compression": "zstd"}, "compression zstd is for the TIFF formats"),
    ):
        with pytest.raises(PicamcalError, match=f"^{re.escape(message)}"):
            BatchOptions(out_dir="o", **keywords)


#: The same mistakes on the command line: one usage line each, the options under their command-line names, as
#: ``picamcal correct`` said them before the checks moved into BatchOptions.
CLI_MISTAKES = {
    "white": (["--out", "o", "--white", "w.png"], "Invalid value: --white and --input-encoding go with --processed"),
    "tuning": (
        ["--out", "o", "--tuning", "t.json"],
        "Invalid value for --tuning: without --processed it gives the colour matrix of --output-format srgb-png, "
        "srgb-png16, srgb-jpeg",
    ),
    "binned": (["--out", "o", "--processed", "--binned"], "Invalid value: --binned is for raw images"),
    "no place": ([], "Invalid value: give --out FOLDER for image files, or --zarr STACK.zarr for one stack"),
    "two places": (
        ["--out", "o", "--zarr", "z.zarr"],
        "Invalid value: give --out FOLDER for image files, or --zarr STACK.zarr for one stack",
    ),
    "workers": (
        ["--out", "o", "--workers", "2", "--scheduler", "tcp://h:1"],
        "Invalid value for --workers: not with --scheduler (the cluster has its own)",
    ),
    "mosaic": (
        ["--out", "o", "--mosaic", "2x2"],
        "Invalid value for --mosaic: a mosaic is a tiling of one --zarr stack: give --zarr STACK.zarr",
    ),
    "mosaic 0x2": (
        ["--zarr", "z.zarr", "--mosaic", "0x2"],
        "Invalid value for --mosaic: give at least one column and one row",
    ),
}


@pytest.mark.parametrize(("args", "line"), list(CLI_MISTAKES.values()), ids=list(CLI_MISTAKES))
def test_the_command_line_names_its_own_options_in_the_same_mistakes(args, line, tmp_path, monkeypatch, capfd):
    """In this process (quick: every one is refused before any work); main's global settings are put back."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)
    monkeypatch.setattr(logging.getLogger("tifffile"), "level", logging.getLogger("tifffile").level)
    with pytest.raises(SystemExit) as exit:
        main(["correct", "cal.npz", "target.dng", *args])
    assert exit.value.code == 2
    assert capfd.readouterr().err.splitlines() == [f"picamcal: error: {line} (see picamcal correct --help)"]
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------- pool and dask
@pytest.mark.slow
def test_process_pool_and_dask_cluster_write_the_same_bytes_as_a_serial_run(data, tmp_path):
    distributed = pytest.importorskip("distributed")
    pool = run_batch(data["cal"], [data["frames"]], BatchOptions(out_dir=tmp_path / "pool", workers=2))
    assert len(pool.done) == 10 and pool.skipped == [] and pool.failed == []
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cluster:
        seen = []
        dask = run_batch(
            data["cal"],
            [data["frames"]],
            BatchOptions(out_dir=tmp_path / "dask", scheduler=cluster.scheduler_address),
            progress=lambda finished, total: seen.append((finished, total)),
        )
    assert dask.done == pool.done == sorted(data["frames"].iterdir())
    assert seen == [(i, 10) for i in range(11)]
    reference = snapshot(data["reference"])
    assert snapshot(tmp_path / "pool") == reference  # byte for byte: the metadata holds no time stamps
    assert snapshot(tmp_path / "dask") == reference
    record = json.loads(tifffile.TiffFile(tmp_path / "dask" / "f00.tiff").pages[0].description)["picamcal"]
    made_with = record.pop("made_with")  # the settings that made it (tests/test_batch_settings.py)
    assert record == {"source": "f00.dng", "calibration": "cal.npz", "mode": "centre", "binned": False}
    assert made_with["mode"] == "centre" and made_with["used"]["black_level"] == [64.0] * 4


# ---------------------------------------------------------------------------------------------- resuming
@pytest.mark.slow
def test_a_killed_batch_resumes_where_it_stopped(data, tmp_path):
    frames = write_frames(tmp_path / "frames", 24, first_seed=100)
    reference = tmp_path / "reference"
    run_batch(data["cal"], frames, BatchOptions(out_dir=reference, workers=0))
    out = tmp_path / "out"
    # The whole process group (the command, the fork server, the worker) dies at once, as in a power cut.
    process = subprocess.Popen(
        cli("correct", str(data["cal"]), str(tmp_path / "frames"), "--out", str(out), "--workers", "1"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None and len(outputs(out)) < 3:
        time.sleep(0.005)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    time.sleep(0.2)  # let the kernel finish off the other processes of the group
    finished = {p.name: p.stat().st_mtime_ns for p in outputs(out)}
    assert 3 <= len(finished) < 24, "the batch was not stopped half-way"
    for name in finished:  # an output is complete or absent, never half-written
        assert (out / name).read_bytes() == (reference / name).read_bytes()

    result = run("correct", str(data["cal"]), str(tmp_path / "frames"), "--out", str(out), "--workers", "1")
    assert result.returncode == 0, result.stderr
    assert f"wrote {24 - len(finished)} image(s)" in result.stderr
    assert f"skipped {len(finished)} (done already)" in result.stderr
    assert {name: (out / name).stat().st_mtime_ns for name in finished} == finished  # not written again
    assert snapshot(out) == snapshot(reference)  # and no temporary file is left


def test_a_finished_batch_has_nothing_to_do(data, tmp_path):
    out = tmp_path / "out"
    run_batch(
        data["cal"], [data["frames"] / "f00.dng", data["frames"] / "f01.dng"], BatchOptions(out_dir=out, workers=0)
    )
    finished = run_batch(
        data["cal"], [data["frames"] / "f00.dng", data["frames"] / "f01.dng"], BatchOptions(out_dir=out, workers=0)
    )
    assert finished.done == [] and len(finished.skipped) == 2 and finished.failed == []
    again = run_batch(data["cal"], [data["frames"] / "f00.dng"], BatchOptions(out_dir=out, workers=0, overwrite=True))
    assert again.done == [data["frames"] / "f00.dng"]


# ---------------------------------------------------------------------------------------------- bad input
@pytest.mark.slow
def test_a_corrupt_file_is_reported_and_the_others_finish(data, tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    for path in sorted(data["frames"].iterdir()):
        (frames / path.name).write_bytes(path.read_bytes())
    (frames / "f05.dng").write_bytes((frames / "f05.dng").read_bytes()[:2000])  # truncated mid-file
    out = tmp_path / "out"
    result = run("correct", str(data["cal"]), str(frames), "--out", str(out), "--workers", "2")
    assert result.returncode == 1, result.stderr
    assert "wrote 9 image(s)" in result.stderr and "failed 1" in result.stderr
    failures = [line for line in result.stderr.splitlines() if line.startswith("picamcal: failed: ")]
    assert len(failures) == 1 and f"{frames / 'f05.dng'}: " in failures[0], result.stderr
    assert re.search(r"truncated file|LibRaw cannot read it", failures[0])  # the reason (the header or LibRaw's)
    reference = snapshot(data["reference"])
    del reference["f05.tiff"]
    assert snapshot(out) == reference


@pytest.mark.slow
def test_an_unreachable_scheduler_is_one_line_before_any_work(data, tmp_path):
    pytest.importorskip("distributed")
    out = tmp_path / "out"
    result = run(
        "correct", str(data["cal"]), str(data["frames"]), "--out", str(out), "--scheduler", "tcp://127.0.0.1:1"
    )
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines == ["picamcal: error: tcp://127.0.0.1:1: cannot reach the dask scheduler (Connection refused)"]
    assert not out.exists()


def test_an_output_folder_that_cannot_be_made_is_one_line_before_any_work(data, tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    result = run("correct", str(data["cal"]), str(data["frames"]), "--out", str(blocker / "out"))
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines == [f"picamcal: error: {blocker / 'out'}: cannot create the output folder: Not a directory"]
    assert blocker.read_text() == ""


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes into a read-only (0o555) folder")
def test_a_read_only_output_folder_is_refused_before_any_work(data, tmp_path):
    out = tmp_path / "out"
    out.mkdir(mode=0o555)
    with pytest.raises(OutputError, match="cannot write here: Permission denied"):
        run_batch(data["cal"], [data["frames"]], BatchOptions(out_dir=out, workers=0))
    assert list(out.iterdir()) == []


def test_a_read_only_or_full_disk_leaves_no_file_behind(data, tmp_path, monkeypatch):
    """Simulated in this process (workers=0): a real full or read-only disk needs privileges to set up."""
    out = tmp_path / "out"

    real_open = os.open

    def read_only(path, flags, *args):  # picamcal's temporaries cannot be made; reading goes on
        if ".picamcal-" in os.fspath(path) and flags & os.O_CREAT:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS))
        return real_open(path, flags, *args)

    with monkeypatch.context() as m:
        m.setattr("os.open", read_only)
        with pytest.raises(OutputError, match=f"^{re.escape(str(out))}: cannot write here: Read-only file system$"):
            run_batch(data["cal"], [data["frames"]], BatchOptions(out_dir=out, workers=0))

    def no_room(fd, offset, length):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with monkeypatch.context() as m:
        m.setattr("os.posix_fallocate", no_room, raising=False)
        with pytest.raises(OutputError, match=r"no room for one output \(0\.9 MB\): No space left on device"):
            run_batch(data["cal"], [data["frames"]], BatchOptions(out_dir=out, workers=0))
    assert not out.exists()  # refused before any work: the folder the batch made is removed again

    written = []

    def fills_up(path, *args, **kwargs):  # the disk fills during the third file, half-way through writing it
        if len(written) == 2:
            Path(path).write_bytes(b"II*\x00" + bytes(1000))
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        written.append(path)
        with tifffile.TiffWriter(path) as tiff:
            tiff.write(*args, **kwargs)

    monkeypatch.setattr("tifffile.imwrite", fills_up)
    with pytest.raises(OutputError, match=r"cannot write: No space left on device; stopped after 2 of 10 files"):
        run_batch(data["cal"], [data["frames"]], BatchOptions(out_dir=out, workers=0))
    assert sorted(p.name for p in out.iterdir()) == ["f00.tiff", "f01.tiff"]  # no half-written file, no temporary


# ---------------------------------------------------------------------------------------------- outputs
@pytest.mark.slow
def test_zstd_compression_is_lossless(data, tmp_path):
    pytest.importorskip("imagecodecs")
    out = tmp_path / "out"
    result = run("correct", str(data["cal"]), str(data["frames"]), "--out", str(out), "--compression", "zstd")
    assert result.returncode == 0, result.stderr
    for path in sorted(data["reference"].iterdir()):
        with tifffile.TiffFile(path) as plain, tifffile.TiffFile(out / path.name) as packed:
            assert packed.pages[0].compression == tifffile.COMPRESSION.ZSTD
            records = [json.loads(page.description)["picamcal"] for page in (packed.pages[0], plain.pages[0])]
            assert records[0]["made_with"].pop("compression") == "zstd"  # recorded: a setting of the output
            assert records[1]["made_with"].pop("compression") is None
            assert records[0] == records[1]
            np.testing.assert_array_equal(packed.asarray(), plain.asarray())
    assert sum(p.stat().st_size for p in out.iterdir()) < 0.8 * sum(
        p.stat().st_size for p in data["reference"].iterdir()
    )


@pytest.mark.slow
def test_zarr_stack_holds_the_frames_with_ome_metadata_and_resumes(data, tmp_path):
    zarr = pytest.importorskip("zarr")
    stack = tmp_path / "frames.zarr"
    frames = sorted(data["frames"].iterdir())
    result = run("correct", str(data["cal"]), str(data["frames"]), "--zarr", str(stack), "--compression", "zstd")
    assert result.returncode == 0, result.stderr
    group = zarr.open_group(stack, mode="r")
    ome = group.attrs["ome"]
    assert ome["version"] == "0.5"
    assert [a["name"] for a in ome["multiscales"][0]["axes"]] == ["t", "c", "y", "x"]
    assert ome["multiscales"][0]["datasets"][0]["path"] == "0"
    array = group["0"]
    assert array.shape == (10, 3, 240, 320) and array.chunks == (1, 1, 240, 320) and array.dtype == np.float32
    assert array.metadata.dimension_names == ("t", "c", "y", "x")
    assert [type(c).__name__ for c in array.compressors] == ["ZstdCodec"]
    for i, frame in enumerate(frames):
        np.testing.assert_array_equal(
            np.moveaxis(array[i], 0, -1), tifffile.imread(data["reference"] / f"{frame.stem}.tiff")
        )
    assert group.attrs["picamcal"]["done"] == list(range(10))

    # As if killed before frames 3 and 7 were written and recorded: the rerun writes just those.
    record = dict(group.attrs["picamcal"], done=[0, 1, 2, 4, 5, 6, 8, 9])
    writable = zarr.open_group(stack, mode="r+")
    writable.attrs["picamcal"] = record
    writable["0"][3] = np.nan
    writable["0"][7] = np.nan
    resumed = run_batch(data["cal"], [data["frames"]], BatchOptions(zarr_path=stack, workers=2))
    assert resumed.done == [frames[3], frames[7]] and len(resumed.skipped) == 8
    array = zarr.open_array(stack / "0", mode="r")
    for i in (3, 7):
        np.testing.assert_array_equal(
            np.moveaxis(array[i], 0, -1), tifffile.imread(data["reference"] / f"{frames[i].stem}.tiff")
        )

    finished = run_batch(data["cal"], [data["frames"]], BatchOptions(zarr_path=stack, workers=0))
    assert finished.done == [] and len(finished.skipped) == 10
    with pytest.raises(OutputError, match="holds a stack of other inputs or settings: other mode "):
        run_batch(data["cal"], [data["frames"]], BatchOptions(zarr_path=stack, workers=0, mode="flat"))


def test_a_folder_passes_over_npz_files_that_are_not_raw(tmp_path):
    from picamcal.batch import expand_inputs
    from picamcal.raw import RawImage, write_npz

    raw = RawImage(np.zeros((4, 4), np.uint16), "RGGB", (0,) * 4, 1023, 10)
    write_npz(tmp_path / "frame.npz", raw)
    np.savez(tmp_path / "truth.npz", site_mixing=np.zeros(3))
    assert expand_inputs([tmp_path]) == [tmp_path / "frame.npz"]


@pytest.mark.slow
def test_zarr_mosaic_places_each_frame_as_its_tile_and_resumes(data, tmp_path):
    zarr = pytest.importorskip("zarr")
    frames = sorted(data["frames"].iterdir())[:5]
    mosaic = tmp_path / "mosaic.zarr"
    result = run_batch(data["cal"], frames, BatchOptions(zarr_path=mosaic, mosaic=(3, 2), workers=2))
    assert len(result.done) == 5 and not result.failed
    array = zarr.open_array(mosaic / "0", mode="r")
    height, width = tifffile.imread(data["reference"] / "f00.tiff").shape[:2]
    assert array.shape == (1, 3, 2 * height, 3 * width) and array.chunks == (1, 1, height, width)
    for index, frame in enumerate(frames):
        row, column = divmod(index, 3)
        tile = array[0, :, row * height : (row + 1) * height, column * width : (column + 1) * width]
        np.testing.assert_array_equal(
            np.moveaxis(tile, 0, -1), tifffile.imread(data["reference"] / f"{frame.stem}.tiff")
        )
    assert np.isnan(array[0, :, height:, 2 * width :]).all()  # the sixth tile: no frame, fill value
    again = run_batch(data["cal"], frames, BatchOptions(zarr_path=mosaic, mosaic=(3, 2), workers=0))
    assert again.done == [] and len(again.skipped) == 5
    with pytest.raises(PicamcalError, match="5 frames do not fit a mosaic of 2 x 2 tiles"):
        run_batch(data["cal"], frames, BatchOptions(zarr_path=tmp_path / "small.zarr", mosaic=(2, 2), workers=0))
