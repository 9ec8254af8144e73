"""What ``correct`` says and decides for a new user: the default mode, outputs beside the inputs, folder entries it
passes over, near misses of its choices, and a single file that cannot be corrected.

All in this process (``picamcal.cli.main`` and ``run_batch`` with ``workers=0``), on 320 x 240 simulated frames.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import tifffile

from conftest import simulated_calibration
from picamcal import CalibrationFileError, OutputError, PicamcalWarning, calibrate, correct, load_calibration, read_raw
from picamcal.batch import BatchOptions, expand_inputs, run_batch
from picamcal.cli import main
from picamcal.modes import Mode
from picamcal.raw import write_dng
from picamcal.simulate import make_camera, simulate_target

SIZE = (320, 240)


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict[str, Path]:
    """A full calibration, a white-only one of the same white and dark frame, and three frames."""
    root = tmp_path_factory.mktemp("messages")
    refs, cal = simulated_calibration(root, SIZE, seed=4)
    calibrate(read_raw(refs["white"]), black=read_raw(refs["black"])).save(root / "flat.npz")
    frames = root / "frames"
    frames.mkdir()
    camera = make_camera("imx219", size=SIZE)
    for i in range(3):
        write_dng(frames / f"f{i}.dng", simulate_target(camera, seed=20 + i)[0])
    small = simulate_target(make_camera("imx219", size=(160, 120)), seed=1)[0]
    write_dng(root / "small.dng", small)
    return {"root": root, "cal": cal, "flat": root / "flat.npz", "frames": frames, "small": root / "small.dng"}


def cli(capfd, *args: str) -> tuple[int, list[str]]:
    """``picamcal ARGS`` in this process: its exit status and its stderr lines."""
    with pytest.raises(SystemExit) as exit:
        main(list(args))
    return exit.value.code, capfd.readouterr().err.splitlines()


def scans_with_frames(data: dict[str, Path], folder: Path) -> Path:
    shutil.copytree(data["frames"], folder)
    return folder


# ---------------------------------------------------------------------------------------------- the default mode
def test_without_a_mode_a_white_only_calibration_corrects_its_flat_field_and_says_so(data, tmp_path, capfd):
    frame = read_raw(data["frames"] / "f0.dng")
    flat = load_calibration(data["flat"])
    assert np.array_equal(correct(frame, flat), correct(frame, flat, "flat"))  # the library's default
    code, err = cli(
        capfd, "correct", str(data["flat"]), str(data["frames"]), "--out", str(tmp_path / "o"), "--workers", "0"
    )
    assert code == 0, err
    assert [re.sub(r" \([0-9.]+ files/s\)", "", line) for line in err] == [
        f"wrote 3 image(s) to {tmp_path / 'o'} in mode flat (the best this calibration does: it has no colour "
        "references, only a white); skipped 0 (done already); failed 0"
    ]
    expected = correct(frame, flat, "flat")
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "o" / "f0.tiff"), expected)  # same kernel, same bytes

    full = run_batch(data["cal"], [data["frames"]], BatchOptions(out_dir=tmp_path / "full", workers=0))
    assert full.mode is Mode.CENTRE and full.mode_reason == "the best this calibration does: it has colour unmixing"
    given = run_batch(data["cal"], [data["frames"]], BatchOptions(out_dir=tmp_path / "pure", mode="pure", workers=0))
    assert given.mode is Mode.PURE and given.mode_reason is None  # a mode given is not explained


def test_an_unmixing_mode_asked_of_a_white_only_calibration_names_mode_flat(data, tmp_path, capfd):
    with pytest.raises(CalibrationFileError, match=r"for mode centre: .*; or correct with --mode flat"):
        correct(read_raw(data["frames"] / "f0.dng"), load_calibration(data["flat"]), "centre")
    for mode in ("centre", "pure"):
        code, err = cli(
            capfd, "correct", str(data["flat"]), str(data["frames"]), "--out", str(tmp_path), "--mode", mode
        )
        assert code == 2 and len(err) == 1, err
        assert err[0].startswith(
            f"picamcal: error: {data['flat']}: a flat-field calibration (white only) has no colour"
        )
        assert f"mode {mode}:" in err[0] and err[0].endswith("; or correct with --mode flat (its flat field)")


# ---------------------------------------------------------------------------------------------- outputs beside inputs
def test_an_output_folder_inside_the_input_folder_is_written_and_never_read(data, tmp_path, capfd):
    scans = scans_with_frames(data, tmp_path / "scans")
    out = scans / "corrected"
    code, err = cli(capfd, "correct", str(data["cal"]), str(scans), "--out", str(out), "--workers", "0")
    assert code == 0 and err[-1].startswith("wrote 3 image(s)"), err
    assert sorted(p.name for p in out.iterdir()) == ["f0.tiff", "f1.tiff", "f2.tiff"]
    first = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    code, err = cli(capfd, "correct", str(data["cal"]), str(scans), "--out", str(out), "--workers", "0")
    assert code == 0 and "wrote 0 image(s)" in err[-1] and "skipped 3 (done already)" in err[-1], err
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == first  # not written again

    # Outputs with an input's suffix (linear-dng writes .dng), reached by a recursive pattern: still never inputs.
    dngs = scans / "dng"
    options = BatchOptions(out_dir=dngs, output_format="linear-dng", workers=0)
    pattern = str(scans / "**" / "*.dng")
    assert [p.name for p in run_batch(data["cal"], [pattern], options).done] == ["f0.dng", "f1.dng", "f2.dng"]
    again = run_batch(data["cal"], [pattern, str(scans / "*")], options)
    assert again.done == [] and [p.name for p in again.skipped] == ["f0.dng", "f1.dng", "f2.dng"]
    assert expand_inputs([scans], skip=out) == [scans / "f0.dng", scans / "f1.dng", scans / "f2.dng"]


def test_an_output_folder_inside_the_input_folder_must_be_new_or_picamcals_own(data, tmp_path):
    scans = scans_with_frames(data, tmp_path / "scans")
    theirs = scans / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("the user's own")
    with pytest.raises(
        OutputError, match=r"theirs: lies inside the input .*scans \(an output folder inside it must be new"
    ):
        run_batch(data["cal"], [scans], BatchOptions(out_dir=theirs, workers=0))
    assert [p.name for p in theirs.iterdir()] == ["notes.txt"]

    ours = scans / "ours"
    assert len(run_batch(data["cal"], [scans / "f0.dng"], BatchOptions(out_dir=ours, workers=0)).done) == 1
    (ours / ".DS_Store").write_bytes(b"a file browser's")  # hidden: never an input, never replaced
    assert len(run_batch(data["cal"], [scans], BatchOptions(out_dir=ours, workers=0)).done) == 2
    empty = scans / "empty"
    empty.mkdir()
    assert len(run_batch(data["cal"], [scans], BatchOptions(out_dir=empty, workers=0)).done) == 3
    with pytest.raises(OutputError, match="holds the input"):  # the output never holds an input
        run_batch(data["cal"], [scans / "ours" / "f0.tiff"], BatchOptions(out_dir=scans, workers=0))


# ---------------------------------------------------------------------------------------------- folder entries
def test_a_folders_entries_that_are_not_files_are_passed_over_with_one_warning(data, tmp_path, capfd):
    scans = scans_with_frames(data, tmp_path / "scans")
    (scans / "gone.dng").symlink_to(tmp_path / "deleted.dng")
    os.mkfifo(scans / "pipe.DNG")  # reading it would wait for ever
    (scans / "day2.dng").mkdir()
    (scans / "loop.dng").symlink_to(scans / "loop.dng")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert expand_inputs([scans]) == [scans / "f0.dng", scans / "f1.dng", scans / "f2.dng"]
    assert [(w.category, str(w.message)) for w in caught] == [
        (
            PicamcalWarning,
            f"{scans}: passed over 4 entries that are not regular files: day2.dng (a folder), gone.dng (a symbolic "
            "link to nothing), loop.dng (a symbolic link that loops), pipe.DNG (a FIFO)",
        )
    ]
    code, err = cli(capfd, "correct", str(data["cal"]), str(scans), "--out", str(tmp_path / "o"), "--workers", "0")
    assert code == 0 and err[0].startswith("wrote 3 image(s)"), err
    assert err[1:] == [f"picamcal: warning: {caught[0].message}"]


# ---------------------------------------------------------------------------------------------- near misses
@pytest.mark.parametrize(
    ("option", "value", "meant"),
    [
        ("--output-format", "png", "srgb-png"),
        ("--output-format", "jpg", "srgb-jpeg"),
        ("--output-format", "tif", "float32-tiff"),
        ("--output-format", "uint16", "uint16-tiff"),
        ("--output-format", "dng", "linear-dng"),
        ("--compression", "zst", "zstd"),
        ("--mode", "center", "centre"),
        ("--pattern", "RGBG", "RGGB"),
    ],
)
def test_a_near_miss_of_each_choice_gets_did_you_mean(data, tmp_path, capfd, option, value, meant):
    code, err = cli(
        capfd, "correct", str(data["cal"]), str(data["frames"]), "--out", str(tmp_path / "o"), option, value
    )
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"picamcal: error: Invalid value for {option}: {value!r} is not one of ")
    assert err[0].endswith(f"; did you mean {meant}? (see picamcal correct --help)")
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------------------------- failures
def test_a_single_file_that_cannot_be_corrected_is_one_error_line_and_leaves_no_folder(data, tmp_path, capfd):
    out = tmp_path / "new" / "corrected"
    code, err = cli(capfd, "correct", str(data["cal"]), str(data["small"]), "--out", str(out))
    assert code == 2
    assert err == [
        f"picamcal: error: {data['small']}: image does not match the calibration: size 160x120, calibration is for "
        "320x240: the image is of a 160x120 sensor, the calibration of a 320x240 one; give the image's sensor area "
        "(--sensor-crop X,Y,WIDTH,HEIGHT) or calibrate in the image's mode"
    ]
    assert not (tmp_path / "new").exists()  # neither the folder nor its parent, both made by the run
    missing = tmp_path / "missing.dng"
    code, err = cli(capfd, "correct", str(data["cal"]), str(missing), "--out", str(out))
    assert code == 2 and err == [f"picamcal: error: {missing}: no such file"]
    assert not (tmp_path / "new").exists()
    if importlib.util.find_spec("zarr") is not None:  # a stack the run made, with no frame in it, goes too
        code, err = cli(
            capfd, "correct", str(data["cal"]), str(data["small"]), "--zarr", str(tmp_path / "new" / "s.zarr")
        )
        assert code == 2 and len(err) == 1 and "image does not match the calibration" in err[0], err
        assert not (tmp_path / "new").exists()


def test_a_batch_keeps_exit_status_1_with_its_failures_before_its_summary(data, tmp_path, capfd):
    out = tmp_path / "corrected"
    good = data["frames"] / "f0.dng"
    code, err = cli(
        capfd, "correct", str(data["cal"]), str(data["small"]), str(good), "--out", str(out), "--workers", "0"
    )
    assert code == 1
    assert err[0] == (
        f"picamcal: failed: {data['small']}: image does not match the calibration: size 160x120, calibration is for "
        "320x240: the image is of a 160x120 sensor, the calibration of a 320x240 one; give the image's sensor area "
        "(--sensor-crop X,Y,WIDTH,HEIGHT) or calibrate in the image's mode"
    )
    assert err[1].startswith(f"wrote 1 image(s) to {out}") and err[1].endswith("failed 1") and len(err) == 2
    nothing = tmp_path / "nothing"
    code, err = cli(
        capfd, "correct", str(data["cal"]), str(data["small"]), str(tmp_path / "gone.dng"), "--out", str(nothing)
    )
    assert code == 1 and len(err) == 3 and not nothing.exists()  # every file failed: no empty folder left behind
