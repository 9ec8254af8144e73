"""The calibration value: immutability, save/load round trip, schema checks, corrupt files, image compatibility."""

from __future__ import annotations

import dataclasses
import json
import pickle
import zipfile

import numpy as np
import pytest

from picamcal import (
    Calibration,
    CalibrationFileError,
    CalibrationInputError,
    Mode,
    OutputError,
    PicamcalWarning,
    calibrate,
    correct,
    load_calibration,
)
from picamcal.calibration import ARRAYS, GLOBAL_ARRAYS, RECORD_FIELDS, UNMIXING_ARRAYS
from picamcal.raw import RawImage


@pytest.fixture
def cal(linear_refs):
    return calibrate(**linear_refs)


def assert_same_calibration(a: Calibration, b: Calibration) -> None:
    """Every field equal: arrays to the bit and in dtype, the record's fields and the provenance."""
    for f in dataclasses.fields(Calibration):
        if f.name == "path":
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert isinstance(x, np.ndarray) and isinstance(y, np.ndarray), f.name
            assert x.dtype == y.dtype and x.shape == y.shape, f.name
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y, f.name


def test_the_fields_are_the_files_arrays_and_record():
    names = {f.name for f in dataclasses.fields(Calibration)}
    assert names == {*ARRAYS, *GLOBAL_ARRAYS, *RECORD_FIELDS, "provenance", "path"}
    assert set(UNMIXING_ARRAYS) == {
        "crosstalk",
        "unmixing",
        "pure_unmixing",
        "condition_number",
        "ill_conditioned",
        "centre_response",
        "colour_response_inverse",
    }


@pytest.mark.parametrize("kind", ["full", "flat"])
def test_round_trip_keeps_every_field_and_the_kind(tmp_path, linear_refs, kind):
    refs = linear_refs if kind == "full" else {"white": linear_refs["white"], "black": linear_refs["black"]}
    cal = calibrate(**refs)
    path = cal.save(tmp_path / "cal.npz")
    back = load_calibration(path)
    assert back.kind == kind and back.path == path and cal.path is None
    assert_same_calibration(back, cal)
    assert back.to_record() == cal.to_record()
    assert set(back.to_arrays()) == ({*ARRAYS, *GLOBAL_ARRAYS} - (set() if kind == "full" else set(UNMIXING_ARRAYS)))
    assert_same_calibration(Calibration.load(path), cal)  # the classmethod is the same reader
    assert [i["role"] for i in back.inputs] == (
        ["white", "red", "green", "blue", "black"] if kind == "full" else ["white", "black"]
    )
    assert back.provenance["software_version"] and back.provenance["created"]
    with np.load(path, allow_pickle=False) as data:  # plain arrays and JSON: no pickles anywhere
        record = json.loads(str(data["metadata"]))
    assert record["schema"] == "picamcal-calibration" and record["schema_version"] == 2 and record["kind"] == kind
    # The record on disk keeps the keys files have always had, the derived count included.
    assert {*RECORD_FIELDS, "inputs", "created", "software_version", "black_frame"} <= set(record)
    assert ("ill_conditioned_bins" in record) == (kind == "full")


def test_a_calibration_is_immutable(tmp_path, cal):
    loaded = load_calibration(cal.save(tmp_path / "cal.npz"))
    for value in (cal, loaded):
        with pytest.raises(dataclasses.FrozenInstanceError):
            value.white = value.white * 2
        with pytest.raises(dataclasses.FrozenInstanceError):
            value.bin_size = 8
        for name, array in value.to_arrays().items():
            assert not array.flags.writeable, name
            with pytest.raises(ValueError, match="read-only"):
                array[(0,) * array.ndim] = 1
        with pytest.raises(TypeError):
            value.provenance["created"] = "yesterday"  # type: ignore[index]
        with pytest.raises(TypeError):
            value.inputs[0]["name"] = "other.dng"  # type: ignore[index]
        assert isinstance(value.inputs, tuple)


def test_a_calibration_does_not_share_memory_with_what_it_was_made_from(cal):
    white = np.array(cal.white)  # writeable, the caller's own
    made = dataclasses.replace(cal, white=white)
    white[:] = -1  # would be a negative white, had the calibration kept this array
    assert np.all(made.white > 0) and not np.shares_memory(made.white, white)
    record = cal.to_record()
    record["inputs"][0]["name"] = "changed.dng"  # to_record is a copy
    assert cal.inputs[0]["name"] != "changed.dng"


def test_replace_makes_a_new_value_and_checks_it(tmp_path, cal):
    loaded = load_calibration(cal.save(tmp_path / "cal.npz"))
    brighter = dataclasses.replace(loaded, white=loaded.white * 2, lens_shading=loaded.lens_shading)
    np.testing.assert_array_equal(brighter.white, 2 * loaded.white)
    assert brighter.path is None  # a derived value is not the file's content
    np.testing.assert_array_equal(loaded.white, cal.white)  # the original is unchanged
    # Checked exactly as on creation, in memory: CalibrationInputError, not the file's error.
    with pytest.raises(CalibrationInputError, match="calibration array 'white' holds 576 values <= 0"):
        dataclasses.replace(loaded, white=-loaded.white)
    with pytest.raises(CalibrationInputError, match="calibration lacks the array 'unmixing'"):
        dataclasses.replace(cal, unmixing=None)
    with pytest.raises(CalibrationInputError, match=r"a flat calibration holds 'centre_response', .*: inconsistent"):
        dataclasses.replace(cal, kind="flat", site_responses=cal.site_responses[:1])
    with pytest.raises(CalibrationInputError, match=r"'unmixing' has shape \(3, 3\), expected \(12, 16, 3, 3\)"):
        dataclasses.replace(cal, unmixing=np.eye(3, dtype=np.float32))
    with pytest.raises(CalibrationInputError, match="record 'bin_size' must be even, not 15"):
        dataclasses.replace(cal, bin_size=15)
    with pytest.raises(CalibrationInputError, match="record 'centre_region'"):
        dataclasses.replace(cal, centre_region=(0, 99, 0, 1))
    with pytest.raises(CalibrationInputError, match="provenance holds 'width', a field of the calibration"):
        dataclasses.replace(cal, provenance={**cal.provenance, "width": 3})


