"""A batch that never lies: every output records the settings that made it; a re-run keeps (and names) outputs made
with other settings, or replaces them with ``--overwrite``; batches writing into one folder at once share the work
through claims (:mod:`picamcal.batch.claims`), and a killed run's claims do not block a later one.

On 320 x 240 simulated IMX219 frames (black level 64 in their files). The concurrent batches are real processes,
started together on the same folder; nothing here depends on how fast the machine is.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile
from PIL import Image

from conftest import simulated_calibration
from picamcal import OutputError
from picamcal.batch import BatchOptions, claims, run_batch
from picamcal.cli import main
from picamcal.export.tuning import stock_tuning_path
from picamcal.output import OUTPUT_SUFFIXES, write_corrected
from picamcal.output.provenance import read_record
from picamcal.raw import read_raw, write_dng
from picamcal.simulate import make_camera, simulate_target

SIZE = (320, 240)
FRAMES = 4


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict[str, Path]:
    """A calibration and FRAMES simulated frames."""
    root = tmp_path_factory.mktemp("settings")
    _, cal = simulated_calibration(root, SIZE, seed=5)
    frames = root / "frames"
    frames.mkdir()
    camera = make_camera("imx219", size=SIZE)
    for i in range(FRAMES):
        write_dng(frames / f"f{i}.dng", simulate_target(camera, seed=30 + i)[0])
    return {"cal": cal, "frames": frames}


def cli(capfd, *args: object) -> tuple[int, list[str]]:
    """``picamcal ARGS`` in this process: its exit status and its stderr lines."""
    with pytest.raises(SystemExit) as exit:
        main([str(arg) for arg in args])
    return exit.value.code, capfd.readouterr().err.splitlines()


def contents(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def leftovers(folder: Path) -> list[str]:
    """Hidden entries: claims and temporaries (none may be left once a run has ended)."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


# ------------------------------------------------------------------------------------------ settings on a re-run
def test_a_rerun_with_another_black_level_keeps_the_outputs_says_so_and_overwrite_remakes_them(data, tmp_path, capfd):
    out = tmp_path / "out"
    code, err = cli(capfd, "correct", data["cal"], data["frames"], "--out", out, "--workers", "0")
    assert code == 0, err
    first = contents(out)

    code, err = cli(capfd, "correct", data["cal"], data["frames"], "--out", out, "--workers", "0", "--black-level", 60)
    assert code == 1, err  # outputs not made as asked: the batch does not pass for done
    assert err[-2] == (
        f"picamcal: kept {FRAMES} outputs made with other settings (black level 64, now 60): use --overwrite to "
        "remake them"
    )
    assert "wrote 0 image(s)" in err[-1] and "skipped 0 (done already)" in err[-1]
    assert contents(out) == first  # left as they were

    code, err = cli(
        capfd,
        "correct",
        data["cal"],
        data["frames"],
        "--out",
        out,
        "--workers",
        "0",
        "--black-level",
        60,
        "--overwrite",
    )
    assert code == 0 and f"wrote {FRAMES} image(s)" in err[-1], err
    record = read_record(out / "f0.tiff")["made_with"]
    assert record["black_level"] == [60.0] * 4 and record["used"]["black_level"] == [60.0] * 4
    # 4 DN less black taken off a signal of some hundred DN: the remade image is brighter, by a few per cent at most
    ratio = np.median(tifffile.imread(out / "f0.tiff")) / np.median(tifffile.imread(io.BytesIO(first["f0.tiff"])))
    assert 1.001 < ratio < 1.1

    code, err = cli(capfd, "correct", data["cal"], data["frames"], "--out", out, "--workers", "0", "--black-level", 60)
    assert code == 0 and f"skipped {FRAMES} (done already)" in err[-1] and "kept" not in " ".join(err), err


def test_the_newcomers_walk_a_frame_taken_at_black_0_then_corrected_with_64_says_so(data, tmp_path, capfd):
    """The stumble of issue 31: a file that says black level 0 corrected as it says, then again with
    ``--black-level 64``, was "skipped 1 (done already)"."""
    raw = read_raw(data["frames"] / "f0.dng")
    write_dng(tmp_path / "frame.dng", dataclasses.replace(raw, black_level=(0, 0, 0, 0)))
    out = tmp_path / "out"
    assert cli(capfd, "correct", data["cal"], tmp_path / "frame.dng", "--out", out, "--pattern", "BGGR")[0] == 0
    code, err = cli(
        capfd, "correct", data["cal"], tmp_path / "frame.dng", "--out", out, "--pattern", "BGGR", "--black-level", 64
    )
    assert code == 1 and err[-2] == (
        "picamcal: kept 1 output made with other settings (black level 0, now 64): use --overwrite to remake them"
    ), err


