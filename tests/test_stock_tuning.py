"""Every stock libcamera tuning file, read as libcamera reads it; export-tuning from them for every sensor, with its
variants; the colour gains each exported file records; apply-tuning's output formats."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import warnings
from pathlib import Path

import numpy as np
import pytest
import tifffile

from picamcal import calibrate
from picamcal._json import parse_libcamera_yaml
from picamcal.cli import main
from picamcal.errors import PicamcalError, PicamcalWarning
from picamcal.export.isp import apply_tuning, check_tuning
from picamcal.export.tuning import (
    BUNDLED_TUNING_DIR,
    TuningError,
    export_tuning,
    load_tuning,
    save_tuning,
    stock_tuning_files,
    stock_tuning_path,
)
from picamcal.raw import RawImage
from picamcal.raw.processed import tuning_gamma_curve
from picamcal.sensors import SENSORS
from picamcal.simulate import make_camera, simulate_references

DATA = Path(__file__).parent / "data" / "libcamera-tuning"
BUNDLED = sorted(BUNDLED_TUNING_DIR.glob("*/*.json"))
#: Raspberry Pi's two stock files with a trailing comma, which libcamera's YAML parser takes and JSON refuses.
TRAILING_COMMAS = ("pisp/imx283.json", "vc4/ov64a40.json")
#: Every colour sensor of the registry with a stock tuning file of its own.
STOCK_SENSORS = [name for name, s in SENSORS.items() if not s.monochrome and "" in stock_tuning_files(name)]


@pytest.fixture
def cli(monkeypatch, capfd):
    """``picamcal ARGS`` in this process: (exit status, stdout, stderr); main's global settings are put back."""
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)
    monkeypatch.setattr(logging.getLogger("tifffile"), "level", logging.getLogger("tifffile").level)

    def run(*args: str) -> tuple[int, str, str]:
        capfd.readouterr()
        with pytest.raises(SystemExit) as exit_:
            main([str(a) for a in args])
        out, err = capfd.readouterr()
        return exit_.value.code, out, err

    return run


def one_error(result: tuple[int, str, str], *fragments: str) -> str:
    """The one error line of a refused command (exit 2), checked to hold every fragment."""
    code, out, err = result
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("picamcal: error: "), (code, out, err)
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def small_calibration(sensor: str, folder: Path, size=(320, 240)) -> Path:
    """A noiseless calibration of the simulated ``sensor`` at ``size``, saved as ``folder/<sensor>.npz``."""
    refs = simulate_references(make_camera(sensor, size=size), seed=1, noise=False)
    path = folder / f"{sensor}.npz"
    calibrate(**refs).save(path)
    return path


@pytest.fixture(scope="module")
def imx219(tmp_path_factory) -> dict:
    """A small IMX219 calibration with its white, and the same calibration without its sensor."""
    folder = tmp_path_factory.mktemp("imx219")
    refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1, noise=False)
    cal = calibrate(**refs)
    cal.save(folder / "cal.npz")
    anonymous = dataclasses.replace(cal, sensor=None)
    anonymous.save(folder / "anonymous.npz")
    from picamcal import write_dng

    write_dng(folder / "white.dng", refs["white"])
    return {"folder": folder, "cal": folder / "cal.npz", "anonymous": folder / "anonymous.npz", "refs": refs}


# --------------------------------------------------------------------------------------------- the stock files
def test_every_stock_file_ships_unchanged_with_its_licence():
    """The bundled folder is Raspberry Pi's, byte for byte: the checksums of libcamera's files at the commit its
    README names (taken from the copy the files came from), and the tests' own copies are the same bytes."""
    sums = dict(line.split("  ")[::-1] for line in (DATA / "SHA256SUMS").read_text().splitlines())
    shipped = {str(p.relative_to(BUNDLED_TUNING_DIR)) for p in BUNDLED} | {"LICENSE", "README.md"}
    assert shipped == set(sums)
    for name, digest in sums.items():
        assert hashlib.sha256((BUNDLED_TUNING_DIR / name).read_bytes()).hexdigest() == digest, name
    assert [len(list((BUNDLED_TUNING_DIR / d).glob("*.json"))) for d in ("vc4", "pisp")] == [33, 34]
    assert "Redistribution" in (BUNDLED_TUNING_DIR / "LICENSE").read_text()
    for copy in DATA.glob("*/*.json"):
        assert copy.read_bytes() == (BUNDLED_TUNING_DIR / copy.parent.name / copy.name).read_bytes()


