"""Hardening of the loaders (calibration, tuning JSON, target layout, acquisition manifest, processed images) and
of what picamcal exports (tuning files, the legacy table).

Whatever the bytes, the loaders raise only picamcal's own errors, and what they accept can be used: fuzz tests
mutate real files written by picamcal. Calibrations are validated on creation and on load (a negative, zero,
NaN or complex white is refused). Exports are checked against libcamera's own parsing rules and the hardware's
gain range before anything is written. Memory tests measure the peak resident memory of the command line refusing
a zip-bomb calibration and a 20000 x 20032 16-bit PNG.
"""

from __future__ import annotations

import copy
import dataclasses
import io
import itertools
import json
import math
import re
import shutil
import struct
import sys
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np
import png
import pytest
import tifffile
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from conftest import run_measured
from picamcal import (
    CalibrationFileError,
    CalibrationInputError,
    PicamcalError,
    RawFormatError,
    calibrate,
    load_calibration,
)
from picamcal.acquire.acquisition import acquire, read_manifest
from picamcal.acquire.cameras import SimCamera
from picamcal.analysis.wheels import analyse, find_wheels, read_layout
from picamcal.export.isp import lens_shading_gains, tuning_black_level, tuning_ccm
from picamcal.export.legacy import check_legacy_table, legacy_table, save_legacy_table
from picamcal.export.tuning import TuningError, export_tuning, load_tuning, save_tuning, stock_tuning_path
from picamcal.raw.processed import read_processed, tuning_gamma_curve
from picamcal.references import find_references
from picamcal.simulate import simulate_run, wheel_layout, wheel_scene
from picamcal.target import render_target, target_layout
from test_cli import assert_bad_input, run

FUZZ = settings(max_examples=150, deadline=None, database=None)
CLI = (sys.executable, "-c", "from picamcal.cli import main; main()")
#: libcamera's ALSC grid (columns, rows) per target: awbRegions of the vc4 and PiSP IPAs.
LIBCAMERA_GRIDS = {"bcm2835": (16, 12), "pisp": (32, 32)}
#: Gains each ISP can hold (FORMATS.md section 4): vc4 stores u4.10, below 16; the PiSP packs them below 8.
HARDWARE_MAX_GAIN = {"bcm2835": 16.0, "pisp": 8.0}


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory) -> dict[str, Path]:
    """A small real run: the simulated references as DNG files, a full and a flat calibration made from them."""
    folder = tmp_path_factory.mktemp("loaders")
    refs = simulate_run(folder / "sim", size=(320, 240), noise=False)
    calibrate(*(refs[role] for role in ("white", "red", "green", "blue", "black"))).save(folder / "cal.npz")
    calibrate(refs["white"]).save(folder / "flat.npz")
    return {"folder": folder, "sim": folder / "sim", "cal": folder / "cal.npz", "flat": folder / "flat.npz"}


# --- helpers -------------------------------------------------------------------------------------------------


def _members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as archive:
        return {info.filename: archive.read(info) for info in archive.infolist()}


def _write_npz(path: Path, members: dict[str, bytes], compress: bool = False) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return path