def test_a_black_level_given_as_the_files_have_it_is_the_same_setting(data, tmp_path, capfd):
    """Made from the files' own 64, the outputs are those ``--black-level 64`` makes: done already."""
    out = tmp_path / "out"
    assert cli(capfd, "correct", data["cal"], data["frames"], "--out", out, "--workers", "0")[0] == 0
    code, err = cli(capfd, "correct", data["cal"], data["frames"], "--out", out, "--workers", "0", "--black-level", 64)
    assert code == 0 and f"skipped {FRAMES} (done already)" in err[-1], err


def test_several_differing_settings_are_each_named(data, tmp_path):
    out = tmp_path / "out"
    run_batch(data["cal"], [data["frames"]], BatchOptions(out_dir=out, workers=0, mode="flat"))
    again = run_batch(
        data["cal"], [data["frames"]], BatchOptions(out_dir=out, workers=0, output_format="uint16-tiff", pattern="RGGB")
    )
    assert again.done == [] and again.skipped == []
    assert [found for _, found in again.kept] == [
        ["mode flat, now centre", "format float32-tiff, now uint16-tiff", "Bayer pattern BGGR, now RGGB"]
    ] * FRAMES


def test_a_reference_file_counts_by_its_content_and_an_input_encoding_is_named(data, tmp_path, monkeypatch):
    """The tuning file of an sRGB output's colour matrix: the same file named from another folder, or renamed, is
    the same setting; another content is not. Processed images: the input encoding."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(stock_tuning_path("imx219", "pisp"), "t.json")
    frame, out = data["frames"] / "f0.dng", tmp_path / "out"

    def srgb(tuning: Path) -> BatchOptions:
        return BatchOptions(out_dir=out, workers=0, output_format="srgb-png", tuning=tuning)

    assert run_batch(data["cal"], [frame], srgb(Path("t.json"))).done == [frame]
    assert run_batch(data["cal"], [frame], srgb(tmp_path / "t.json")).skipped == [frame]
    shutil.copy("t.json", "u.json")
    assert run_batch(data["cal"], [frame], srgb(Path("u.json"))).skipped == [frame]
    Path("v.json").write_text(json.dumps(json.loads(Path("t.json").read_text())))  # other bytes: another file
    assert run_batch(data["cal"], [frame], srgb(Path("v.json"))).kept == [(frame, ["tuning file t.json, now v.json"])]

    rgb = np.full((120, 160, 3), 128, np.uint8)
    Image.fromarray(rgb).save("isp.png")
    processed = tmp_path / "processed"
    run_batch(data["cal"], ["isp.png"], BatchOptions(out_dir=processed, workers=0, processed=True))
    linear = BatchOptions(out_dir=processed, workers=0, processed=True, input_encoding="linear")
    assert run_batch(data["cal"], ["isp.png"], linear).kept == [(Path("isp.png"), ["input encoding srgb, now linear"])]


FORMATS = ["float32-tiff", "uint16-tiff", "srgb-png", "srgb-png16", "srgb-jpeg", "linear-dng", "dng-gainmap"]


@pytest.mark.parametrize("output_format", FORMATS)
def test_every_output_format_records_the_settings_that_made_it(data, tmp_path, output_format):
    frame = data["frames"] / "f0.dng"
    out = tmp_path / "out"
    options = BatchOptions(out_dir=out, workers=0, output_format=output_format)
    assert run_batch(data["cal"], [frame], options).done == [frame]
    record = read_record(out / f"f0{OUTPUT_SUFFIXES[output_format]}")["made_with"]
    assert record["output_format"] == output_format and record["mode"] == "centre"
    assert record["calibration"] == "cal.npz" and len(record["calibration_sha256"]) == 64
    assert record["black_level"] is None and record["used"] == {
        "pattern": "BGGR",
        "black_level": [64.0] * 4,
        "white_level": 1023,
    }
    given = BatchOptions(out_dir=out, workers=0, output_format=output_format, black_level=(64, 64, 64, 64))
    assert run_batch(data["cal"], [frame], given).skipped == [frame]  # the file's own 64: the same
    other = run_batch(
        data["cal"], [frame], BatchOptions(out_dir=out, workers=0, output_format=output_format, mode="flat")
    )
    assert other.kept == [(frame, ["mode centre, now flat"])]


def test_an_output_without_the_record_is_kept_and_a_file_picamcal_did_not_write_is_never_replaced(data, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    write_corrected(out / "f0.tiff", np.ones((240, 320, 3), np.float32), "float32-tiff", {"mode": "centre"})
    tifffile.imwrite(out / "f1.tiff", np.zeros((4, 4, 3), np.uint8))  # not picamcal's
    foreign = (out / "f1.tiff").read_bytes()
    frames = sorted(data["frames"].iterdir())
    result = run_batch(data["cal"], frames, BatchOptions(out_dir=out, workers=0))
    assert result.done == frames[2:]
    assert result.kept == [(frames[0], ["settings not recorded (an earlier picamcal wrote it)"])]
    assert [(path, reason.split(": ", 1)[1]) for path, reason in result.failed] == [
        (frames[1], "exists and is not an image picamcal wrote: picamcal replaces only what it wrote itself; "
         "choose another --out"),
    ]  # fmt: skip
    with pytest.raises(OutputError, match=r"f1\.tiff: exists and is not an image picamcal wrote"):
        run_batch(data["cal"], frames, BatchOptions(out_dir=out, workers=0, overwrite=True))
    assert (out / "f1.tiff").read_bytes() == foreign
    assert run_batch(data["cal"], frames[:1], BatchOptions(out_dir=out, workers=0, overwrite=True)).done == frames[:1]


def test_one_file_whose_output_name_is_taken_by_another_programs_file_is_one_line_and_exit_2(data, tmp_path, capfd):
    out = tmp_path / "out"
    out.mkdir()
    tifffile.imwrite(out / "f0.tiff", np.zeros((4, 4, 3), np.uint8))
    code, err = cli(capfd, "correct", data["cal"], data["frames"] / "f0.dng", "--out", out, "--workers", "0")
    assert code == 2 and len(err) == 1 and "f0.tiff: exists and is not an image picamcal wrote" in err[0], err


# ---------------------------------------------------------------------------------------------------- claims
HOLD = """
import sys
from picamcal.batch import claims
for target in sys.argv[1:]:
    assert claims.take(target, "another run")