@pytest.mark.parametrize("name", TRAILING_COMMAS)
def test_the_stock_files_with_trailing_commas_load(name):
    path = BUNDLED_TUNING_DIR / name
    with pytest.raises(ValueError, match="Expecting property name"):
        json.loads(path.read_text())  # what JSON refuses
    tuning = load_tuning(path)
    assert tuning["target"] == ("pisp" if name.startswith("pisp") else "bcm2835")
    assert len(tuning["algorithms"]) > 10 and check_tuning(tuning, path) == tuning["target"]
    linear, encoded = tuning_gamma_curve(path)
    assert linear[0] == 0 and linear[-1] == 1 and np.all(np.diff(encoded) >= 0)


@pytest.mark.slow
@pytest.mark.parametrize("path", BUNDLED, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_stock_file_loads_as_json_would_read_it(path):
    """libcamera's parser and JSON agree on every stock file JSON reads: the same values of the same types."""
    tuning = load_tuning(path)
    if f"{path.parent.name}/{path.name}" not in TRAILING_COMMAS:
        strict = json.loads(path.read_text())
        assert tuning == strict and json.dumps(tuning) == json.dumps(strict)


@pytest.mark.slow
def test_a_calibration_exports_into_every_stock_file_and_what_is_written_loads_back(imx219, tmp_path):
    """Any stock file as a base (--base, or a variant's): the export keeps its algorithms, is written, and loads back
    through the same reader with libcamera's rules."""
    cal = calibrate(**imx219["refs"])
    for path in BUNDLED:
        base = load_tuning(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PicamcalWarning)  # the files without rpi.alsc get one, with a warning
            tuning = export_tuning(cal, base, base_path=path)
        saved = tmp_path / f"{path.parent.name}_{path.name}"
        save_tuning(saved, tuning)
        again = load_tuning(saved)
        assert again == tuning and check_tuning(again, saved) == base["target"], path
        kept = [a for a in base["algorithms"] if "rpi.alsc" not in a]
        assert [a for a in again["algorithms"] if "rpi.alsc" not in a] == kept, path


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        ('{"version": 2.0,\n "target": "pisp"\n "algorithms": []}', 3, "did not find expected ',' or '}'"),
        ('{"version": 2.0,\n "target": "pisp",\n "target": "vc4", "algorithms": []}', 3, "appears twice"),
        ('{"version": 2.0, "target": &t "pisp",\n "algorithms": [*t]}', 2, "an alias (*t)"),
        ('{"version": 2.0, "target": "pisp",\n ["a"]: 1, "algorithms": []}', 2, "a key that is a list or a mapping"),
        ('{"version": 2.0, "target": "pisp", "algorithms": [\n' + "{},\n" * 2000 + "]}", 2001, "more than 1999"),
    ],
    ids=["syntax", "duplicate key", "alias", "list as key", "2000 items"],
)
def test_what_libcamera_refuses_is_refused_with_the_file_the_reason_and_the_line(tmp_path, text, line, message):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(TuningError) as caught:
        load_tuning(path)
    assert str(caught.value).startswith(f"{path}: not a libcamera tuning file: ")
    assert message in str(caught.value) and f"line {line}" in str(caught.value)


def test_what_libcamera_takes_and_json_does_not_is_taken(tmp_path):
    """Comments, tabs, a trailing comma, YAML's own layout, quoted numbers: libcamera reads every value as text."""
    path = tmp_path / "yaml.json"
    path.write_text(
        "# a comment\nversion: 2.0\ntarget: 'pisp'\nalgorithms:\n  - rpi.black_level: {black_level: \"4096\",\n\t}\n"
    )
    tuning = load_tuning(path)
    assert tuning == {"version": 2.0, "target": "pisp", "algorithms": [{"rpi.black_level": {"black_level": 4096}}]}
    for text, problem in (("", "the file is empty"), ('{"version": 2.0}\n---\n{}', "more than one YAML document")):
        path.write_text(text)
        with pytest.raises(TuningError, match=problem):
            load_tuning(path)


def test_without_libyaml_the_python_parser_reads_the_stock_files_the_same(monkeypatch):
    """PyYAML without its C parser (a build without libyaml) falls back to its pure-Python one, which refuses the
    tabs libyaml takes: the values must still be libyaml's, the errors still name the line."""
    import yaml

    files = [BUNDLED_TUNING_DIR / name for name in (*TRAILING_COMMAS, "pisp/imx708.json")]
    assert b"\t" in files[-1].read_bytes()  # a tab before a closing brace, as 15 stock files have
    with_libyaml = [load_tuning(path) for path in files]
    monkeypatch.delattr(yaml, "CSafeLoader")
    assert [load_tuning(path) for path in files] == with_libyaml
    with pytest.raises(TuningError, match=r"expected ',' or '}'.* at line 2"):
        parse_libcamera_yaml(b'{"a": 1\n "b": 2}', TuningError, "a libcamera tuning file")


