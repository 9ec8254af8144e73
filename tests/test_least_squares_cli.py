"""``picamcal calibrate`` with extra colour references (``colour_<name>`` files, ``--colour``) and
``--max-noise-penalty``: what it writes and prints, and the bad input it refuses (exit 2, one line, nothing written).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from picamcal import load_calibration, write_dng
from picamcal.simulate import make_camera, render, simulate_references
from test_cli import assert_bad_input, run


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """White, red, green, blue, black, and a cyan mixture in two frames (colour_cyan_1, colour_cyan_2), 160x120."""
    root = tmp_path_factory.mktemp("extras")
    refs = root / "refs"
    refs.mkdir()
    camera = make_camera("imx219", size=(160, 120))
    for role, raw in simulate_references(camera, seed=2).items():
        write_dng(refs / f"{role}.dng", raw)
    for k in (1, 2):
        write_dng(refs / f"colour_cyan_{k}.dng", render(camera, (0, 1, 1), rng=10 + k))
    write_dng(root / "amber.dng", render(camera, (1, 0.5, 0), rng=20))
    write_dng(root / "colour_small.dng", render(make_camera("imx219", size=(128, 96)), (1, 0, 1), rng=21))
    return root


@pytest.mark.slow  # 3.3 s
def test_calibrate_a_folder_with_extras_and_a_bound(folder):
    out = folder / "cal.npz"
    result = run(
        "calibrate",
        str(folder / "refs"),
        "--colour",
        f"amber={folder / 'amber.dng'}",
        "--max-noise-penalty",
        "2.5",
        "--out",
        str(out),
    )
    assert result.returncode == 0, result.stderr
    cal = load_calibration(out)
    inputs = {i["role"]: i for i in cal.inputs}
    assert list(inputs) == ["white", "red", "green", "blue", "colour_cyan", "colour_amber", "black"]
    assert inputs["colour_cyan"]["frame_count"] == 2  # colour_cyan_1 and _2 averaged, as whites are
    assert cal.noise_limit["max_noise_penalty"] == 2.5 and cal.noise_penalty("centre").max() <= 2.5
    printed = result.stdout + result.stderr
    assert "worst noise penalty (centre mode) 2.50" in printed
    assert "least-squares unmixing from 5 colour references" in printed
    assert "noise_limit: noise penalty bounded at 2.5x" in printed and "CIEDE2000" in printed


def bad(folder: Path, *args: str) -> tuple:
    out = folder / "bad.npz"
    return run("calibrate", str(folder / "refs"), *args, "--out", str(out)), out


@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (("--max-noise-penalty", "0.5"), ("--max-noise-penalty", "0.5 is outside the accepted range, 1 or more")),
        (("--max-noise-penalty", "nan"), ("--max-noise-penalty", "nan is outside the accepted range")),
        (
            ("--max-noise-penalty", "1.1"),
            ("max noise penalty 1.1 is below the flat field's own", "--max-noise-penalty"),
        ),
        (("--colour", "AMBER"), ("--colour", "'AMBER': name the colour, NAME=FILE")),
    ],
)
@pytest.mark.slow
def test_bad_options_are_refused(folder, args, fragments):
    result, out = bad(folder, *args)
    assert_bad_input(result, *fragments)
    assert not out.exists()


def test_two_references_of_one_name_are_refused(folder):
    amber = str(folder / "amber.dng")
    result, out = bad(folder, "--colour", f"amber={amber}", "--colour", f"Amber={amber}")
    assert_bad_input(result, "--colour", "two references are named amber")
    assert not out.exists()


@pytest.mark.slow
def test_an_extra_that_repeats_another_colour_is_refused_naming_it(folder):
    amber = str(folder / "amber.dng")
    result, out = bad(folder, "--colour", f"amber={amber}", "--colour", f"orange={amber}")  # one file, two names
    assert_bad_input(result, "amber.dng", "colour_orange reference is identical to the colour_amber reference")
    assert not out.exists()


@pytest.mark.slow
def test_an_extra_of_another_size_is_refused_naming_it(folder):
    result, out = bad(folder, "--colour", str(folder / "colour_small.dng"))  # the name from the file: small
    assert_bad_input(result, "colour_small.dng", "size 128x96 differs from the white reference's 160x120")
    assert not out.exists()


def test_extras_without_the_primaries_are_refused_naming_the_folder(folder, tmp_path):
    for name in ("white.dng", "colour_cyan_1.dng"):
        (tmp_path / name).write_bytes((folder / "refs" / name).read_bytes())
    result = run("calibrate", str(tmp_path), "--out", str(tmp_path / "cal.npz"))
    assert_bad_input(result, str(tmp_path), "colour_cyan_1.dng is an extra colour reference, but there is no red")
    assert not (tmp_path / "cal.npz").exists()
    np.testing.assert_equal(sorted(p.name for p in tmp_path.iterdir()), ["colour_cyan_1.dng", "white.dng"])