print("held", flush=True)
sys.stdin.readline()
for target in sys.argv[1:]:
    claims.release(target, "another run")
"""


def hold_claims(*targets: Path) -> subprocess.Popen:
    """A process of another run that claims ``targets`` and holds them until a line on its stdin (then it releases
    them) or until it is killed (then they stay, stale)."""
    process = subprocess.Popen(
        [sys.executable, "-c", HOLD, *map(str, targets)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert process.stdout.readline() == "held\n"
    return process


def test_a_stale_claim_of_a_killed_run_does_not_block_a_later_run(data, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    holder = hold_claims(out / "f0.tiff", out / "f1.tiff")
    assert claims.is_claimed(out / "f0.tiff")
    holder.kill()  # as kill -9: its claims stay behind
    holder.wait()
    assert len(leftovers(out)) == 2 and not claims.is_claimed(out / "f0.tiff")
    frames = sorted(data["frames"].iterdir())
    result = run_batch(data["cal"], frames, BatchOptions(out_dir=out, workers=0))
    assert result.done == frames and result.by_another_run == []
    assert leftovers(out) == []


def test_claims_are_stale_by_age_when_their_maker_cannot_be_asked(tmp_path):
    """An empty claim (its maker killed between making and writing it) after EMPTY_STALE_AFTER_S; another
    machine's after STALE_AFTER_S untouched; a fresh one of another machine is live."""
    empty, remote = tmp_path / "a.tiff", tmp_path / "b.tiff"
    claims.claim_path(empty).touch()
    claims.claim_path(remote).write_text(json.dumps({"host": "0badc0de", "pid": 1, "start": "1", "run": "r"}))
    assert claims.is_claimed(empty) and claims.is_claimed(remote) and not claims.take(remote, "mine")
    old = time.time() - claims.STALE_AFTER_S - 1
    os.utime(claims.claim_path(empty), (old, old))
    os.utime(claims.claim_path(remote), (old, old))
    assert not claims.is_claimed(empty) and claims.take(empty, "mine") and claims.take(remote, "mine")
    claims.release(empty, "mine")
    claims.release(remote, "mine")
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("other_writes", [True, False], ids=["written-by-the-other", "left-by-the-other"])
def test_an_output_another_run_holds_is_waited_for_then_counted_or_done(data, tmp_path, other_writes):
    """The other run writes the output and lets go: it is counted as written by another run; it is killed without
    writing it: this run does it."""
    frames = sorted(data["frames"].iterdir())
    reference = tmp_path / "reference"
    run_batch(data["cal"], frames, BatchOptions(out_dir=reference, workers=0))
    out = tmp_path / "out"
    out.mkdir()
    holder = hold_claims(out / "f0.tiff")
    results = []
    options = BatchOptions(out_dir=out, workers=0)
    batch = threading.Thread(target=lambda: results.append(run_batch(data["cal"], frames, options)))
    batch.start()
    try:
        while not all((out / f"f{i}.tiff").exists() for i in range(1, FRAMES)) and batch.is_alive():
            time.sleep(0.02)  # the others are done; f0 is waited for
        assert batch.is_alive() and not (out / "f0.tiff").exists()
        if other_writes:
            shutil.copy(reference / "f0.tiff", out / "f0.tiff")  # as the other run writes it
            holder.communicate("done\n")  # and lets go
        else:
            holder.kill()
        holder.wait()
    finally:
        batch.join()
    (result,) = results
    assert result.done == (frames[1:] if other_writes else frames)
    assert result.by_another_run == (frames[:1] if other_writes else [])
    assert contents(out) == contents(reference) and leftovers(out) == []