def test_two_sections_of_one_algorithm_are_refused_as_libcamera_refuses_them():
    stock = load_tuning(stock_tuning_path("imx219", "pisp"))
    black = next(a for a in stock["algorithms"] if "rpi.black_level" in a)
    with pytest.raises(TuningError, match=r"rpi\.black_level appears twice"):
        check_tuning({**stock, "algorithms": [*stock["algorithms"], black]})


# ------------------------------------------------------------------------------ export-tuning without --base
@pytest.mark.parametrize("sensor", STOCK_SENSORS)
def test_every_sensor_with_a_stock_file_exports_without_a_base(sensor, tmp_path, cli):
    cal = small_calibration(sensor, tmp_path, size=(160, 120))
    code, out, err = cli("export-tuning", cal, "--out", tmp_path / "tuning")
    assert code == 0, err
    targets = sorted(stock_tuning_files(sensor)[""])
    written = sorted((tmp_path / "tuning").iterdir())
    labels = {"bcm2835": "vc4", "pisp": "pisp"}
    assert [p.name for p in written] == sorted(f"{sensor}_{labels[t]}.json" for t in targets)
    for path in written:
        tuning = load_tuning(path)
        stock = load_tuning(stock_tuning_path(sensor, tuning["target"]))
        alsc = next(a["rpi.alsc"] for a in tuning["algorithms"] if "rpi.alsc" in a)
        assert alsc["n_iter"] == 0 and tuning["version"] == stock["version"]
        assert [a for a in tuning["algorithms"] if "rpi.alsc" not in a] == [
            a for a in stock["algorithms"] if "rpi.alsc" not in a
        ]
        red, blue = tuning["picamcal"]["colour_gains"]
        assert f"--awbgains {red:g},{blue:g}" in err + out
    if len(targets) == 1:  # only one platform has a file: said in one line
        assert f"ships no {'pisp' if targets == ['bcm2835'] else 'vc4'} tuning file for the {sensor}" in err + out


def test_sensors_without_a_stock_file_start_from_libcamera_s_generic_file(tmp_path, cli):
    outside = [name for name, s in SENSORS.items() if not s.monochrome and not stock_tuning_files(name)]
    assert outside  # the registry holds sensors Raspberry Pi ships no tuning for (third-party modules)
    cal = small_calibration(outside[0], tmp_path, size=(160, 120))
    code, out, err = cli("export-tuning", cal, "--out", tmp_path / "t")
    assert code == 0, err
    assert f"no tuning file for the {outside[0]}: started from libcamera's uncalibrated.json" in out + err
    sensor = SENSORS[outside[0]]
    for target in ("vc4", "pisp"):
        exported = load_tuning(tmp_path / "t" / f"{outside[0]}_{target}.json")
        black = next(a["rpi.black_level"] for a in exported["algorithms"] if "rpi.black_level" in a)
        assert black["black_level"] == sensor.black_level << (16 - sensor.bit_depth)  # the sensor's, not 4096


def test_variants_are_chosen_by_name_and_a_missing_one_lists_the_sensors(tmp_path, cli):
    cal = small_calibration("imx708", tmp_path, size=(320, 180))
    code, _, err = cli("export-tuning", cal, "--out", tmp_path / "wide", "--variant", "wide")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "wide").iterdir()) == ["imx708_wide_pisp.json", "imx708_wide_vc4.json"]
    for target in ("vc4", "pisp"):
        exported = load_tuning(tmp_path / "wide" / f"imx708_wide_{target}.json")
        stock = load_tuning(BUNDLED_TUNING_DIR / target / "imx708_wide.json")
        assert exported["algorithms"][0] == stock["algorithms"][0]
        assert next(a for a in exported["algorithms"] if "rpi.awb" in a) == next(
            a for a in stock["algorithms"] if "rpi.awb" in a
        )  # the wide module's own white balance, not the standard one's
    code, _, err = cli("export-tuning", cal, "--out", tmp_path / "sensor-wide", "--sensor", "imx708_wide_noir")
    assert code == 0, err  # --sensor names the variant
    assert (tmp_path / "sensor-wide" / "imx708_wide_noir_pisp.json").exists()
    one_error(
        cli("export-tuning", cal, "--out", tmp_path / "x", "--variant", "mono"),
        "the imx708 has no stock tuning variant 'mono'; its variants: noir, wide, wide_noir",
    )
    cal296 = small_calibration("imx296", tmp_path, size=(320, 240))
    code, out, err = cli("export-tuning", cal296, "--out", tmp_path / "16mm", "--variant", "16mm")
    assert code == 0, err
    assert [p.name for p in (tmp_path / "16mm").iterdir()] == ["imx296_16mm_pisp.json"]
    assert "ships no vc4 tuning file for the imx296_16mm: wrote the pisp one only" in err + out
    one_error(
        cli("export-tuning", cal296, "--out", tmp_path / "m", "--variant", "mono"),
        "imx296_mono.json is for the imx296_mono, another sensor",
        "its variants: 6mm (pisp only), 16mm (pisp only)",
    )
    one_error(
        cli("export-tuning", cal296, "--out", tmp_path / "v", "--variant", "16mm", "--target", "vc4"),
        "ships no vc4 tuning file for the imx296_16mm, only a pisp one",
    )
    assert not any((tmp_path / name).exists() for name in ("x", "m", "v"))


