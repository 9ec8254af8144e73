"""The calibration value: save/load round trip, schema checks, corrupt files, image compatibility."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from picamcal import CalibrationFileError, OutputError, calibrate, correct, load_calibration
from picamcal.calibration import ARRAYS, GLOBAL_ARRAYS
from picamcal.raw import RawImage


@pytest.fixture
def cal(linear_refs):
    return calibrate(**linear_refs)


def test_round_trip_keeps_every_array_and_the_record(tmp_path, cal):
    path = cal.save(tmp_path / "cal.npz")
    back = load_calibration(path)
    assert set(back.arrays) == set(ARRAYS) | set(GLOBAL_ARRAYS)
    for name, value in cal.arrays.items():
        np.testing.assert_array_equal(back.arrays[name], value)
    assert back.meta == cal.meta
    for key in (
        "software_version",
        "created",
        "sensor",
        "pattern",
        "width",
        "height",
        "bin_size",
        "black_level",
        "inputs",
    ):
        assert key in back.meta
    assert [i["role"] for i in back.meta["inputs"]] == ["white", "red", "green", "blue", "black"]
    with np.load(path, allow_pickle=False) as data:  # plain arrays and JSON: no pickles anywhere
        record = json.loads(str(data["metadata"]))
    assert record["schema"] == "picamcal-calibration" and record["schema_version"] == 1


def test_input_checksums_are_recorded(tmp_path, linear_refs):
    from picamcal.raw import write_dng

    paths = {k: write_dng(tmp_path / f"{k}.dng", r) for k, r in linear_refs.items()}
    cal = calibrate(**paths)
    inputs = {i["role"]: i for i in cal.meta["inputs"]}
    assert inputs["white"]["name"] == "white.dng" and inputs["white"]["format"] == "dng"
    import hashlib

    assert inputs["red"]["sha256"] == hashlib.sha256(paths["red"].read_bytes()).hexdigest()


def test_save_refuses_to_overwrite_when_asked(tmp_path, cal):
    cal.save(tmp_path / "cal.npz")
    with pytest.raises(OutputError, match="exists already"):
        cal.save(tmp_path / "cal.npz", overwrite=False)
    assert [p.name for p in tmp_path.iterdir()] == ["cal.npz"]  # no temporary files left behind


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda p: p.write_bytes(b"not a zip"), r"not a picamcal calibration file \(not an .npz archive\)"),
        (lambda p: p.write_bytes(p.read_bytes()[:200]), "not a readable picamcal calibration"),
        (lambda p: np.savez(p, x=np.zeros(2)), r"not a picamcal calibration file \(an .npz without its record\)"),
        (lambda p: np.savez(p, metadata=np.array(json.dumps({"schema": "other"}))), "not a picamcal calibration"),
        (lambda p: np.savez(p, metadata=np.array([{"a": 1}], dtype=object)), "holds Python objects"),
        (lambda p: np.savez(p, metadata=np.array("{not json")), "its record is not JSON"),
    ],
)
def test_corrupt_files_are_refused(tmp_path, cal, damage, message):
    path = cal.save(tmp_path / "cal.npz")
    damage(path)
    with pytest.raises(CalibrationFileError, match=message) as caught:
        load_calibration(path)
    assert "allow_pickle" not in str(caught.value)  # numpy's advice does not apply to a calibration


def _rewrite(path, **changes):
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    record = json.loads(str(arrays.pop("metadata")))
    for key, value in changes.items():
        if key in arrays or key.startswith("array_"):
            arrays[key.removeprefix("array_")] = value
        else:
            record[key] = value
    with zipfile.ZipFile(path, "w"):
        pass
    np.savez(path, metadata=np.array(json.dumps(record)), **arrays)


def test_schema_version_and_shapes_are_checked(tmp_path, cal):
    path = cal.save(tmp_path / "cal.npz")
    _rewrite(path, schema_version=99)
    with pytest.raises(CalibrationFileError, match="schema version 99 is not supported"):
        load_calibration(path)
    path = cal.save(tmp_path / "cal2.npz")
    _rewrite(path, unmixing=np.zeros((3, 3, 3, 3), np.float32))
    with pytest.raises(CalibrationFileError, match="'unmixing' has shape"):
        load_calibration(path)
    path = cal.save(tmp_path / "cal3.npz")
    bad = cal.unmixing.copy()
    bad[0, 0, 0, 0] = np.nan
    _rewrite(path, unmixing=bad)
    with pytest.raises(CalibrationFileError, match="non-finite"):
        load_calibration(path)


def test_missing_file(tmp_path):
    with pytest.raises(CalibrationFileError, match="no such calibration file"):
        load_calibration(tmp_path / "none.npz")


def test_image_from_another_sensor_or_size_is_refused(cal, linear_refs):
    white = linear_refs["white"]
    other_sensor = RawImage(white.bayer, white.pattern, white.black_level, 1023, 10, "imx477", {"path": "x.dng"})
    with pytest.raises(CalibrationFileError, match=r"x\.dng: image does not match the calibration: sensor imx477"):
        correct(other_sensor, cal)
    smaller = RawImage(white.bayer[:64, :64], white.pattern, white.black_level, 1023, 10, "imx219", {"path": "y.dng"})
    with pytest.raises(CalibrationFileError, match=r"y\.dng: .*size 64x64, calibration is for 256x192"):
        correct(smaller, cal)


def test_noise_penalty_definitions(cal):
    # balance changes nothing spatially; flat is the vignetting gain relative to the centre; unmixing adds to it.
    np.testing.assert_allclose(cal.noise_penalty("balance"), 1.0)
    flat = cal.noise_penalty("flat")
    ys, xs = cal.centre_slices
    w_centre = cal.white[ys, xs].reshape(-1, 3).mean(0)
    np.testing.assert_allclose(flat, w_centre / cal.white, rtol=1e-5)
    centre = cal.noise_penalty("centre")
    np.testing.assert_allclose(centre[ys, xs].mean((0, 1)), 1.0, atol=0.02)  # U is the identity at the centre
    assert centre.max() > flat.max()  # unmixing costs noise where the crosstalk is strong
    assert cal.noise_penalty("pure").mean() > cal.noise_penalty("centre").mean()
    with pytest.raises(ValueError, match="unknown mode"):
        cal.noise_penalty("nope")
