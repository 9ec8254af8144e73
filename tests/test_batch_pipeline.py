"""The overlapped pipeline of a batch worker: the same bytes as a serial correction, failures, bounded memory."""

from __future__ import annotations

import errno
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest
import tifffile

from conftest import simulated_calibration
from picamcal import PicamcalWarning
from picamcal.batch import BatchOptions, run_batch
from picamcal.batch.pipeline import OUTPUT_SLOTS, READ_AHEAD, SlotPool, overlapped
from picamcal.batch.record import batch_settings, made_with
from picamcal.calibration import load_calibration
from picamcal.correct import correct
from picamcal.output import OUTPUT_SUFFIXES, camera_to_srgb, write_corrected
from picamcal.raw import read_raw, write_dng
from picamcal.records import sha256_file
from picamcal.simulate import make_camera, simulate_target

SIZE = (320, 240)
FRAMES = 5


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict[str, Path]:
    """A calibration and FRAMES simulated target frames, each with its own noise."""
    root = tmp_path_factory.mktemp("pipeline")
    simulated_calibration(root, SIZE, seed=3)
    frames = root / "frames"
    frames.mkdir()
    camera = make_camera("imx219", size=SIZE)
    for i in range(FRAMES):
        write_dng(frames / f"f{i:02d}.dng", simulate_target(camera, seed=10 + i)[0])
    return {"cal": root / "cal.npz", "frames": frames}


def serial(cal_path: Path, frames: list[Path], out: Path, output_format: str, compression: str | None) -> None:
    """The plain library recipe, one file after the other: read, correct (float32), write, with the record of the
    settings a batch writes (picamcal.batch.record)."""
    cal = load_calibration(cal_path)
    out.mkdir()
    settings = batch_settings(
        calibration=cal_path,
        calibration_sha256=sha256_file(cal_path),
        mode="centre",
        binned=False,
        processed=False,
        output_format=output_format,
        compression=compression,
        read_options={},
        geometry={},
    )
    for frame in frames:
        raw = read_raw(frame)
        info = {"source": frame.name, "calibration": cal_path.name, "mode": "centre", "binned": False}
        info["made_with"] = made_with(settings, raw)
        write_corrected(
            out / f"{frame.stem}{OUTPUT_SUFFIXES[output_format]}",
            correct(raw, cal, "centre"),
            output_format,
            info,
            colour_matrix=camera_to_srgb(raw.metadata) if output_format.startswith("srgb") else None,
            compression=compression,
        )


FORMATS = [
    ("float32-tiff", None),
    ("float32-tiff", "zstd"),
    ("uint16-tiff", None),
    ("uint16-tiff", "zstd"),
    ("srgb-png", None),
    ("srgb-png16", None),
    ("srgb-jpeg", None),
]


@pytest.mark.parametrize(("output_format", "compression"), FORMATS, ids=[f"{f}-{c}" for f, c in FORMATS])
def test_the_overlapped_pipeline_writes_the_bytes_of_a_serial_correction(data, tmp_path, output_format, compression):
    if compression is not None:
        pytest.importorskip("imagecodecs")
    frames = sorted(data["frames"].iterdir())
    serial(data["cal"], frames, tmp_path / "serial", output_format, compression)
    options = BatchOptions(out_dir=tmp_path / "batch", output_format=output_format, compression=compression, workers=0)
    result = run_batch(data["cal"], frames, options)
    assert result.done == frames and result.failed == []
    expected = {p.name: p.read_bytes() for p in sorted((tmp_path / "serial").iterdir())}
    assert {p.name: p.read_bytes() for p in sorted((tmp_path / "batch").iterdir())} == expected  # byte for byte


def test_a_workers_next_task_corrects_into_the_output_arrays_of_its_last(data, tmp_path, monkeypatch):
    """Fresh memory is dear: the output slots outlive a task, so a worker's next one allocates no output array."""
    from picamcal.batch import worker

    outs: list[np.ndarray | None] = []
    real_correct = worker.correct

    def recording(*args, out=None, **kwargs):
        outs.append(out)
        return real_correct(*args, out=out, **kwargs)

    monkeypatch.setattr(worker, "correct", recording)
    frames = sorted(data["frames"].iterdir())
    for name in ("first", "second"):
        options = BatchOptions(out_dir=tmp_path / name, output_format="uint16-tiff", workers=0)
        assert run_batch(data["cal"], frames, options).done == frames
    second = outs[FRAMES:]
    assert all(out is not None for out in second) and len({id(out) for out in second}) == OUTPUT_SLOTS
    assert [p.read_bytes() for p in sorted((tmp_path / "second").iterdir())] == [
        p.read_bytes() for p in sorted((tmp_path / "first").iterdir())
    ]


def test_runs_at_once_in_one_process_take_slots_of_their_own():
    pool = SlotPool(keep=1)
    with pool.taken() as first, pool.taken() as second:
        assert len(first) == len(second) == OUTPUT_SLOTS
        assert not {id(slot) for slot in first} & {id(slot) for slot in second}
    with pool.taken() as again:
        assert again is first or again is second  # one set kept, the other let go