def test_sensor_option_on_a_calibration_that_does_not_say_its_sensor(imx219, tmp_path, cli):
    anonymous = imx219["anonymous"]
    one_error(cli("export-tuning", anonymous, "--out", tmp_path / "a"), "does not say its sensor", "--sensor")
    one_error(cli("export-tuning", anonymous, "--out", tmp_path / "b", "--sensor", "imx2l9"), "did you mean imx219?")
    code, _, err = cli("export-tuning", anonymous, "--out", tmp_path / "c", "--sensor", "IMX219")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "c").iterdir()) == ["imx219_pisp.json", "imx219_vc4.json"]
    one_error(
        cli("export-tuning", imx219["cal"], "--out", tmp_path / "d", "--sensor", "imx477"),
        "cal.npz: the calibration is for the imx219, not the imx477 --sensor names",
    )
    assert not any((tmp_path / name).exists() for name in ("a", "b", "d"))


def test_errors_name_their_file(imx219, tmp_path, cli):
    other = tmp_path / "imx477.json"
    other.write_bytes(stock_tuning_path("imx219", "bcm2835").read_bytes())
    one_error(
        cli("export-tuning", imx219["cal"], "--base", other, "--out", tmp_path / "o.json"),
        f"{other}: the calibration is for the imx219, the base tuning file for the imx477",
    )
    # A white falling to 5 % of its centre in the corners needs gains near 20: above what a Pi 4 can apply (16).
    refs = dict(imx219["refs"])
    white = refs["white"]
    y, x = np.mgrid[0 : white.height, 0 : white.width]
    falloff = 1 - 0.95 * (((x - white.width / 2) / white.width) ** 2 + ((y - white.height / 2) / white.height) ** 2) * 2
    level = white.black_level[0]
    bayer = np.round((white.bayer.astype(float) - level) * falloff + level).astype(np.uint16)
    refs["white"] = RawImage(bayer, white.pattern, white.black_level, white.white_level, white.bit_depth, white.sensor)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PicamcalWarning)
        calibrate(**refs).save(tmp_path / "dark.npz")
    one_error(
        cli("export-tuning", tmp_path / "dark.npz", "--target", "vc4", "--out", tmp_path / "o.json"),
        f"{tmp_path / 'dark.npz'}: the lens shading table needs gains up to",
        "above the bcm2835 hardware limit of 16",
        "--clip-gains",
    )
    assert not (tmp_path / "o.json").exists()


