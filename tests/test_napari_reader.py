"""The napari plugin's reader, writers and sample data (issue 32, items 1, 3 and 4), and its npe2 manifest.

Every raw format opens through the reader with the mosaic EQUAL to ``read_raw``'s and the RGB equal to the library's
linear RGB; a calibration opens as its maps; a folder as a stack. What is not picamcal's is declined quietly; what is
but is bad shows the command line's one line in napari's notification area and opens nothing; the writers write what
``picamcal correct`` writes, and refuse what the command line refuses. The files are made with picamcal's own writers
and simulator. Only two tests start Qt (napari's viewer, the dialog), on a virtual X display (Xvfb).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import tifffile

pytest.importorskip("napari")

import picamcal
from picamcal import PicamcalError, read_raw
from picamcal.napari import _dialog, _layers, _reader, _sample, _writer
from picamcal.raw import to_picamera2, write_brcm, write_dng, write_npz, write_picamera2_npy
from picamcal.raw.packing import pack
from picamcal.simulate import make_camera, render, simulate_run

SIZE = (320, 240)
NOTHING = [(None,)]


# Fixtures ----------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """One frame in each raw format picamcal reads (and a simulated run, and its calibrations), made by picamcal."""
    folder = tmp_path_factory.mktemp("formats")
    run = simulate_run(folder / "run", "imx219", size=SIZE, seed=3)
    white = read_raw(run["white"])
    legacy = render(make_camera("imx219", size=(640, 480)), "white", rng=4)  # a legacy JPEG+raw mode's size
    anonymous = picamcal.RawImage(white.bayer, white.pattern, white.black_level, white.white_level, 10)
    array, config, metadata = to_picamera2(white)
    paths = {
        "dng": write_dng(folder / "white.dng", white),
        "dng without a sensor": write_dng(folder / "anonymous.dng", anonymous),  # as picamera2's early DNGs
        "brcm": write_brcm(folder / "legacy.jpg", legacy),
        "npy": write_picamera2_npy(folder / "buffer.npy", array, config, metadata, sensor="imx219"),
        "npz": write_npz(folder / "frame.npz", white),
        "npz of a registry size": write_npz(
            folder / "vga.npz", picamcal.RawImage(legacy.bayer, legacy.pattern, legacy.black_level, 1023, 10)
        ),
    }
    headless = folder / "dump.raw"
    headless.write_bytes(pack(white.bayer, 10, 416).tobytes())  # rpicam-raw's bytes: 320 10-bit pixels in 416
    paths["headless"] = headless
    calibrate = picamcal.calibrate
    refs = {role: read_raw(run[role]) for role in ("white", "red", "green", "blue", "black")}
    paths["calibration"] = calibrate(**refs).save(folder / "cal.npz")
    paths["flat calibration"] = calibrate(refs["white"]).save(folder / "flat.npz")
    return {**paths, **{f"run {name}": path for name, path in run.items()}, "run": folder / "run"}


@pytest.fixture
def notes(monkeypatch):
    """What the plugin shows in napari's notification area during the test: (severity, message). Recorded where it
    calls napari (``_reader.show``), so that what other code notifies (napari's own hooks on Python's warnings, once
    a viewer has installed them) is not mixed in; the test of the viewer checks napari receives it."""
    received: list[tuple[str, str]] = []
    real = _reader.show

    def show(kind: str, message: str) -> None:
        received.append((kind, message))
        real(kind, message)

    monkeypatch.setattr(_reader, "show", show)
    return received


HEADLESS_ANSWERS = {"raw_format": "SBGGR10_CSI2P", "size": "320x240", "sensor": "imx219"}


@pytest.fixture
def answers(monkeypatch):
    """The dialog replaced by answers given at once (as a user would type them); the requests it got are kept."""
    asked: list[_dialog.Request] = []
    given: dict[str, dict[str, str] | None] = {_dialog.HEADLESS: HEADLESS_ANSWERS, _dialog.BLACK_LEVEL: None}

    def ask(request: _dialog.Request):
        asked.append(request)
        typed = given[request.need]
        return None if typed is None else _dialog.parse_answers(typed, request.need)

    monkeypatch.setattr(_dialog, "ask_read_options", ask)
    return given, asked


def open_layers(path) -> list:
    reader = _reader.get_reader(str(path))
    assert reader is not None, path
    return reader(str(path))


# Reading -------------------------------------------------------------------------------------------------------------

FORMATS = ["dng", "dng without a sensor", "brcm", "npy", "npz", "headless"]


@pytest.mark.parametrize("fmt", FORMATS)
def test_each_format_opens_as_its_linear_rgb_and_its_mosaic(files, answers, notes, fmt):
    path = files[fmt]
    layers = open_layers(path)
    options = _dialog.parse_answers(HEADLESS_ANSWERS) if fmt == "headless" else {}
    raw = read_raw(path, **options)
    assert [kind for _, _, kind in layers] == ["image", "image"]
    (rgb, rgb_kwargs, _), (mosaic, raw_kwargs, _) = layers
    np.testing.assert_array_equal(mosaic, raw.bayer)  # the mosaic as read_raw gives it, uint16
    assert mosaic.dtype == np.uint16
    np.testing.assert_array_equal(rgb, _layers.linear_rgb(raw))  # the library's linear RGB, bit for bit
    assert rgb_kwargs["rgb"] and rgb_kwargs["name"] == path.stem and rgb_kwargs["visible"]
    assert raw_kwargs["name"] == f"{path.stem} (raw)" and raw_kwargs["colormap"] == "gray" and not raw_kwargs["visible"]
    record = rgb_kwargs["metadata"]["picamcal"]
    assert record["path"] == str(path) and record["pattern"] == raw.pattern and record["kind"] == "linear rgb"
    assert record["black_level"] == list(raw.black_level) and record["white_level"] == raw.white_level
    assert record["bit_depth"] == raw.bit_depth and record["raw"].bayer is mosaic
    assert raw_kwargs["metadata"]["picamcal"]["kind"] == "raw mosaic"
    given = {"raw_format": "SBGGR10_CSI2P", "size": [320, 240], "sensor": "imx219"}
    assert record["read_options"] == (given if fmt == "headless" else {})
    if raw.sensor == "imx219":  # the physical pixel size: the IMX219's 1.12 um pitch, times the mode's binning
        assert record["sensor"] == "imx219" and record["geometry"] is not None
        pitch = 1.12 * record["geometry"]["binning"]
        assert rgb_kwargs["scale"] == raw_kwargs["scale"] == (pytest.approx(pitch), pytest.approx(pitch))
        assert rgb_kwargs["units"] == ("micrometer", "micrometer")
    else:
        assert "scale" not in rgb_kwargs and record["pixel_size_um"] is None
    for key in ("exposure_time_s", "analogue_gain", "iso"):
        if key in raw.metadata:
            assert record[key] == pytest.approx(raw.metadata[key])
    assert [severity for severity, _ in notes] == []  # nothing to say about a good file


def test_the_linear_rgb_is_the_kernels_development_of_the_file(files):
    from picamcal.correct import demosaic
    from picamcal.kernels import correct_numpy

    raw = read_raw(files["dng"])
    fields = _layers.linear_fields(raw)
    rgb = _layers.linear_rgb(raw)
    # The C kernel and numpy's pass are one float32 arithmetic: equal, or an ulp apart where a compiler rounds one
    # operation differently (picamcal.kernels); the values are below 2, where an ulp is 1.2e-7.
    np.testing.assert_allclose(rgb, correct_numpy(raw.bayer, fields), rtol=0, atol=2.5e-7)
    # What it computes, written out: each site black-subtracted, times its channel's white balance over its range
    # from black to white, then colour-demosaicing's Malvar (float64 convolutions: the last bits differ).
    (red, blue), source = _layers.white_balance(raw)
    assert (red, blue) == tuple(raw.metadata["colour_gains"]) and source == "the file's colour gains"
    balance = np.array([red, 1.0, blue])[picamcal.raw.site_channels(raw.pattern)]
    mosaic = raw.black_subtracted()
    for site in range(4):
        mosaic[site // 2 :: 2, site % 2 :: 2] *= np.float32(balance[site] / (raw.white_level - raw.black_level[site]))
    np.testing.assert_allclose(rgb, demosaic(mosaic, raw.pattern), rtol=0, atol=1e-5)
    # The white balance (frozen on the white's central half, picamcal.bayer.central_half) makes the white grey there.
    rows, cols = picamcal.bayer.central_half(raw.height, raw.width)
    centre = rgb[rows, cols].mean(axis=(0, 1))
    assert np.ptp(centre) < 0.01 * centre.mean()


def test_a_dngs_as_shot_neutral_is_its_white_balance():
    raw = picamcal.RawImage(np.zeros((4, 4), np.uint16), "BGGR", 64, 1023, 10, None, {"as_shot_neutral": [0.5, 1, 0.8]})
    assert _layers.white_balance(raw) == ((2.0, 1.25), "the DNG's AsShotNeutral")
    assert _layers.linear_fields(raw).site_gains.tolist() == pytest.approx([1.25 / 959, 1 / 959, 1 / 959, 2.0 / 959])


def test_the_warnings_reading_gives_are_in_the_metadata_and_the_notification_area(files, notes):
    with pytest.warns(picamcal.PicamcalWarning) as caught:
        read_raw(files["npz of a registry size"])
    said = [str(w.message) for w in caught]
    layers = open_layers(files["npz of a registry size"])
    assert layers[0][1]["metadata"]["picamcal"]["warnings"] == said
    record = layers[0][1]["metadata"]["picamcal"]
    assert record["sensor"] is None and record["sensor_candidates"] == ["ov5647", "imx219"]  # 640x480: either
    assert notes == [("warning", text) for text in said]


def test_a_dump_of_an_unknown_sensor_asks_for_its_black_level(files, answers, notes):
    given, asked = answers
    given[_dialog.HEADLESS] = {"raw_format": "SBGGR10_CSI2P", "size": "320x240"}  # no sensor: no black level
    given[_dialog.BLACK_LEVEL] = {"black_level": "64"}
    layers = open_layers(files["headless"])
    assert [request.need for request in asked] == [_dialog.HEADLESS, _dialog.BLACK_LEVEL]
    with pytest.raises(PicamcalError) as missing:
        picamcal.raw.model.require_black_level(read_raw(files["headless"], raw_format="SBGGR10_CSI2P", size=SIZE))
    assert asked[1].reason == f"{files['headless'].name}: {missing.value.problem}" and asked[1].required
    raw = read_raw(files["headless"], raw_format="SBGGR10_CSI2P", size=SIZE, black_level=64)
    np.testing.assert_array_equal(layers[0][0], _layers.linear_rgb(raw))
    np.testing.assert_array_equal(layers[1][0], raw.bayer)
    assert layers[0][1]["metadata"]["picamcal"]["read_options"]["black_level"] == [64.0]
    # Cancelled: nothing opens, and nothing is said.
    given[_dialog.BLACK_LEVEL] = None
    notes.clear()
    assert open_layers(files["headless"]) == NOTHING and notes == []
    given[_dialog.HEADLESS] = None
    assert open_layers(files["headless"]) == NOTHING and notes == []


def test_a_headless_dump_is_offered_what_its_size_suggests(tmp_path):
    from picamcal.raw.picamera2.formats import parse_raw_format

    row = -(-parse_raw_format("SRGGB10_CSI2P").row_bytes(3280) // 32) * 32
    (tmp_path / "video.raw").write_bytes(bytes(row * 2464 * 2))  # two IMX219 full frames
    assert _dialog.headless_defaults(tmp_path / "video.raw") == {
        "raw_format": "SBGGR10_CSI2P",
        "size": "3280x2464",
        "sensor": "imx219",
    }


def test_a_calibration_opens_as_its_maps(files, notes):
    cal = picamcal.load_calibration(files["calibration"])
    layers = open_layers(files["calibration"])
    names = [kwargs["name"] for _, kwargs, _ in layers]
    elements = [f"cal unmixing U[{p},{q}]" for p in "RGB" for q in "RGB"]
    assert names == [f"cal flat-field gain {c}" for c in "RGB"] + elements + ["cal noise penalty"]
    by_name = {kwargs["name"]: (data, kwargs) for data, kwargs, _ in layers}
    for c, channel in enumerate("RGB"):
        data, kwargs = by_name[f"cal flat-field gain {channel}"]
        np.testing.assert_array_equal(data, cal.lens_shading[..., c])
        assert kwargs["colormap"] == "viridis" and kwargs["contrast_limits"] == (1.0, float(cal.lens_shading.max()))
    reach = float(np.abs(cal.unmixing[..., ~np.eye(3, dtype=bool)]).max())
    for p, out in enumerate("RGB"):
        for q, inp in enumerate("RGB"):
            data, kwargs = by_name[f"cal unmixing U[{out},{inp}]"]
            np.testing.assert_array_equal(data, cal.unmixing[..., p, q])
            if p != q:  # diverging, centred on zero
                assert kwargs["colormap"] == "PiYG" and kwargs["contrast_limits"] == (-reach, reach)
    data, kwargs = by_name["cal noise penalty"]
    np.testing.assert_array_equal(data, cal.noise_penalty("centre").max(axis=-1))
    assert kwargs["colormap"] == "inferno" and kwargs["contrast_limits"] == (1.0, float(data.max()))
    assert kwargs["visible"] and not any(k["visible"] for _, k, _ in layers[:-1])
    # On the bins, placed over the image: 16 pixels of 1.12 um each, the first bin's centre at pixel 7.5.
    assert kwargs["scale"] == pytest.approx((17.92, 17.92)) and kwargs["translate"] == pytest.approx((8.4, 8.4))
    assert kwargs["metadata"]["picamcal"]["calibration"].kind == "full" and notes == []


def test_a_flat_calibration_has_its_flat_field_only_and_says_so(files, notes):
    layers = open_layers(files["flat calibration"])
    assert [kwargs["name"] for _, kwargs, _ in layers] == [f"flat flat-field gain {c}" for c in "RGB"]
    assert "no unmixing" in layers[0][1]["metadata"]["picamcal"]["note"]
    said = f"{files['flat calibration']}: a flat-field calibration (a white alone): its flat field only, no unmixing"
    assert notes == [("info", said)]


def test_a_folder_opens_as_a_stack_and_so_do_files_opened_together(files):
    frames = sorted(files["run"].glob("*.dng"))  # black, blue, green, red, target, white: one size
    layers = open_layers(files["run"])
    (rgb, kwargs, _), (mosaics, raw_kwargs, _) = layers
    assert rgb.shape == (len(frames), 240, 320, 3) and mosaics.shape == (len(frames), 240, 320)
    assert kwargs["name"] == "run" and raw_kwargs["name"] == "run (raw)"
    assert kwargs["metadata"]["picamcal"]["paths"] == [str(p) for p in frames]
    for k, frame in enumerate(frames):
        raw = read_raw(frame)
        np.testing.assert_array_equal(mosaics[k], raw.bayer)
        np.testing.assert_array_equal(rgb[k], _layers.linear_rgb(raw))
    assert kwargs["scale"] == pytest.approx((1.0, 1.12, 1.12))
    chosen = [str(files["run white"]), str(files["run red"])]
    reader = _reader.get_reader(chosen)  # napari's "open as stack"
    assert reader is not None
    (rgb, kwargs, _), _ = reader(chosen)
    assert rgb.shape == (2, 240, 320, 3) and kwargs["metadata"]["picamcal"]["paths"] == chosen


def test_frames_of_different_sizes_are_refused_naming_the_first_odd_one(files, tmp_path, notes):
    folder = tmp_path / "mixed"
    folder.mkdir()
    for name in ("a.dng", "b.dng"):
        shutil.copy(files["dng"], folder / name)
    write_dng(folder / "c.jpg.dng", read_raw(files["brcm"]))  # 640 x 480
    shutil.copy(files["dng"], folder / "d.dng")
    assert open_layers(folder) == NOTHING
    assert notes == [("error", f"{folder / 'c.jpg.dng'}: is 640x480, the stack's frames are 320x240")]


def test_files_that_are_not_picamcals_are_declined_quietly(files, tmp_path, notes):
    from PIL import Image

    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "photo.png")
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "photo.jpg")  # a JPEG with no raw block
    (tmp_path / "notes.txt").write_text("focus at 3 mm")
    (tmp_path / "notes.dng").write_text("focus at 3 mm")  # a name is not a format
    tifffile.imwrite(tmp_path / "image.tif", np.zeros((8, 8), np.uint16))  # a TIFF, not a DNG
    np.savez(tmp_path / "other.npz", a=np.eye(3))  # another program's archive
    np.save(tmp_path / "array.npy", np.eye(3))  # no picamera2 sidecar beside it
    (tmp_path / "empty.dng").write_bytes(b"")
    (tmp_path / "folder").mkdir()
    (tmp_path / "folder" / "notes.txt").write_text("no frames here")
    paths = [p for p in tmp_path.iterdir() if p.name != "folder"] + [tmp_path / "folder"]
    assert {p.name: _reader.get_reader(str(p)) for p in paths} == {p.name: None for p in paths}
    assert _reader.get_reader([str(tmp_path / "photo.png"), str(files["dng"])]) is None
    assert notes == []


def truncated(source: Path, path: Path, keep: float = 0.5) -> Path:
    data = source.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    return path


def forged_npz(source: Path, path: Path) -> Path:
    """picamcal's raw .npz with its mosaic's .npy header declaring 100000 x 100000 pixels."""
    with zipfile.ZipFile(source) as archive, zipfile.ZipFile(path, "w") as forged:
        for item in archive.infolist():
            data = archive.read(item)
            if item.filename == "bayer.npy":
                data = data.replace(b"(240, 320)", b"(100000, 100000)")
            forged.writestr(item, data)
    return path


def blank_raw_header(source: Path, path: Path) -> Path:
    """A JPEG+raw file whose raw block's header, after its BRCM ident, is zeros."""
    data = bytearray(source.read_bytes())
    start = data.rfind(b"BRCM")
    data[start + 4 : start + 512] = bytes(508)  # its name, size, padding, format and Bayer order (at 0xB0) among them
    path.write_bytes(bytes(data))
    return path