@pytest.mark.slow
def test_a_pool_of_pipelines_writes_the_same_bytes_and_a_zarr_stack_the_same_values(data, tmp_path):
    zarr = pytest.importorskip("zarr")
    frames = sorted(data["frames"].iterdir())
    serial(data["cal"], frames, tmp_path / "serial", "uint16-tiff", None)
    options = BatchOptions(out_dir=tmp_path / "pool", output_format="uint16-tiff", workers=2)
    assert run_batch(data["cal"], frames, options).done == frames
    expected = {p.name: p.read_bytes() for p in sorted((tmp_path / "serial").iterdir())}
    assert {p.name: p.read_bytes() for p in sorted((tmp_path / "pool").iterdir())} == expected

    assert run_batch(data["cal"], frames, BatchOptions(zarr_path=tmp_path / "s.zarr", workers=2)).done == frames
    stack = zarr.open_array(tmp_path / "s.zarr" / "0", mode="r")
    cal = load_calibration(data["cal"])
    for i, frame in enumerate(frames):  # exactly: the same kernel on the same frame
        np.testing.assert_array_equal(np.moveaxis(stack[i], 0, -1), correct(read_raw(frame), cal, "centre"))


def test_a_failing_read_and_a_failing_write_in_the_middle_are_reported_and_the_others_finish(
    data, tmp_path, monkeypatch
):
    frames = tmp_path / "frames"
    frames.mkdir()
    for path in sorted(data["frames"].iterdir()):
        (frames / path.name).write_bytes(path.read_bytes())
    (frames / "f01.dng").write_bytes((frames / "f01.dng").read_bytes()[:3000])  # truncated: its read fails
    real_imwrite = tifffile.imwrite

    def fails_for_f03(path, *args, **kwargs):  # an I/O error writing the fourth file, not a full disk
        if Path(path).name.startswith(".f03."):
            Path(path).write_bytes(b"II*\x00")
            raise OSError(errno.EIO, "Input/output error")
        return real_imwrite(path, *args, **kwargs)

    monkeypatch.setattr("tifffile.imwrite", fails_for_f03)
    out = tmp_path / "out"
    result = run_batch(data["cal"], [frames], BatchOptions(out_dir=out, workers=0))
    assert [p.name for p in result.done] == ["f00.dng", "f02.dng", "f04.dng"]
    assert [p.name for p, _ in result.failed] == ["f01.dng", "f03.dng"]
    assert "Input/output error" in result.failed[1][1]
    assert sorted(p.name for p in out.iterdir()) == ["f00.tiff", "f02.tiff", "f04.tiff"]  # no temporary left


def test_the_reader_runs_only_a_bounded_number_of_files_ahead_of_a_stalled_writer():
    """While the first file's write is held back, the reader may read the files the output slots and the
    read-ahead queue hold, and no more: with an unbounded queue it would read all twenty (then the write is
    released at once); bounded, the write waits its full second."""
    reads: list[int] = []
    unbounded = threading.Event()
    seen_while_stalled: list[int] = []

    def read(n: int) -> np.ndarray:
        reads.append(n)
        if len(reads) == 20:
            unbounded.set()
        return np.full(1000, n)

    def write(n: int, corrected: np.ndarray) -> None:
        if n == 0:
            unbounded.wait(timeout=1.0)
            seen_while_stalled.append(len(reads))

    finished = list(overlapped(list(range(20)), read, lambda x, slot: x * 2, write))
    assert sorted(f.job for f in finished) == list(range(20)) and all(f.error is None for f in finished)
    # file 0 in the writer, one corrected in each other slot, READ_AHEAD waiting, and one in the reader's hand
    assert seen_while_stalled == [OUTPUT_SLOTS + READ_AHEAD + 1]


def test_each_file_keeps_its_own_warnings_and_a_fatal_failure_stops_the_rest():
    def read(n: int) -> int:
        if n == 1:
            warnings.warn(f"file {n} looks odd", PicamcalWarning, stacklevel=1)
        return n

    def write(n: int, corrected: int) -> None:
        if n == 3:
            raise OSError(errno.ENOSPC, "No space left on device")

    finished = {f.job: f for f in overlapped(list(range(8)), read, lambda x, slot: x, write, fatal=lambda e: True)}
    assert [str(w.message) for w in finished[1].warnings] == ["file 1 looks odd"]
    assert all(not f.warnings for job, f in finished.items() if job != 1)
    assert isinstance(finished[3].error, OSError)
    assert sorted(finished) == [0, 1, 2, 3]  # nothing written after the disk filled up


@pytest.mark.parametrize("bits", [8, 16])
def test_the_srgb_code_table_gives_the_formulas_codes_exactly(bits):
    """encode_srgb looks the codes up (a table of cells and the thresholds inside them) instead of evaluating
    the sRGB curve per pixel: the same codes, at every threshold, one float64 step either side, and elsewhere."""
    from picamcal.output.colour import _code_table, encode_srgb, srgb_transfer

    top = 2**bits - 1
    base, inside = _code_table(bits)
    thresholds = inside[np.isfinite(inside)]
    assert len(thresholds) > 0.9 * top  # nearly every code's threshold falls inside a cell, not on its edge
    linear = np.concatenate(
        [
            np.random.default_rng(bits).random(200_000),
            thresholds,
            np.nextafter(thresholds, 0.0),
            np.nextafter(thresholds, 1.0),
            np.arange(len(base)) / (len(base) - 1),  # the cells' edges
        ]
    )
    expected = np.rint(top * srgb_transfer(linear))
    rgb = np.repeat(linear[:, None, None], 3, axis=2)  # white level 1: the identity leaves each value as it is
    assert np.array_equal(encode_srgb(rgb, white_level=1.0, bits=bits)[:, 0, 0], expected)
