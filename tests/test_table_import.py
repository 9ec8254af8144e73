"""The lens shading calibrations users already have: read, inspected, converted to the Pi 4's and Pi 5's tables, and
used to correct, as the flat field they describe (picamcal.export.tables)."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import picamcal
from picamcal import PicamcalError, PicamcalWarning
from picamcal.bayer import bin_sites
from picamcal.export.isp import apply_tuning, channel_tables, lens_shading_gains_at
from picamcal.export.legacy import legacy_table, table_shape
from picamcal.export.tables import (
    TableFileError,
    describe_table,
    load_flat_field,
    read_shading_table,
    table_calibration,
)
from picamcal.export.tables.c_header import read_header_table
from picamcal.export.tuning import (
    check_tuning,
    export_tuning,
    load_tuning,
    stock_tuning_path,
)
from picamcal.geometry import SensorMode
from picamcal.simulate import make_camera, render, simulate_references
from test_cli import assert_bad_input, run

IMX219 = (3280, 2464)
#: OpenFlexure's server keeps other settings beside the table in the same .npz.
OTHER_SETTINGS = {"shutter_speed": np.array(20000), "analog_gain": np.array(1.0), "awb_gains": np.array([1.6, 1.2])}


def _cv(values: np.ndarray) -> float:
    return float(values.std() / values.mean())


def block_flatness(rgb: np.ndarray) -> dict[str, float]:
    """CV of the 16 x 16 block means of G, R/G and B/G over the whole frame (as tests/test_export.py measures it)."""
    means = np.stack([bin_sites(rgb[..., c], 16).mean(-1) for c in range(3)], axis=-1)
    g = means[..., 1]
    return {"G": _cv(g), "R/G": _cv(means[..., 0] / g), "B/G": _cv(means[..., 2] / g)}


def openflexure_table(calibration) -> np.ndarray:
    """A table as OpenFlexure's server saves one: the legacy firmware's, its gains truncated to u3.5."""
    return legacy_table(calibration, rounding="floor")


@pytest.fixture(scope="module", params=[(0.0, 0.0), (3.0, -2.0)], ids=["centred", "tilted"])
def microscope(request, tmp_path_factory):
    """Two microscopes' saved tables: a full IMX219 white (the second behind tilted optics), its calibration, the
    microscope_settings.npz OpenFlexure would have saved from it, and the tunings exported from that calibration
    itself for each platform (``own``)."""
    folder = tmp_path_factory.mktemp("microscope")
    white = render(make_camera("imx219", tilt=request.param), "white", rng=1)
    white_path = picamcal.write_dng(folder / "white.dng", white)
    calibration = picamcal.calibrate(white)
    calibration.save(folder / "cal.npz")
    table = openflexure_table(calibration)
    np.savez(folder / "microscope_settings.npz", lens_shading_table=table, **OTHER_SETTINGS)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PicamcalWarning)
        own = {target: export_tuning(calibration, load_tuning(stock_tuning_path("imx219", target)))
               for target in ("bcm2835", "pisp")}  # fmt: skip
    return {"folder": folder, "white": white, "white_path": white_path, "calibration": calibration, "table": table,
            "own": own}  # fmt: skip


# --- what it must show: OpenFlexure's tables on a Pi 4 and a Pi 5 ---------------------------------------------------


@pytest.mark.slow
def test_openflexure_tables_become_tunings_that_flatten_their_white_as_well_as_its_own_calibration(microscope):
    folder = microscope["folder"]
    out = folder / "tuning"
    result = run("export-tuning", str(folder / "microscope_settings.npz"), "--sensor", "imx219", "--out", str(out))
    assert result.returncode == 0, result.stderr
    for target, label in (("bcm2835", "vc4"), ("pisp", "pisp")):
        tuning = load_tuning(out / f"imx219_{label}.json")
        assert check_tuning(tuning) == target  # libcamera's rules accept it
        assert tuning["picamcal"]["sensor"] == "imx219" and "colour_gains" not in tuning["picamcal"]
        from_table = block_flatness(apply_tuning(microscope["white"], tuning))
        from_calibration = block_flatness(apply_tuning(microscope["white"], microscope["own"][target]))
        # The grid's own limit: the table's tuning within 1.2 times the block CV of a tuning from the white itself
        # (measured 0.93 to 1.11: the u3.5 steps, dequantised, and the table's 64-pixel cells cost that much).
        for key, cv in from_table.items():
            assert cv <= 1.2 * from_calibration[key], (target, key, from_table, from_calibration)


@pytest.mark.slow
def test_a_pi_4_tuning_converted_to_the_pi_5_and_back_is_within_half_a_percent_in_every_cell(microscope, tmp_path):
    vc4 = tmp_path / "imx219_vc4.json"
    tuning = microscope["own"]["bcm2835"]
    vc4.write_text(json.dumps(tuning))
    pisp, back = tmp_path / "pisp" / "imx219_pisp.json", tmp_path / "back" / "imx219_vc4.json"
    for source, target, out in ((vc4, "pisp", pisp), (pisp, "vc4", back)):
        result = run("export-tuning", str(source), "--target", target, "--out", str(out))
        assert result.returncode == 0, result.stderr
        said = result.stdout + result.stderr
        assert f"base {stock_tuning_path('imx219', target)}" in said  # the stock file of the target
    full = SensorMode.full(*IMX219)
    original, returned = channel_tables(tuning, full), channel_tables(load_tuning(back), full)
    # Resampled as libcamera samples each grid, not zoomed: measured 0.18 % at most.
    assert float(np.abs(returned / original - 1).max()) < 0.005


@pytest.mark.slow
def test_export_lst_of_a_pi_5_tuning_gives_the_legacy_table_of_its_flat_field(microscope, tmp_path):
    (tmp_path / "imx219_pisp.json").write_text(json.dumps(microscope["own"]["pisp"]))
    result = run("export-lst", str(tmp_path / "imx219_pisp.json"), "--out", str(tmp_path / "lst.npy"))
    assert result.returncode == 0, result.stderr
    table = np.load(tmp_path / "lst.npy")
    direct = legacy_table(microscope["calibration"])
    # Through the Pi 5's grid and back to 64-pixel cells: less than half a u3.5 step from the white's own table on
    # average, 3 at most at the edges, where the grids extrapolate differently (measured 0.39 and 0.40; 2 and 3).
    difference = np.abs(table.astype(int) - direct)
    assert table.shape == direct.shape and int(difference.max()) <= 3 and float(difference.mean()) < 0.5


@pytest.mark.slow
def test_a_stock_tuning_with_several_colour_temperatures_converts_at_its_default_one(tmp_path):
    flat = table_calibration(read_shading_table(stock_tuning_path("imx219", "bcm2835")))
    assert list(flat.provenance["imported_table"]["cts"]) == [3000, 3850, 6000]
    assert flat.provenance["imported_table"]["ct"] == 4500.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PicamcalWarning)
        pisp = export_tuning(flat, load_tuning(stock_tuning_path("imx219", "pisp")))
    # The Pi 5's finer grid holds the Pi 4's field within 1 % everywhere (the stock lens' steep corners included):
    # compared at the centre of each Pi 4 cell, each normalised at the frame's centre.
    full = SensorMode.full(*IMX219)
    rows = (np.arange(12) + 0.5) * IMX219[1] / 12 - 0.5
    cols = (np.arange(16) + 0.5) * IMX219[0] / 16 - 0.5
    stock = lens_shading_gains_at(load_tuning(stock_tuning_path("imx219", "bcm2835")), full, rows, cols)
    converted = lens_shading_gains_at(pisp, full, rows, cols)
    ratio = (converted / converted[:, 5:7, 7:9].mean(axis=(1, 2), keepdims=True)) / (
        stock / stock[:, 5:7, 7:9].mean(axis=(1, 2), keepdims=True)
    )
    assert float(np.abs(ratio - 1).max()) < 0.01, ratio


@pytest.mark.slow
def test_correct_and_apply_tuning_use_a_table_as_the_flat_field(microscope, tmp_path):
    folder = microscope["folder"]
    result = run("correct", str(folder / "microscope_settings.npz"), str(microscope["white_path"]), "--out",
                 str(tmp_path / "corrected"), "--workers", "0")  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "in mode flat" in result.stdout + result.stderr
    import tifffile

    corrected = tifffile.imread(tmp_path / "corrected" / "white.tiff")
    assert block_flatness(corrected)["G"] < 0.005  # flat to 0.5 % (measured 0.22 %; the white before: 14 %)
    applied = tmp_path / "applied.tiff"
    result = run("apply-tuning", str(folder / "microscope_settings.npz"), str(microscope["white_path"]), "--out",
                 str(applied))  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert block_flatness(tifffile.imread(applied))["G"] < 0.005


# --- reading each kind of file --------------------------------------------------------------------------------------


def _header(table: np.ndarray, *, swapped: bool = False, style: str = "6by9") -> str:
    """A C header as 6by9's lens_shading tool writes it (or cpixip's script, grid_width and grid_height swapped)."""
    _, rows, cols = table.shape
    lines = ["uint8_t ls_grid[] = {"]
    for plane, name in zip(table, ("R", "Gr", "Gb", "B"), strict=True):
        lines.append(f"//{name} - Ch {3 - ['R', 'Gr', 'Gb', 'B'].index(name)}")
        for row in plane:
            values = [f"0x{v:02x}" if style == "hex" else str(v) for v in row]
            lines.append(", ".join(values) + ",")
    width, height = (rows, cols) if swapped else (cols, rows)
    lines += [
        "};",
        "uint32_t ref_transform = 3;",
        f"uint32_t grid_width = {width};",
        f"uint32_t grid_height = {height};",
    ]
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def small_table() -> np.ndarray:
    rng = np.random.default_rng(3)
    return rng.integers(32, 90, size=table_shape(*IMX219), dtype=np.uint8)


@pytest.mark.parametrize("style", ["6by9", "swapped", "hex"])
def test_a_c_header_reads_as_the_table_it_holds(small_table, tmp_path, style):
    path = tmp_path / "ls_table_3280x2464.h"
    path.write_text("/* lens shading for a microscope */\n" + _header(small_table, swapped=style == "swapped",
                                                                         style=style))  # fmt: skip
    table, said = read_header_table(path)
    assert np.array_equal(table, small_table)
    assert said["ref_transform"] == 3
    read = read_shading_table(path)
    assert read.kind == "c-header" and read.rounding == "floor"


def test_each_container_gives_the_same_table(small_table, tmp_path):
    np.save(tmp_path / "lst.npy", small_table)
    np.savez(tmp_path / "microscope_settings.npz", lens_shading_table=small_table, **OTHER_SETTINGS)
    (tmp_path / "ls_table.h").write_text(_header(small_table))
    kinds = {}
    for name in ("lst.npy", "microscope_settings.npz", "ls_table.h"):
        table = read_shading_table(tmp_path / name)
        assert np.array_equal(table.legacy, small_table), name
        kinds[name] = table.kind
    assert kinds == {"lst.npy": "npy", "microscope_settings.npz": "openflexure", "ls_table.h": "c-header"}


def test_a_table_becomes_a_flat_calibration_of_the_whole_sensor(small_table, tmp_path):
    np.save(tmp_path / "lst.npy", small_table)
    flat = load_flat_field(tmp_path / "lst.npy")
    assert (flat.kind, flat.sensor, flat.width, flat.height, flat.pattern) == ("flat", "imx219", *IMX219, "BGGR")
    assert flat.geometry is not None and flat.geometry.is_full
    assert flat.inputs[0]["role"] == "lens_shading_table" and flat.inputs[0]["name"] == "lst.npy"
    # W is proportional to 1 / gain: where the table asks for twice the gain, the white is half as bright.
    assert float(flat.site_white.max() / flat.site_white.min()) == pytest.approx(
        float(small_table.max() / small_table.min()), rel=0.1
    )


@pytest.mark.slow
def test_picamcal_s_own_table_goes_back_to_the_flat_field_it_came_from(tmp_path):
    white = simulate_references(make_camera("imx219"), noise=False)["white"]
    calibration = picamcal.calibrate(white)
    np.save(tmp_path / "lst.npy", legacy_table(calibration))
    flat = load_flat_field(tmp_path / "lst.npy")
    # The table keeps each channel's shape: its lens shading is the calibration's within the u3.5 steps, 1 % at
    # most over the frame's inner 90 % (measured 0.6 %); the corners' outer half cell is clamped by the firmware.
    inner = (slice(8, -8), slice(10, -10))
    ratio = flat.lens_shading[inner] / calibration.lens_shading[inner]
    assert float(np.abs(ratio / ratio.mean(axis=(0, 1)) - 1).max()) < 0.01


# --- inspect -------------------------------------------------------------------------------------------------------


def test_inspect_says_what_each_table_is(small_table, tmp_path):
    np.save(tmp_path / "lst.npy", small_table)
    np.savez(tmp_path / "microscope_settings.npz", lens_shading_table=small_table, **OTHER_SETTINGS)
    (tmp_path / "ls_table.h").write_text(_header(small_table))
    shutil.copy(stock_tuning_path("imx219", "pisp"), tmp_path / "imx219.json")
    result = run("inspect", "--json", *(str(tmp_path / name) for name in
                 ("lst.npy", "microscope_settings.npz", "ls_table.h", "imx219.json")))  # fmt: skip
    assert result.returncode == 0, result.stderr
    records = {Path(r["path"]).name: r for r in json.loads(result.stdout)}
    gains = [round(int(small_table.min()) / 32, 4), round(int(small_table.max()) / 32, 4)]
    for name, words in (
        ("lst.npy", "legacy lens shading table (.npy, picamcal export-lst)"),
        ("microscope_settings.npz", "OpenFlexure lens shading table (microscope_settings.npz)"),
        ("ls_table.h", "legacy lens shading table (C header)"),
    ):
        record = records[name]
        assert record["readable"] and record["format"].startswith(words), record
        assert record["grid"] == "52 x 39 cells of 64 px, planes R, Gr, Gb, B"
        assert record["sensor"] == "imx219" and record["gains"] == gains and record["unity"] == "32 in u3.5"
    tuning = records["imx219.json"]
    assert tuning["grid"] == "32 x 32 (Pi 5, pisp)" and tuning["sensor"] == "imx219" and tuning["unity"] == "1.0"
    assert tuning["colour_temperatures"] == [3000, 5000]  # the stock file's two tables
    assert "taken at 4500 K" in tuning["format"] and 1.0 <= tuning["gains"][0] < tuning["gains"][1] < 8
    table = run("inspect", str(tmp_path / "microscope_settings.npz"))
    assert "OpenFlexure lens shading table" in table.stdout and "not a raw buffer" not in table.stdout


def test_inspect_of_a_table_of_no_known_size_says_so(tmp_path):
    np.save(tmp_path / "odd.npy", np.full((4, 10, 10), 40, np.uint8))
    record = describe_table(read_shading_table(tmp_path / "odd.npy"))
    assert record["sensor"] is None and record["sensor_candidates"] == []


# --- bad input -------------------------------------------------------------------------------------------------------


def _assert_refused(tmp_path: Path, source: Path, *fragments: str, extra: tuple[str, ...] = ()) -> None:
    out = tmp_path / "out"
    result = run("export-tuning", str(source), "--out", str(out), *extra)
    assert_bad_input(result, source.name, *fragments)
    assert not out.exists() or not any(out.iterdir())  # nothing written


def test_a_table_of_an_unknown_shape_is_refused(tmp_path):
    np.save(tmp_path / "odd.npy", np.full((4, 10, 10), 40, np.uint8))
    _assert_refused(tmp_path, tmp_path / "odd.npy", "shape (4, 10, 10) fits no sensor", "(4, 39, 52) for the IMX219")
    np.save(tmp_path / "three.npy", np.full((3, 39, 52), 40, np.uint8))
    _assert_refused(tmp_path, tmp_path / "three.npy", "shape (3, 39, 52)", "expected (4, rows, columns)")


def test_a_table_for_another_sensor_than_the_one_named_is_refused(small_table, tmp_path):
    np.save(tmp_path / "lst.npy", small_table)
    _assert_refused(tmp_path, tmp_path / "lst.npy", "not the imx477's", "imx219", extra=("--sensor", "imx477"))


def test_a_table_with_zeros_is_refused(small_table, tmp_path):
    zeros = small_table.copy()
    zeros[1, 3, 4] = 0
    np.savez(tmp_path / "microscope_settings.npz", lens_shading_table=zeros)
    _assert_refused(tmp_path, tmp_path / "microscope_settings.npz", "1 zeros", "gain 0")


def test_gains_past_what_the_target_can_hold_are_refused(tmp_path):
    tuning = load_tuning(stock_tuning_path("imx219", "bcm2835"))
    alsc = next(a["rpi.alsc"] for a in tuning["algorithms"] if "rpi.alsc" in a)
    lut = np.asarray(alsc["luminance_lut"]).reshape(12, 16)
    alsc["luminance_lut"] = (1 + 11 * (lut - lut.min()) / (lut.max() - lut.min())).ravel().round(3).tolist()
    alsc["luminance_strength"] = 1.0  # a corner gain of 12: the Pi 4 holds it, the Pi 5 (below 8) cannot
    path = tmp_path / "imx219_vc4.json"
    path.write_text(json.dumps(tuning))
    _assert_refused(tmp_path, path, "above the pisp hardware limit of 8", "--clip-gains", extra=("--target", "pisp"))


@pytest.mark.slow
def test_a_tuning_file_with_no_rpi_alsc_or_a_broken_one_is_refused(tmp_path):
    shutil.copy(stock_tuning_path("imx219", "pisp").parent / "uncalibrated.json", tmp_path / "imx219.json")
    _assert_refused(tmp_path, tmp_path / "imx219.json", "no rpi.alsc section", "lens shading table")
    broken = load_tuning(stock_tuning_path("imx219", "pisp"))
    next(a["rpi.alsc"] for a in broken["algorithms"] if "rpi.alsc" in a)["luminance_lut"] = [1.0, 2.0]
    (tmp_path / "broken_imx219.json").write_text(json.dumps(broken))
    _assert_refused(tmp_path, tmp_path / "broken_imx219.json", "luminance_lut must hold 1024 items")


@pytest.mark.slow
def test_a_c_header_that_is_not_a_table_is_refused(tmp_path):
    (tmp_path / "camera.h").write_text("#pragma once\nint camera_open(const char *name);\n")
    _assert_refused(tmp_path, tmp_path / "camera.h", "no table", "ls_table.h")
    (tmp_path / "short.h").write_text("uint8_t ls_grid[] = { 32, 33, 34 };\n")
    _assert_refused(tmp_path, tmp_path / "short.h", "3 numbers", "4 planes")
    (tmp_path / "words.h").write_text("uint8_t ls_grid[] = { 32, gain(2), 34, 35 };\n")
    _assert_refused(tmp_path, tmp_path / "words.h", "'gain(2)'", "whole numbers 0..255")


def test_an_npz_with_other_keys_is_refused(tmp_path):
    np.savez(tmp_path / "settings.npz", exposure=np.array(1.0), gains=np.ones(2))
    _assert_refused(tmp_path, tmp_path / "settings.npz", "holds exposure, gains", "lens_shading_table")


def test_report_of_a_table_names_the_command_that_takes_it(small_table, tmp_path):
    np.savez(tmp_path / "microscope_settings.npz", lens_shading_table=small_table)
    result = run("report", str(tmp_path / "microscope_settings.npz"), "--out", str(tmp_path / "report"))
    assert_bad_input(result, "OpenFlexure lens shading table", "picamcal export-tuning microscope_settings.npz")
    assert "correct" not in result.stderr
    assert not (tmp_path / "report").exists()


@pytest.mark.slow
def test_export_tuning_for_a_sensor_without_a_stock_file_starts_from_the_bundled_generic_one(tmp_path):
    white = simulate_references(make_camera("imx585", size=(384, 216)), seed=1)["white"]
    picamcal.calibrate(white).save(tmp_path / "cal.npz")
    result = run("export-tuning", str(tmp_path / "cal.npz"), "--out", str(tmp_path / "tuning"))
    assert result.returncode == 0, result.stderr
    assert "started from libcamera's uncalibrated.json" in result.stdout + result.stderr  # said, not asked for
    tuning = load_tuning(tmp_path / "tuning" / "imx585_pisp.json")
    black = next(a["rpi.black_level"] for a in tuning["algorithms"] if "rpi.black_level" in a)
    assert black["black_level"] == 200 << 4  # the imx585's 200 at 12 bits, on libcamera's 16-bit scale


# --- whatever the bytes: picamcal's own error --------------------------------------------------------------------


@pytest.fixture(scope="module")
def table_files(tmp_path_factory) -> dict[str, bytes]:
    folder = tmp_path_factory.mktemp("tables")
    table = np.random.default_rng(1).integers(32, 90, size=table_shape(*IMX219), dtype=np.uint8)
    np.save(folder / "lst.npy", table)
    np.savez(folder / "microscope_settings.npz", lens_shading_table=table, **OTHER_SETTINGS)
    (folder / "ls_table.h").write_text(_header(table))
    return {name: (folder / name).read_bytes() for name in ("lst.npy", "microscope_settings.npz", "ls_table.h")} | {
        "imx219.json": stock_tuning_path("imx219", "bcm2835").read_bytes()
    }


@given(data=st.data())
@settings(max_examples=150, deadline=None, database=None)
def test_table_readers_raise_only_picamcal_errors(table_files, tmp_path_factory, data):
    name = data.draw(st.sampled_from(sorted(table_files)))
    content = bytearray(table_files[name])
    how = data.draw(st.sampled_from(["flip", "cut", "digits"]))
    if how == "cut":
        content = content[: data.draw(st.integers(0, len(content) - 1))]
    elif how == "digits" and name.endswith((".h", ".json")):  # numbers of any size, signs and letters in the text
        at = data.draw(st.integers(0, len(content)))
        content[at:at] = data.draw(st.sampled_from([b"-", b"999999999999", b"0x", b"x", b"/*", b"{", b"}", b"1e999"]))
    for at, byte in data.draw(st.lists(st.tuples(st.integers(0, 1 << 20), st.integers(0, 255)), max_size=6)):
        if content:
            content[at % len(content)] = byte
    folder = tmp_path_factory.getbasetemp() / "fuzz_tables"
    folder.mkdir(exist_ok=True)
    path = folder / name
    path.write_bytes(bytes(content))
    try:
        table = read_shading_table(path)
        describe_table(table)
    except PicamcalError:
        return
    assert table.legacy is None or (table.legacy.dtype == np.uint8 and table.legacy.shape[0] == 4)


def test_table_errors_are_picamcals(tmp_path):
    assert issubclass(TableFileError, PicamcalError)
    (tmp_path / "notes.txt").write_text("focus at 3 mm")
    with pytest.raises(TableFileError, match="not a lens shading calibration"):
        read_shading_table(tmp_path / "notes.txt")