def test_an_image_given_for_the_calibration_says_what_each_command_needs(imx219, tmp_path, cli):
    white = imx219["folder"] / "white.dng"
    for command in (["export-tuning", white, "--out", tmp_path / "t"], ["export-lst", white, "--out", tmp_path / "l"]):
        one_error(
            cli(*command),
            "white.dng: this is a raw image, not a calibration: make one from the reference images with picamcal "
            "calibrate",
        )
    # correct takes a calibration and images: there the likely slip is their order.
    one_error(
        cli("correct", white, imx219["cal"], "--out", tmp_path / "c"),
        "white.dng: this is a raw image, not a calibration (the calibration comes first: picamcal correct",
    )
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------- colour gains
def test_each_exported_file_records_the_gains_that_make_the_white_neutral_and_apply_tuning_uses_them(
    imx219, tmp_path, cli
):
    """The vc4 and pisp files of one calibration leave different casts with gains 1,1 (their colour tables are
    normalised differently); each records its own gains, and apply-tuning, using them, makes the white neutral in
    both."""
    code, _, err = cli("export-tuning", imx219["cal"], "--out", tmp_path / "t")
    assert code == 0, err
    white = imx219["folder"] / "white.dng"
    balances, gains = {}, {}
    for target in ("vc4", "pisp"):
        path = tmp_path / "t" / f"imx219_{target}.json"
        record = json.loads(path.read_text())["picamcal"]
        assert record["calibration"] == "cal.npz" and "--awbgains" in record["colour_gains_use"]
        gains[target] = np.array(record["colour_gains"])
        unbalanced = apply_tuning(imx219["refs"]["white"], load_tuning(path), colour_gains=(1.0, 1.0))
        mean = unbalanced.reshape(-1, 3).mean(axis=0)
        # The gains are the white's green / red and green / blue through this file (rounded to 4 decimals).
        np.testing.assert_allclose(gains[target], [mean[1] / mean[0], mean[1] / mean[2]], rtol=2e-3)
        code, out, err = cli("apply-tuning", path, white, "--out", tmp_path / f"{target}.tiff")
        assert code == 0, err
        assert f"colour gains {gains[target][0]:g},{gains[target][1]:g}" in out + err
        rgb = tifffile.imread(tmp_path / f"{target}.tiff").reshape(-1, 3).mean(axis=0)
        balances[target] = (rgb[0] / rgb[1], rgb[2] / rgb[1], mean[0] / mean[1])
    # Neutral within 0.3 %: the ISP's gains in fixed point (1/1024 on vc4, 10-bit codes on pisp, 0.1 %), the
    # recorded gains' 4 decimals and the demosaiced edges; measured within 0.01 %.
    for red, blue, _ in balances.values():
        assert red == pytest.approx(1, abs=3e-3) and blue == pytest.approx(1, abs=3e-3)
    # With gains 1,1 the white is far from neutral (the simulated camera's red is 0.80 of its green) ...
    assert all(abs(balances[target][2] - 1) > 0.1 for target in balances)
    # ... and each file needs its own gains: the vc4 file's differ from the pisp file's by more than that tolerance
    # (measured: red 1.2528 and 1.2420, 0.9 % apart), so one set for both would leave one of the whites tinted.
    assert np.abs(gains["vc4"] / gains["pisp"] - 1).max() > 3e-3
    vc4 = tmp_path / "t" / "imx219_vc4.json"
    code, _, err = cli("apply-tuning", vc4, white, "--out", tmp_path / "ones.tiff", "--colour-gains", "1,1")
    assert code == 0, err
    ones = tifffile.imread(tmp_path / "ones.tiff").reshape(-1, 3).mean(axis=0)
    assert ones[0] / ones[1] == pytest.approx(balances["vc4"][2], rel=1e-4)  # an explicit option overrides


def test_a_bad_colour_gains_record_is_refused(imx219, tmp_path):
    tuning = export_tuning(
        calibrate(**imx219["refs"]), load_tuning(stock_tuning_path("imx219", "pisp")), base_path="imx219.json"
    )
    tuning["picamcal"]["colour_gains"] = [1.2, -1]
    with pytest.raises(TuningError, match=r"picamcal\.colour_gains\[1\] must be a positive number, not -1"):
        check_tuning(tuning, "t.json")


# --------------------------------------------------------------------------------------- apply-tuning's output
def test_apply_tuning_writes_the_format_its_out_names(imx219, tmp_path, cli):
    import png
    from PIL import Image

    tuning = stock_tuning_path("imx219", "pisp")
    white = imx219["folder"] / "white.dng"
    for name, kind in (("isp.png", "PNG"), ("isp.jpg", "JPEG"), ("isp.JPEG", "JPEG")):
        code, _, err = cli("apply-tuning", tuning, white, "--out", tmp_path / name)
        assert code == 0, err
        with Image.open(tmp_path / name) as image:
            assert image.format == kind and image.size == (320, 240)
    width, height, _, info = png.Reader(filename=str(tmp_path / "isp.png")).read()
    assert (width, height, info["bitdepth"], info["planes"]) == (320, 240, 16, 3)
    code, _, err = cli("apply-tuning", tuning, white, "--out", tmp_path / "isp.tif")
    assert code == 0, err
    assert tifffile.imread(tmp_path / "isp.tif").dtype == np.float32
    for name in ("isp.bmp", "isp.dng", "isp"):
        one_error(cli("apply-tuning", tuning, white, "--out", tmp_path / name), "--out", "writes .tiff")
        assert not (tmp_path / name).exists()


# ------------------------------------------------------------------------------ the camera's own tuning, on a Pi
def test_a_stock_path_error_is_a_picamcal_error():
    with pytest.raises(PicamcalError, match="no stock tuning variant 'tele'"):
        stock_tuning_path("imx219", "pisp", "tele")