def test_a_calibration_pickles_as_itself(tmp_path, cal):
    loaded = load_calibration(cal.save(tmp_path / "cal.npz"))
    back = pickle.loads(pickle.dumps(loaded))
    assert_same_calibration(back, loaded)
    assert back.path == loaded.path and not back.white.flags.writeable


def test_the_old_mode_name_balance_is_uncorrected_with_a_warning(cal, linear_refs):
    white = linear_refs["white"]
    uncorrected = correct(white, cal, Mode.UNCORRECTED)
    with pytest.warns(PicamcalWarning, match="mode 'balance' is now called 'uncorrected'") as caught:
        old = correct(white, cal, "balance")
    assert len(caught) == 1  # once per call, not once per step of the correction
    np.testing.assert_array_equal(old, uncorrected)
    with pytest.warns(PicamcalWarning, match="'balance'"):
        assert cal.check_mode("balance") is Mode.UNCORRECTED
    assert cal.modes == tuple(Mode)


@pytest.mark.slow
def test_the_command_line_takes_the_old_mode_name_with_a_warning(tmp_path, cal, linear_refs):
    from picamcal.raw import write_dng
    from test_cli import run

    cal.save(tmp_path / "cal.npz")
    write_dng(tmp_path / "white.dng", linear_refs["white"])
    result = run(
        "correct",
        str(tmp_path / "cal.npz"),
        str(tmp_path / "white.dng"),
        "--mode",
        "balance",
        "--out",
        str(tmp_path / "old"),
    )
    assert result.returncode == 0, result.stderr
    assert "mode 'balance' is now called 'uncorrected'" in result.stderr
    new = run(
        "correct",
        str(tmp_path / "cal.npz"),
        str(tmp_path / "white.dng"),
        "--mode",
        "uncorrected",
        "--out",
        str(tmp_path / "new"),
    )
    assert new.returncode == 0 and "balance" not in new.stderr, new.stderr
    assert (tmp_path / "old" / "white.tiff").read_bytes() == (tmp_path / "new" / "white.tiff").read_bytes()
    wrong = run(
        "correct", str(tmp_path / "cal.npz"), str(tmp_path / "white.dng"), "--mode", "flt", "--out", str(tmp_path / "x")
    )
    assert wrong.returncode == 2 and "did you mean flat?" in wrong.stderr
    helped = run("correct", "--help")
    assert all(mode.value in helped.stdout for mode in Mode)


def test_input_checksums_are_recorded(tmp_path, linear_refs):
    from picamcal.raw import write_dng

    paths = {k: write_dng(tmp_path / f"{k}.dng", r) for k, r in linear_refs.items()}
    cal = calibrate(**paths)
    inputs = {i["role"]: i for i in cal.inputs}
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
    # uncorrected changes nothing spatially; flat is the vignetting gain relative to the centre; unmixing adds to it.
    np.testing.assert_allclose(cal.noise_penalty("uncorrected"), 1.0)
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


def test_the_light_is_recorded_and_checked(tmp_path, cal):
    assert cal.light is None  # calibrate alone does not know it
    screen = dataclasses.replace(cal, light="screen")
    back = load_calibration(screen.save(tmp_path / "cal.npz"))
    assert back.light == "screen" and back.to_record()["light"] == "screen"
    with np.load(tmp_path / "cal.npz", allow_pickle=False) as data:
        assert json.loads(str(data["metadata"]))["light"] == "screen"
    with pytest.raises(CalibrationInputError, match="record 'light' must be one of jig, screen, sheets, not 'sun'"):
        dataclasses.replace(cal, light="sun")
    _rewrite(tmp_path / "cal.npz", light="sun")
    with pytest.raises(CalibrationFileError, match=r"cal\.npz: .*record 'light' must be one of jig, screen, sheets"):
        load_calibration(tmp_path / "cal.npz")


def test_an_old_calibration_file_loads_with_its_light_unknown():
    from pathlib import Path

    from picamcal.analysis.verdicts import expected_accuracy

    path = Path(__file__).parent / "data" / "calibration_before_issue13.npz"
    with np.load(path, allow_pickle=False) as data:
        assert "light" not in json.loads(str(data["metadata"]))  # written before calibrations recorded their light
    old = load_calibration(path)
    assert old.light is None and old.to_record()["light"] is None
    # Its expected accuracy is that of every light's workflow, the jig's and the screen's.
    expected = expected_accuracy(old)
    assert expected["light"] is None and {"jig", "screen"} <= {w["calibration"] for w in expected["workflows"]}