def _npy(array: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array(out, array, allow_pickle=True)
    return out.getvalue()


def _npy_header(descr: object, shape: object, fortran: object = False) -> bytes:
    text = f"{{'descr': {descr!r}, 'fortran_order': {fortran!r}, 'shape': {shape!r}, }}"
    text += " " * (-(11 + len(text)) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text.encode("latin1")


def _record(members: dict[str, bytes]) -> dict:
    return json.loads(str(np.load(io.BytesIO(members["metadata.npy"]))))


def flat_png(path: Path, width: int, height: int, value: int = 30000) -> Path:
    """A 16-bit RGB PNG of one grey level, written in constant time and memory: after a full flush a raw deflate
    stream's blocks for equal input are equal, so one block of 64 rows is repeated."""
    row = b"\x00" + struct.pack(">H", value) * (3 * width)
    rows_per_block = 64 if height % 64 == 0 else 1
    deflate = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = deflate.compress(row * rows_per_block) + deflate.flush(zlib.Z_FULL_FLUSH)
    stream = b"\x78\x9c" + block * (height // rows_per_block) + deflate.flush(zlib.Z_FINISH)
    adler = 1
    for _ in range(height):
        adler = zlib.adler32(row, adler)
    stream += struct.pack(">I", adler)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 16, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", stream) + chunk(b"IEND", b""))
    return path


# JSON values that break loaders: wrong types, huge and special numbers (as text tokens), deep nesting.
_SPECIAL = {"\x00deep": "[" * 5000 + "]" * 5000, "\x00nan": "NaN", "\x00inf": "1e999", "\x00big": "9" * 5000}
json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.sampled_from([0, -1, 1, 2, 3, 4, 16, 255, 4500, 65535, 0.0, -0.5, 1e-300, 1e308, 2.5])
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=6)
    | st.sampled_from([*_SPECIAL, "full", "flat", "BGGR", "ring", "disc", "centre", "white", "pisp"]),
    lambda children: st.lists(children, max_size=6) | st.dictionaries(st.text(max_size=4), children, max_size=4),
    max_leaves=12,
)


def _dumps(value: object) -> str:
    text = json.dumps(value)
    for key, token in _SPECIAL.items():
        text = text.replace(json.dumps(key), token)
    return text


def _paths(value: object, prefix: tuple = ()) -> list[tuple]:
    found = [prefix]
    if isinstance(value, dict):
        for key, child in value.items():
            found += _paths(child, (*prefix, key))
    elif isinstance(value, list):
        for i, child in enumerate(value[:4]):
            found += _paths(child, (*prefix, i))
    return found


def mutate_json(data: st.DataObject, document: object) -> bytes:
    """Bytes of ``document`` with values replaced or deleted, or its text cut, flipped or not UTF-8."""
    how = data.draw(st.sampled_from(["replace", "replace", "replace", "delete", "cut", "flip", "latin1"]))
    if how in ("replace", "delete"):
        document = copy.deepcopy(document)
        for _ in range(data.draw(st.integers(1, 3))):
            path = data.draw(st.sampled_from(_paths(document)))
            if not path:
                document = data.draw(json_values)
                continue
            parent = document
            for key in path[:-1]:
                parent = parent[key]
            if how == "delete" and isinstance(parent, dict):
                del parent[path[-1]]
            else:
                parent[path[-1]] = data.draw(json_values)
        return _dumps(document).encode()
    text = json.dumps(document).encode()
    if how == "cut":
        return text[: data.draw(st.integers(0, len(text) - 1))]
    if how == "latin1":
        return text.replace(b'"', b'"\xe9', 1)
    flipped = bytearray(text)
    for at, byte in data.draw(st.lists(st.tuples(st.integers(0, len(text) - 1), st.integers(0, 255)), max_size=8)):
        flipped[at] = byte
    return bytes(flipped)


# --- calibrations: validated on creation and on load -----------------------------------------------------------


@pytest.mark.parametrize("white", ["negative", "zero", "nan", "complex", "int"])
def test_creation_refuses_a_white_that_cannot_correct(sim_run, white):
    cal = load_calibration(sim_run["cal"])
    bad = {
        "negative": -cal.white,
        "zero": np.zeros_like(cal.white),
        "nan": np.where(cal.white > cal.white.mean(), np.nan, cal.white),
        "complex": cal.white.astype(np.complex64),
        "int": cal.white.astype(np.int32),
    }[white]
    with pytest.raises(CalibrationInputError, match="calibration array 'white'"):
        dataclasses.replace(cal, white=bad)


@pytest.mark.slow
def test_a_bad_white_on_file_is_refused_in_one_line_by_every_command(sim_run, tmp_path):
    # Before: export-tuning wrote a tuning file (exit 0) and correct gave negative or all-NaN images.
    members = _members(sim_run["cal"])
    white = np.load(io.BytesIO(members["white.npy"]))
    for name, bad in (("negative", -white), ("complex", white.astype(np.complex64)), ("zero", 0 * white)):
        path = _write_npz(tmp_path / f"{name}.npz", {**members, "white.npy": _npy(bad)})
        with pytest.raises(CalibrationFileError, match=rf"{name}\.npz: calibration array 'white'"):
            load_calibration(path)
    out = tmp_path / "t.json"
    result = run("export-tuning", str(tmp_path / "negative.npz"), "--target", "pisp", "--out", str(out))
    assert_bad_input(result, "negative.npz", "'white'", "<= 0")
    result = run("correct", str(tmp_path / "complex.npz"), str(sim_run["sim"] / "target.dng"), "--out", str(tmp_path))
    assert_bad_input(result, "complex.npz", "'white' has complex values")
    assert not out.exists() and not (tmp_path / "target.tiff").exists()


def test_record_types_and_agreement_with_the_fields_are_checked(sim_run, tmp_path):
    members = _members(sim_run["cal"])
    record = _record(members)
    for change, message in (
        ({"width": "320"}, "record 'width' must be a positive whole number, not the string '320'"),
        ({"width": 336}, "a 320x240 crop binned 1x1 is not the calibration's 336x240"),
        (
            {
                "width": 336,
                "geometry": {**record["geometry"], "crop": [0, 0, 336, 240], "sensor_size": [336, 240], "size": None},
            },
            "'site_responses' has shape (4, 15, 20, 4), expected (4, 15, 21, 4)",
        ),
        ({"geometry": {**record["geometry"], "crop": [0, 0, 640, 240]}}, "is not an area of the 320x240 sensor"),
        ({"geometry": {**record["geometry"], "hflip": 1}}, "record 'geometry'.hflip must be true or false"),
        ({"geometry": {**record["geometry"], "source": "guess"}}, "record 'geometry'.source must be one of camera"),
        ({"bin_size": 15}, "record 'bin_size' must be even"),
        ({"pattern": "XGGB"}, "record 'pattern' must be one of RGGB, GBRG, BGGR, GRBG"),
        ({"centre_region": [5, 99, 6, 13]}, "is not a region of the 15 x 20 bins"),
        ({"schema_version": True}, "schema version True is not supported"),
        ({"width": 100000, "height": 100000}, "declares an image of 100000x100000 pixels"),
        ({"inputs": [{"role": "white", "frame_count": 3}]}, "temporal_noise_dn must be a number, not null"),
    ):
        text = json.dumps({**record, **change})
        path = _write_npz(tmp_path / "c.npz", {**members, "metadata.npy": _npy(np.array(text))})
        with pytest.raises(CalibrationFileError, match=r"c\.npz: ") as caught:
            load_calibration(path)
        assert message in str(caught.value)
    deep = json.dumps(record).replace('"inputs": [', '"inputs": [' + "[" * 3000 + "]" * 3000 + ", ")
    path = _write_npz(tmp_path / "d.npz", {**members, "metadata.npy": _npy(np.array(deep))})
    with pytest.raises(CalibrationFileError, match="its record is not JSON: nested too deeply"):
        load_calibration(path)  # before: RecursionError


def test_forged_headers_and_sizes_are_refused_before_reading(sim_run, tmp_path):
    members = _members(sim_run["cal"])
    data = members["white.npy"][128:]
    for member, message in (
        (_npy_header("<f4", (10**6, 10**6)) + data, "'white' has shape (1000000, 1000000), expected (15, 20, 3)"),
        (_npy_header("<f4", (15, 20, 3))[:40], "'white' has a header cut short"),  # numpy: tokenize.TokenError
        (_npy_header([("a", "<f4")], (15, 20, 3)) + data, "'white' is a structured array"),
        (_npy_header("|O", (15, 20, 3)) + data, "not a picamcal calibration file (it holds Python objects)"),
        (_npy_header("<c16", (15, 20, 3)) + data, "'white' has complex values (complex128), expected real floating"),
        (_npy_header("<f4", (15, 20, 3, 1)) + data, "'white' has shape (15, 20, 3, 1)"),
    ):
        path = _write_npz(tmp_path / "h.npz", {**members, "white.npy": member})
        with pytest.raises(CalibrationFileError, match=r"h\.npz: ") as caught:
            load_calibration(path)
        assert message in str(caught.value)
    path = _write_npz(tmp_path / "s.npz", {**members, "white.npy": members["white.npy"] + bytes(64)})
    with pytest.raises(CalibrationFileError, match="'white' declares 3792 bytes, its header 3728: corrupt"):
        load_calibration(path)


def test_zip_bombs_and_damaged_archives_are_refused(sim_run, tmp_path):
    members = _members(sim_run["cal"])
    bomb = _write_npz(tmp_path / "bomb.npz", {**members, "white.npy": members["white.npy"] + bytes(64 << 20)}, True)
    with pytest.raises(CalibrationFileError, match=r"'white\.npy' would inflate from [\d.]+ MB to 67 MB: .*zip bomb"):
        load_calibration(bomb)
    whole = sim_run["cal"].read_bytes()
    flipped = whole[:40000] + bytes([whole[40000] ^ 0xFF]) + whole[40001:]  # in crosstalk's data
    for name, content in (("cut.npz", whole[: len(whole) // 2]), ("flip.npz", flipped)):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(CalibrationFileError, match="not a readable picamcal calibration"):
            load_calibration(tmp_path / name)  # the half archive has no directory; the flipped byte fails the CRC
    with pytest.raises(CalibrationFileError, match="is a directory"):
        load_calibration(tmp_path)


@given(data=st.data())
@settings(max_examples=300, deadline=None, database=None)
def test_load_calibration_raises_only_picamcal_errors_and_what_loads_is_usable(sim_run, data):
    base = sim_run[data.draw(st.sampled_from(["cal", "flat"]))]
    members = _members(base)
    how = data.draw(st.sampled_from(["array", "array", "record", "record", "header", "flip", "cut", "member"]))
    names = sorted(members)
    if how == "array":
        name = data.draw(st.sampled_from(names))
        original = np.load(io.BytesIO(members[name]))
        dtype = data.draw(st.sampled_from(["<f4", "<f8", ">f8", "<f2", "<c8", "<i4", "|i1", "<u2", "|b1", "<U3", "|O"]))
        shape = data.draw(st.sampled_from([original.shape, ()]) | st.lists(st.integers(0, 4), max_size=4).map(tuple))
        fill = data.draw(st.sampled_from(["same", math.nan, math.inf, -math.inf, 0.0, -1.0, 1e38, 1.0]))
        source = (original if shape == original.shape else np.ones(shape)) if fill == "same" else np.full(shape, fill)
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            try:
                array = source.astype(dtype)
            except (TypeError, ValueError):  # the record's text as a number
                array = np.ones(shape, dtype)
        members[name] = _npy(array)
        content = _write_npz(sim_run["folder"] / "fuzz.npz", members, data.draw(st.booleans())).read_bytes()
    elif how == "record":
        content_text = mutate_json(data, _record(members)).decode("utf-8", "replace")
        members["metadata.npy"] = _npy(np.array(content_text))
        content = _write_npz(sim_run["folder"] / "fuzz.npz", members).read_bytes()
    elif how == "header":
        name = data.draw(st.sampled_from(names))
        descr = data.draw(st.sampled_from(["<f4", "<f8", "|b1", "<U9", "|O", "<c8", "x", 5, [("a", "<f4")]]))
        shape = data.draw(st.lists(st.sampled_from([0, 1, 3, 4, 15, 20, -1, 10**12, 2**64]), max_size=4).map(tuple))
        header = _npy_header(descr, shape, data.draw(st.sampled_from([False, True, "x"])))
        header = header[: data.draw(st.integers(8, len(header)))]
        members[name] = header + members[name][128:]
        content = _write_npz(sim_run["folder"] / "fuzz.npz", members).read_bytes()
    elif how == "member":
        name = data.draw(st.sampled_from(names))
        if data.draw(st.booleans()):
            del members[name]
        else:
            members[name.replace(".npy", "")] = members[name]
        content = _write_npz(sim_run["folder"] / "fuzz.npz", members).read_bytes()
    else:
        content = bytearray(base.read_bytes())
        if how == "cut":
            content = content[: data.draw(st.integers(1, len(content) - 1))]
        for at, byte in data.draw(st.lists(st.tuples(st.integers(0, len(content) - 1), st.integers(0, 255)))):
            content[at] = byte
    path = sim_run["folder"] / "fuzz.npz"
    path.write_bytes(bytes(content))
    try:
        cal = load_calibration(path)
    except PicamcalError:
        return
    for name, array in cal.to_arrays().items():
        assert array.dtype == bool or (array.dtype.kind == "f" and np.all(np.isfinite(array))), name
    assert np.all(cal.white > 0) and np.all(cal.site_white > 0)
    assert np.all(np.isfinite(cal.noise_penalty("flat")))


def test_a_white_near_the_float32_limit_gives_a_finite_noise_penalty(sim_run, tmp_path):
    # Found by the fuzz test above: a white of 1e38 everywhere loads (finite, positive), and the centre's float32
    # mean overflowed to inf, which made every noise penalty inf.
    members = _members(sim_run["cal"])
    members["white.npy"] = _npy(np.full(np.load(io.BytesIO(members["white.npy"])).shape, 1e38, "<f4"))
    cal = load_calibration(_write_npz(tmp_path / "bright.npz", members, False))
    for mode in ("flat", "centre"):
        assert np.all(np.isfinite(cal.noise_penalty(mode))), mode
    np.testing.assert_allclose(cal.noise_penalty("flat"), 1.0, rtol=1e-6)


# --- tuning files ---------------------------------------------------------------------------------------------


def _libcamera_problems(tuning: dict) -> list[str]:
    """What libcamera's Raspberry Pi IPA would refuse or clip in a tuning file, by its own code: Alsc::read
    and readCalibrations (tables of the grid's size, every value a double, cts above the previous one, starting
    from 0), readLut, Ccm::read (at least one matrix of 9, cts increasing), and the ISPs' gain ranges."""
    problems = []
    target = tuning["target"]
    cells = math.prod(LIBCAMERA_GRIDS[target])
    if not (isinstance(tuning["version"], float) and tuning["version"] == 2.0):
        problems.append("version")
    for algorithm in tuning["algorithms"]:
        (name, params), *_ = algorithm.items()
        if name == "rpi.alsc":
            lut = params.get("luminance_lut", [1.0] * cells)
            if len(lut) != cells or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in lut):
                problems.append("luminance_lut")
            green = 1 + params.get("luminance_strength", 1.0) * (np.array(lut) - 1)
            for key in ("calibrations_Cr", "calibrations_Cb"):
                last = 0.0
                for entry in params.get(key, []):
                    if not entry["ct"] > last:
                        problems.append(f"Entries in {key} must be in increasing ct order")
                    last = entry["ct"]
                    table = np.array(entry["table"], dtype=float)
                    if table.size != cells or not np.all(np.isfinite(table)):
                        problems.append(f"Incorrect number of values for ct {entry['ct']} in {key}")
                    elif not 0 < (table / table.min() * green).max() < HARDWARE_MAX_GAIN[target]:
                        problems.append(f"{key} gains outside the {target} range")
            if not 0 < green.min() <= green.max() < HARDWARE_MAX_GAIN[target]:
                problems.append("luminance gains outside the range")
        if name == "rpi.ccm":
            cts = [c["ct"] for c in params["ccms"]]
            if not cts or any(b <= a for a, b in itertools.pairwise(cts)):
                problems.append("CCM not in increasing colour temperature order")
            if any(len(c["ccm"]) != 9 or not all(-8 <= v <= 7.9999 for v in c["ccm"]) for c in params["ccms"]):
                problems.append("ccm")
    return problems


@pytest.mark.parametrize("target", ["pisp", "bcm2835"])
def test_exported_tuning_files_pass_libcamera_own_rules(sim_run, tmp_path, target):
    cal = load_calibration(sim_run["cal"])
    base = load_tuning(stock_tuning_path("imx219", target))
    path = save_tuning(tmp_path / "t.json", export_tuning(cal, base, ct=5600, ccm=True))
    written = json.loads(path.read_text(), parse_constant=lambda name: pytest.fail(f"{name} written"))
    assert _libcamera_problems(written) == []
    assert _libcamera_problems(base) == []  # the checker itself accepts Raspberry Pi's own file
    alsc = next(a["rpi.alsc"] for a in written["algorithms"] if "rpi.alsc" in a)
    assert [c["ct"] for c in alsc["calibrations_Cr"]] == [5600]


def test_exports_refuse_what_libcamera_or_the_isp_cannot_use(sim_run, tmp_path):
    cal = load_calibration(sim_run["cal"])
    base = load_tuning(stock_tuning_path("imx219", "pisp"))
    for ct in (0, -4500, 0.5, math.nan, math.inf, True):
        with pytest.raises(TuningError, match="is not a positive number of kelvin"):
            export_tuning(cal, base, ct=ct)
    good = export_tuning(cal, base)
    alsc_at = next(i for i, a in enumerate(good["algorithms"]) if "rpi.alsc" in a)

    def with_alsc(**changes) -> dict:
        tuning = copy.deepcopy(good)
        tuning["algorithms"][alsc_at]["rpi.alsc"].update(changes)
        return tuning

    table = good["algorithms"][alsc_at]["rpi.alsc"]["calibrations_Cr"][0]["table"]
    out = tmp_path / "t.json"
    for tuning, message in (
        (with_alsc(calibrations_Cr=[{"ct": 4500, "table": table}] * 2), "must be in increasing ct order"),
        (with_alsc(calibrations_Cr=[{"ct": 0, "table": table}]), "ct must be a positive number, not 0"),
        (with_alsc(luminance_lut=[math.nan] * 1024), "must be a finite positive number, not nan"),
        (with_alsc(luminance_lut=[0.0] * 1024), "luminance_lut[0] must be a positive number, not 0.0"),
        (with_alsc(calibrations_Cr=[{"ct": 4500, "table": table[:-1]}]), "must hold 1024 items, not 1023"),
        (with_alsc(calibrations_Cr=[{"ct": 4500, "table": [1.0] * 1023 + [9.0]}]), "Cr at 4500 K gives a gain of"),
        (with_alsc(luminance_lut=[1.0] * 1023 + [20.0]), "luminance gives a gain of 20, outside the pisp hardware's"),
    ):
        with pytest.raises(TuningError, match=re.escape(message)):
            save_tuning(out, tuning)
        assert not out.exists()
        assert _libcamera_problems(tuning)  # libcamera's rules, independently, find each one too
    spoilt, white = copy.copy(cal), cal.white.copy()
    white[3, 4, 1] = np.nan
    object.__setattr__(spoilt, "white", white)  # forced past the immutable value's checks: export_tuning still refuses
    with pytest.raises(TuningError, match="must be a finite positive number, not nan"):
        export_tuning(spoilt, base)
    result = run("export-tuning", str(sim_run["cal"]), "--target", "pisp", "--ct", "0", "--out", str(out))
    assert_bad_input(result)  # before: exit 0, and a file libcamera refuses, so the camera would not start
    assert "--ct" in result.stderr or "kelvin" in result.stderr, result.stderr
    assert not out.exists()


def test_legacy_table_refuses_gains_it_cannot_hold(sim_run, tmp_path):
    cal = load_calibration(sim_run["cal"])
    table = legacy_table(cal)
    assert table.dtype == np.uint8 and table.min() >= 32
    dark = cal.site_white.copy()
    dark[:5] /= 20  # a top edge twenty times darker needs gains near 20: above 255 / 32
    with pytest.raises(PicamcalError, match=r"gains up to \d+\.\d+, above its maximum of 7\.97 .*export-tuning"):
        legacy_table(dataclasses.replace(cal, site_white=dark))
    for bad in (table.astype(np.float64), table.astype(np.int16) * 9, table[0]):
        with pytest.raises(PicamcalError, match="legacy table"):
            save_legacy_table(tmp_path / "lst.npy", bad)
        assert not (tmp_path / "lst.npy").exists()
    check_legacy_table(table)


@given(data=st.data())
@FUZZ
def test_tuning_loaders_raise_only_picamcal_errors_and_what_loads_is_usable(sim_run, data):
    target = data.draw(st.sampled_from(["pisp", "bcm2835"]))
    stock = json.loads(stock_tuning_path("imx219", target).read_text())
    read = ("rpi.alsc", "rpi.black_level", "rpi.ccm", "rpi.contrast")
    small = {**stock, "algorithms": [a for a in stock["algorithms"] if next(iter(a)) in read]}
    path = sim_run["folder"] / "fuzz_tuning.json"
    path.write_bytes(mutate_json(data, small))
    try:
        tuning_gamma_curve(path)
    except PicamcalError:
        pass
    try:
        tuning = load_tuning(path)
    except PicamcalError:
        return
    try:
        with np.errstate(all="ignore"):
            gains = lens_shading_gains(tuning, 64, 48)
    except PicamcalError:  # what picamcal does not emulate (a corner_strength table) says so
        return
    assert not np.any(np.isnan(gains))
    tuning_black_level(tuning, 10)
    tuning_ccm(tuning, 4500)


# --- target layouts -------------------------------------------------------------------------------------------


def test_read_layout_reads_both_layouts_and_refuses_bad_ones_in_one_line(sim_run, tmp_path):
    assert read_layout(sim_run["sim"] / "layout.json")["width"] == 320
    layout = target_layout(640, 360)
    for change, message in (
        ({"width": 0}, "width must be 1 to 100000, not 0"),
        ({"wheels": layout["wheels"][1:]}, "wheels must have different names, one of them 'centre'"),
        ({"fiducials": layout["fiducials"][:4]}, "fiducials must be 4 rings and 1 disc, not 4 and 0"),
        ({"segments": "red"}, "segments must be a list, not the string 'red'"),
    ):
        (tmp_path / "l.json").write_text(json.dumps({**layout, **change}))
        with pytest.raises(PicamcalError, match=r"l\.json: not a target layout: ") as caught:
            read_layout(tmp_path / "l.json")
        assert message in str(caught.value)
    (tmp_path / "deep.json").write_text('{"width": ' + "[" * 4000 + "]" * 4000 + "}")
    assert_bad_input(
        run("report", str(sim_run["cal"]), "--layout", str(tmp_path / "deep.json"), "--out", str(tmp_path / "r")),
        "deep.json",
        "nested too deeply",
    )  # before: a RecursionError traceback
    assert not (tmp_path / "r").exists()


@pytest.fixture(scope="module")
def target_images() -> dict:
    plain, marked = wheel_layout(320, 240), target_layout(320, 240)
    marked_image = ((render_target(marked) / 255.0) ** 2.2).astype(np.float32)
    return {"plain": (plain, wheel_scene(plain)), "marked": (marked, marked_image)}


@given(data=st.data())
@settings(max_examples=80, deadline=None, database=None)
def test_read_layout_raises_only_picamcal_errors_and_what_loads_is_usable(sim_run, target_images, data):
    layout, image = target_images[data.draw(st.sampled_from(["plain", "marked"]))]
    path = sim_run["folder"] / "fuzz_layout.json"
    path.write_bytes(mutate_json(data, layout))
    try:
        found = find_wheels(image, layout=read_layout(path))
        analyse({"uncorrected": image}, found)
    except PicamcalError:
        pass


# --- acquisition manifests ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def acquisition(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("acquired") / "run"
    camera = SimCamera("imx219", size=(64, 48), seed=1)
    acquire(camera, camera.light, folder, settle_s=0)
    return folder


def test_manifest_values_are_checked(acquisition, tmp_path):
    folder = tmp_path / "run"
    shutil.copytree(acquisition, folder)
    record = json.loads((folder / "manifest.json").read_text())
    for change, message in (
        ({"settings": {**record["settings"], "analogue_gain": "1"}}, "settings.analogue_gain must be a positive"),
        ({"camera": {**record["camera"], "size": [64]}}, "camera.size must hold 2 items, not 1"),
        ({"entries": [{**record["entries"][0], "file": ".."}]}, "entries[0].file must be a file name in the run's"),
        ({"roles": ["white", "white"]}, "roles names a role twice"),
    ):
        (folder / "manifest.json").write_text(json.dumps({**record, **change}))
        with pytest.raises(PicamcalError, match=r"manifest\.json: not a usable acquisition manifest: ") as caught:
            read_manifest(folder)
        assert message in str(caught.value)
    (folder / "manifest.json").write_bytes(b'{"format": "\xff"}')
    with pytest.raises(PicamcalError, match=r"corrupt manifest \(not JSON: not UTF-8 text"):
        find_references(folder)


@given(data=st.data())
@FUZZ
def test_manifest_readers_raise_only_picamcal_errors(acquisition, data):
    record = json.loads((acquisition / "manifest.json").read_text())
    folder = acquisition.parent / "fuzz"
    if not folder.exists():
        shutil.copytree(acquisition, folder)
    (folder / "manifest.json").write_bytes(mutate_json(data, record))
    for reader in (read_manifest, find_references):
        try:
            reader(folder)
        except PicamcalError:
            pass


# --- processed images -----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def processed_files() -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    rgb8 = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    files = {}
    for kind, suffix in (("PNG", ".png"), ("JPEG", ".jpg"), ("TIFF", ".tif")):
        out = io.BytesIO()
        Image.fromarray(rgb8).save(out, format=kind)
        files[suffix] = out.getvalue()
    out = io.BytesIO()
    png.Writer(32, 24, bitdepth=16, greyscale=False).write(out, (rgb8.astype(np.uint16) * 257).reshape(24, -1))
    files["16.png"] = out.getvalue()
    out = io.BytesIO()
    tifffile.imwrite(out, rgb8.astype(np.uint16) * 257, photometric="rgb")
    files["16.tiff"] = out.getvalue()
    return files


@given(data=st.data())
@settings(max_examples=300, deadline=None, database=None)
def test_read_processed_raises_only_picamcal_errors(sim_run, processed_files, data):
    name = data.draw(st.sampled_from(sorted(processed_files)))
    content = bytearray(processed_files[name])
    how = data.draw(st.sampled_from(["flip", "cut", "size"]))
    if how == "cut":
        content = content[: data.draw(st.integers(1, len(content) - 1))]
    elif how == "size":  # a PNG's IHDR, a TIFF's first tags, a JPEG's frame header: where the size is declared
        at = data.draw(st.integers(0, min(len(content), 200) - 4))
        content[at : at + 4] = data.draw(st.integers(0, 2**32 - 1)).to_bytes(4, "big")
    for at, byte in data.draw(st.lists(st.tuples(st.integers(0, len(content) - 1), st.integers(0, 255)), max_size=6)):
        content[at] = byte
    path = sim_run["folder"] / f"fuzz{Path(name).suffix}"
    path.write_bytes(bytes(content))
    try:
        image = read_processed(path, "linear")
    except PicamcalError:
        return
    assert image.rgb.ndim == 3 and image.rgb.shape[-1] == 3


def test_processed_images_over_the_pixel_limit_or_not_finite_are_refused(tmp_path, monkeypatch):
    monkeypatch.setenv("PICAMCAL_MAX_PIXELS", "1000")
    small = flat_png(tmp_path / "a.png", 64, 64)
    Image.fromarray(np.zeros((64, 64, 3), np.uint8)).save(tmp_path / "b.jpg")
    for path in (small, tmp_path / "b.jpg"):
        with pytest.raises(RawFormatError, match=r"declares an image of 64x64 pixels \(4096 pixels\), over the limit"):
            read_processed(path)
    monkeypatch.delenv("PICAMCAL_MAX_PIXELS")
    np.testing.assert_allclose(read_processed(small, "linear").rgb, 30000 / 65535, rtol=1e-6)  # a real PNG
    tifffile.imwrite(tmp_path / "nan.tif", np.full((8, 8, 3), np.nan, np.float32), photometric="rgb")
    with pytest.raises(RawFormatError, match=r"nan\.tif: holds 192 NaN or infinite samples"):
        read_processed(tmp_path / "nan.tif")  # before: an all-NaN correction, exit 0
    jpeg = bytearray((tmp_path / "b.jpg").read_bytes())
    frame = jpeg.index(b"\xff\xc0")  # start of frame: precision, height, width
    jpeg[frame + 5 : frame + 9] = struct.pack(">HH", 20032, 20000)
    (tmp_path / "c.jpg").write_bytes(bytes(jpeg))
    with pytest.raises(RawFormatError, match=r"c\.jpg: declares an image of 20000x20032 pixels"):
        read_processed(tmp_path / "c.jpg")  # Pillow's own bomb error, in picamcal's words


# --- memory: forged sizes cost less than one real frame ---------------------------------------------------------


@pytest.mark.slow
def test_forged_sizes_are_refused_with_less_memory_than_a_real_frame(sim_run, tmp_path):
    cal, folder = sim_run["cal"], tmp_path
    legit = flat_png(folder / "frame.png", 1640, 1232)  # the IMX219's full field of view, 2x2 binned
    forged = flat_png(folder / "huge.png", 20000, 20032)  # 2.3 MB of file, 2.4 GB of pixels
    members = _members(cal)
    bomb = folder / "bomb.npz"
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as archive:
        for name, data in members.items():
            if name != "site_responses.npy":
                archive.writestr(name, data)
        with archive.open("site_responses.npy", "w", force_zip64=True) as member:  # 0.6 MB inflating to 640 MB
            member.write(members["site_responses.npy"][:128])
            for _ in range(40):
                member.write(bytes(16 << 20))
    headers = _write_npz(folder / "headers.npz", {**members, "white.npy": _npy_header("<f4", (10**6, 10**6))})

    def correct(calibration: Path, image: Path, out: str) -> tuple[str, ...]:
        options = ("--processed", "--workers", "0", "--out", str(folder / out))
        return (*CLI, "correct", str(calibration), str(image), *options)

    (_, _, baseline), legit_run, png_run, *calibration_runs = (
        run_measured(*command)
        for command in (
            (*CLI, "--version"),
            correct(cal, legit, "real"),
            correct(cal, forged, "forged"),
            correct(bomb, legit, "bomb"),
            correct(headers, legit, "headers"),
        )
    )
    status, stderr, real = legit_run
    assert status == 0, stderr
    budget = baseline + (real - baseline) / 4  # well under one real frame, whatever the machine's baseline
    status, stderr, peak = png_run
    assert status == 2 and "huge.png: declares an image of 20000x20032 pixels" in stderr  # one file: an error
    assert peak < budget, (peak, baseline, real)  # before: 4.2 GB after 9 s, still growing
    for (status, stderr, peak), name, message in zip(
        calibration_runs,
        ("bomb.npz", "headers.npz"),
        ("refused as a zip bomb", "has shape (1000000, 1000000)"),
        strict=True,
    ):
        lines = stderr.strip().splitlines()
        assert status == 2 and len(lines) == 1 and name in lines[0] and message in lines[0], stderr
        assert peak < budget, (name, peak, baseline, real)  # before: 640 MB inflated, or a MemoryError traceback