def calibration_without(source: Path, path: Path, member: str) -> Path:
    with zipfile.ZipFile(source) as archive, zipfile.ZipFile(path, "w") as cut:
        for item in archive.infolist():
            if item.filename != member:
                cut.writestr(item, archive.read(item))
    return path


BAD = {
    "truncated DNG": lambda files, tmp: truncated(files["dng"], tmp / "cut.dng"),
    "JPEG+raw with a blank raw header": lambda files, tmp: blank_raw_header(files["brcm"], tmp / "blank.jpg"),
    "forged mosaic size": lambda files, tmp: forged_npz(files["npz"], tmp / "forged.npz"),
    "picamera2 buffer without its sidecar's config": lambda files, tmp: _broken_sidecar(files, tmp),
    "calibration without its white": lambda files, tmp: calibration_without(
        files["calibration"], tmp / "cal.npz", "white.npy"
    ),
}


def _broken_sidecar(files, tmp: Path) -> Path:
    shutil.copy(files["npy"], tmp / "buffer.npy")
    (tmp / "buffer.json").write_text(json.dumps({"format": picamcal.raw.picamera2.SIDECAR_FORMAT}))
    return tmp / "buffer.npy"


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_file_of_picamcals_shows_the_command_lines_line_and_opens_nothing(files, tmp_path, notes, case):
    path = BAD[case](files, tmp_path)
    reading = picamcal.load_calibration if _reader.recognise(path) == _reader.CALIBRATION else read_raw
    with pytest.raises(PicamcalError) as expected:  # what the command line prints: str(exc), one line
        reading(path)
    before = sorted(tmp_path.iterdir())
    assert open_layers(path) == NOTHING
    assert notes == [("error", str(expected.value))] and "\n" not in str(expected.value)
    assert sorted(tmp_path.iterdir()) == before  # nothing written