# -------------------------------------------------------------------------------------------- batches at once
def as_from_a_terminal() -> None:
    """SIGINT's default disposition in the child, whatever this test run inherited (nohup, ``&``)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def correct_in_a_process(cal: Path, frames: Path, out: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", "from picamcal.cli import main; main()", "correct", cal, frames, "--out", out, *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=as_from_a_terminal,
    )


SUMMARY = re.compile(r"wrote (\d+) image\(s\).*skipped (\d+) \(done already\)(?:; (\d+) written by another run)?")


@pytest.mark.slow
@pytest.mark.parametrize("workers", ["0", "2"])
def test_two_batches_started_together_into_one_folder_share_the_work_and_both_exit_0(data, tmp_path, workers):
    frames = tmp_path / "frames"
    frames.mkdir()
    camera = make_camera("imx219", size=SIZE)
    for i in range(16):
        write_dng(frames / f"g{i:02d}.dng", simulate_target(camera, seed=60 + i)[0])
    reference = tmp_path / "reference"
    run_batch(data["cal"], [frames], BatchOptions(out_dir=reference, workers=0))
    out = tmp_path / "out"
    runs = [correct_in_a_process(data["cal"], frames, out, "--workers", workers) for _ in range(2)]
    outputs = [run.communicate(timeout=600)[1] for run in runs]
    assert [run.returncode for run in runs] == [0, 0], outputs
    counts = []
    for stderr in outputs:
        match = SUMMARY.search(stderr.splitlines()[-1])
        assert match, stderr
        counts.append([int(group or 0) for group in match.groups()])
    (wrote_a, skipped_a, others_a), (wrote_b, skipped_b, others_b) = counts
    assert wrote_a + wrote_b == 16  # each output written once: by one run or the other
    assert skipped_a + others_a == wrote_b and skipped_b + others_b == wrote_a  # each says what the other did
    assert contents(out) == contents(reference) and leftovers(out) == []  # every output right, nothing left over


@pytest.mark.slow
def test_a_run_killed_while_it_holds_claims_is_finished_by_the_next(data, tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    camera = make_camera("imx219", size=(640, 480))
    for i in range(8):
        write_dng(frames / f"g{i}.dng", simulate_target(camera, seed=80 + i)[0])
    simulated_calibration(tmp_path, (640, 480), seed=6)
    out = tmp_path / "out"
    run = correct_in_a_process(tmp_path / "cal.npz", frames, out, "--workers", "0")
    try:
        while not (out.exists() and any(name.endswith(claims.CLAIM_SUFFIX) for name in leftovers(out))):
            assert run.poll() is None, run.stderr.read()  # the claims appear while it works
            time.sleep(0.01)
    finally:
        run.kill()
        run.communicate()
    again = run_batch(tmp_path / "cal.npz", [frames], BatchOptions(out_dir=out, workers=0))
    assert len(again.done) + len(again.skipped) == 8 and again.failed == [] and again.kept == []
    assert leftovers(out) == []