def test_the_notification_is_the_command_lines_own_line(files, tmp_path, notes):
    path = truncated(files["dng"], tmp_path / "cut.dng")
    result = subprocess.run(
        [
            sys.executable,
            "-c",
            "from picamcal.cli import main; main()",
            "calibrate",
            "--white",
            str(path),
            "--out",
            str(tmp_path / "cal.npz"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 2
    assert open_layers(path) == NOTHING
    assert result.stderr.strip() == f"picamcal: error: {notes[0][1]}"


# Writing ------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def corrected(files, tmp_path_factory):
    """The target corrected by the command line (uint16 TIFF, OME-Zarr) and the same as a layer."""
    out = tmp_path_factory.mktemp("cli")
    target, cal_path = files["run target"], files["calibration"]
    common = ["correct", str(cal_path), str(target), "--mode", "centre", "--workers", "0"]
    for extra in (["--out", str(out / "tiff"), "--output-format", "uint16-tiff"], ["--zarr", str(out / "t.zarr")]):
        result = subprocess.run(
            [sys.executable, "-c", "from picamcal.cli import main; main()", *common, *extra],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert result.returncode == 0, result.stderr
    rgb = picamcal.correct(read_raw(target), picamcal.load_calibration(cal_path), "centre")
    meta = {
        "name": "target (centre)",
        "rgb": True,
        "metadata": {"picamcal": {"path": str(target), "calibration": str(cal_path), "mode": "centre"}},
    }
    return out, rgb, meta


def tiff_record(path: Path) -> dict:
    with tifffile.TiffFile(path) as tif:
        return json.loads(tif.pages.first.description)["picamcal"]


@pytest.mark.slow  # the command line's outputs to compare with: two runs of picamcal correct
def test_the_tiff_writer_writes_what_the_command_line_writes(corrected, tmp_path):
    out, rgb, meta = corrected
    assert _writer.write_tiff(str(tmp_path / "t.tif"), rgb, meta) == [str(tmp_path / "t.tif")]
    cli = out / "tiff" / "target.tiff"
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "t.tif"), tifffile.imread(cli))
    ours, theirs = tiff_record(tmp_path / "t.tif"), tiff_record(cli)
    for key in ("source", "calibration", "mode", "binned", "output_format", "encoding", "scale", "picamcal_version"):
        assert ours[key] == theirs[key], key
    assert ours["layer"] == "target (centre)"
    # Again onto its own file: picamcal wrote it, so it is replaced (napari's save dialog asked first).
    assert _writer.write_tiff(str(tmp_path / "t.tif"), rgb * 0.5, meta) == [str(tmp_path / "t.tif")]


@pytest.mark.slow  # the command line's outputs to compare with: two runs of picamcal correct
def test_the_zarr_writer_writes_what_the_command_line_writes(corrected, tmp_path):
    import zarr

    out, rgb, meta = corrected
    assert _writer.write_ome_zarr(str(tmp_path / "t.zarr"), rgb, meta) == [str(tmp_path / "t.zarr")]
    ours, theirs = zarr.open_group(tmp_path / "t.zarr", mode="r"), zarr.open_group(out / "t.zarr", mode="r")
    np.testing.assert_array_equal(ours["0"][:], theirs["0"][:])
    assert ours["0"].chunks == theirs["0"].chunks and dict(ours.attrs["ome"]) == dict(theirs.attrs["ome"])
    record, cli_record = ours.attrs["picamcal"], theirs.attrs["picamcal"]
    assert record["sources"] == cli_record["sources"] and record["calibration"] == cli_record["calibration"]
    assert record["settings"]["mode"] == cli_record["settings"]["mode"] == "centre" and record["done"] == [0]
    # A stack layer: one frame each.
    stack = np.stack([rgb, rgb * 0.5])
    assert _writer.write_ome_zarr(str(tmp_path / "s.zarr"), stack, {"name": "s", "rgb": True}) == [
        str(tmp_path / "s.zarr")
    ]
    np.testing.assert_array_equal(zarr.open_array(tmp_path / "s.zarr" / "0", mode="r")[1], np.moveaxis(stack[1], -1, 0))


def test_the_writers_refuse_a_mosaic_and_a_file_picamcal_did_not_write(files, tmp_path, notes):
    (_, _, _), (mosaic, raw_kwargs, _) = open_layers(files["dng"])
    target = tmp_path / "mosaic.tif"
    assert _writer.write_tiff(str(target), mosaic, raw_kwargs) == []
    assert _writer.write_ome_zarr(str(tmp_path / "mosaic.zarr"), mosaic, raw_kwargs) == []
    line = (
        "holds a linear RGB image, {} floating point: layer 'white (raw)' is the raw mosaic of white.dng "
        "(uint16, one value per pixel)"
    )
    assert notes == [
        ("error", f"{target}: {line.format('(H, W, 3)')}"),
        ("error", f"{tmp_path / 'mosaic.zarr'}: {line.format('(H, W, 3) or (N, H, W, 3)')}"),
    ]
    theirs = tmp_path / "theirs.tif"
    tifffile.imwrite(theirs, np.zeros((4, 6, 3), np.uint16))
    before = theirs.read_bytes()
    notes.clear()
    assert _writer.write_tiff(str(theirs), np.ones((4, 6, 3), np.float32), {"name": "x", "rgb": True}) == []
    assert notes == [
        (
            "error",
            f"{theirs}: exists and is not an image picamcal wrote: picamcal replaces only what it wrote itself; "
            "choose another output",
        )
    ]
    folder = tmp_path / "theirs.zarr"
    folder.mkdir()
    (folder / "data.txt").write_text("mine")
    notes.clear()
    assert _writer.write_ome_zarr(str(folder), np.ones((4, 6, 3), np.float32), {"name": "x", "rgb": True}) == []
    assert notes == [("error", f"{folder}: exists and is not a picamcal zarr stack; choose another --zarr")]
    assert theirs.read_bytes() == before and [p.name for p in folder.iterdir()] == ["data.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["theirs.tif", "theirs.zarr"]  # nothing else written


# Sample data --------------------------------------------------------------------------------------------------------


def test_the_sample_data_is_made_once_in_the_cache_and_reused(tmp_path, monkeypatch):
    monkeypatch.setenv("PICAMCAL_CACHE_DIR", str(tmp_path / "cache"))
    layers = _sample.calibration_run()
    assert [kwargs["name"] for _, kwargs, _ in layers] == ["white", "red", "green", "blue", "black"]
    folder = Path(layers[0][1]["metadata"]["picamcal"]["path"]).parent
    assert folder.parent == tmp_path / "cache" / "napari-samples"
    assert [p.name for p in folder.parent.iterdir()] == [folder.name]  # no temporary left
    for data, kwargs, _ in layers:
        record = kwargs["metadata"]["picamcal"]
        raw = read_raw(record["path"])
        assert record["role"] == kwargs["name"] and Path(record["path"]).name == f"{kwargs['name']}.dng"
        np.testing.assert_array_equal(data, _layers.linear_rgb(raw))
        assert data.shape == (480, 640, 3) and raw.sensor == "imx219"

    def no_simulation(*args, **kwargs):
        raise AssertionError("the sample was simulated again")

    monkeypatch.setattr("picamcal.simulate.simulate_run", no_simulation)
    again = _sample.calibration_run()
    np.testing.assert_array_equal(again[0][0], layers[0][0])
    (_, kwargs, _), (mosaic, _, _) = _sample.colour_wheel()
    record = kwargs["metadata"]["picamcal"]
    assert kwargs["name"] == "colour-wheel target" and Path(record["path"]) == folder / "target.dng"
    assert record["layout"] == json.loads((folder / "layout.json").read_text())
    np.testing.assert_array_equal(mosaic, read_raw(folder / "target.dng").bayer)


def test_a_sample_cut_short_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("PICAMCAL_CACHE_DIR", str(tmp_path / "cache"))

    def cut_short(folder, *args, **kwargs):
        (Path(folder) / "white.dng").write_bytes(b"II*\x00")
        raise OSError("disk full")

    monkeypatch.setattr("picamcal.simulate.simulate_run", cut_short)
    with pytest.raises(OSError):
        _sample.calibration_run()
    assert list((tmp_path / "cache" / "napari-samples").iterdir()) == []


# npe2 and napari ----------------------------------------------------------------------------------------------------


def test_npe2_finds_the_manifest_and_it_validates(files):
    import npe2

    result = subprocess.run([sys.executable, "-m", "npe2", "validate", "picamcal"], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    manager = npe2.PluginManager.instance()
    manager.discover()
    manifest = manager.get_manifest("picamcal")
    contributions = manifest.contributions
    assert [reader.command for reader in contributions.readers] == ["picamcal.get_reader"]
    writers = sorted(writer.command for writer in contributions.writers)
    assert writers == ["picamcal.write_ome_zarr", "picamcal.write_tiff"]
    assert sorted(sample.key for sample in contributions.sample_data) == ["calibration-run", "colour-wheel"]
    assert len(contributions.widgets) == 3
    # This part's commands resolve to these functions; the reader is offered for a DNG and for a folder.
    commands = {command.id: command.python_name for command in contributions.commands}
    assert commands["picamcal.get_reader"] == "picamcal.napari._reader:get_reader"
    assert commands["picamcal.sample_colour_wheel"] == "picamcal.napari._sample:colour_wheel"
    for path in (files["dng"], files["run"]):
        readers = [r.plugin_name for r in manager.iter_compatible_readers([str(path)])]
        assert "picamcal" in readers
    writers = [w.command for w in manager.iter_compatible_writers(["image"]) if w.command.startswith("picamcal")]
    assert sorted(writers) == ["picamcal.write_ome_zarr", "picamcal.write_tiff"]


# Qt: napari's viewer and the dialog, on this module's own X server ---------------------------------------------------


@pytest.fixture(scope="module")
def display(tmp_path_factory):
    """This process's QApplication, on a virtual X display (:mod:`napari_support`); napari's settings in a file of the
    session, not the user's."""
    from qtpy.QtWidgets import QApplication

    from napari_support import qt_application_on_virtual_display

    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("NAPARI_CONFIG", str(tmp_path_factory.mktemp("napari") / "settings.yaml"))
        qt_application_on_virtual_display()
        yield QApplication.instance()


@pytest.mark.slow
def test_napari_opens_and_saves_through_the_plugin(display, files, tmp_path):
    import napari
    from napari.utils.notifications import notification_manager

    viewer = napari.Viewer(show=False)
    try:
        added = viewer.open(str(files["dng"]), plugin="picamcal")
        assert [layer.name for layer in added] == ["white", "white (raw)"]
        raw = read_raw(files["dng"])
        np.testing.assert_array_equal(added[1].data, raw.bayer)
        np.testing.assert_array_equal(added[0].data, _layers.linear_rgb(raw))
        assert added[0].rgb and added[0].metadata["picamcal"]["sensor"] == "imx219"
        assert [str(unit) for unit in added[0].units] == ["micrometer", "micrometer"]
        bad = truncated(files["dng"], tmp_path / "cut.dng")
        received = []

        def keep(notification) -> None:
            received.append(notification)

        notification_manager.notification_ready.connect(keep)
        try:
            assert viewer.open(str(bad), plugin="picamcal") == []  # no layer, no exception: the line is shown
        finally:
            notification_manager.notification_ready.disconnect(keep)
        with pytest.raises(PicamcalError) as expected:
            read_raw(bad)
        errors = [n for n in received if str(n.severity) == "error"]
        assert [str(n.message) for n in errors] == [str(expected.value)]
        assert len(viewer.layers) == 2
        written = napari.plugins.io.save_layers(str(tmp_path / "white.tif"), [added[0]], plugin="picamcal")
        assert written == [str(tmp_path / "white.tif")]
        np.testing.assert_array_equal(
            tifffile.imread(tmp_path / "white.tif"), picamcal.output.encode_uint16(added[0].data)
        )
        assert tiff_record(tmp_path / "white.tif")["source"] == "white.dng"
    finally:
        viewer.close()


def test_the_dialog_asks_for_a_dumps_options_as_the_command_line_does(display, files):
    path = files["headless"]
    request = _reader_request(path)
    dialog = _dialog.ReadOptionsDialog(request)
    try:
        assert list(dialog.fields) == ["raw_format", "size", "stride", "frame", "sensor", "black_level"]
        assert dialog.answers() == {key: "" for key in dialog.fields}  # a 320 x 240 dump: nothing to suggest
        assert "headless dump" in dialog.reason.text() and not dialog.dialog.isVisible()
        dialog.fields["raw_format"].setCurrentText("SBGGR10_CSI2P")
        dialog.fields["size"].setText("320x241")
        assert not dialog.submit() and dialog.options is None
        cli = subprocess.run(
            [
                sys.executable,
                "-c",
                "from picamcal.cli import main; main()",
                "inspect",
                str(path),
                "--raw-format",
                "SBGGR10_CSI2P",
                "--size",
                "320x241",
            ],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert dialog.error.text() in cli.stderr and dialog.error.text().startswith("Invalid value for --size")
        dialog.fields["size"].setText("320x240")
        dialog.fields["stride"].setText("0")
        assert not dialog.submit() and "'--stride'" in dialog.error.text()
        dialog.fields["stride"].setText("")
        dialog.fields["sensor"].setCurrentText("imx219")
        assert dialog.submit() and dialog.error.text() == ""
        assert dialog.options == {"raw_format": "SBGGR10_CSI2P", "size": (320, 240), "sensor": "imx219"}
    finally:
        dialog.dialog.deleteLater()
    black = _dialog.ReadOptionsDialog(
        _dialog.Request(path, _dialog.BLACK_LEVEL, "no black level", {"black_level": "64"})
    )
    try:
        assert list(black.fields) == ["sensor", "black_level"] and black.answers()["black_level"] == "64"
        assert black.submit() and black.options == {"black_level": [64.0]}
    finally:
        black.dialog.deleteLater()
    suggested = {"raw_format": "SBGGR10_CSI2P", "size": "3280x2464", "sensor": "imx219"}  # headless_defaults' kind
    full = _dialog.ReadOptionsDialog(_dialog.Request(path, _dialog.HEADLESS, "a full frame?", suggested))
    try:
        assert full.answers() == {**dict.fromkeys(full.fields, ""), **suggested}  # the fields start filled in
        assert full.fields["stride"].placeholderText() == "libcamera's alignment"
    finally:
        full.dialog.deleteLater()


def _reader_request(path: Path) -> _dialog.Request:
    """The request the reader makes for a headless dump (what it passes to ask_read_options)."""
    asked: list[_dialog.Request] = []
    real = _dialog.ask_read_options
    try:
        _dialog.ask_read_options = lambda request: asked.append(request)  # type: ignore[assignment,func-returns-value]
        _reader.read(str(path))
    finally:
        _dialog.ask_read_options = real
    return asked[0]
