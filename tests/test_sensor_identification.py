"""The sensor of a frame that does not name it (picamera2's DNGs, headless dumps), and ``--sensor`` checked on every
command (issue 23).

A frame of the one registry sensor of its size is taken as that sensor, said once, and recorded; a size several
sensors share is not guessed; a slip of a registry name gets "did you mean"; a sensor outside the registry is kept,
with one warning, and its missing black level asks for a level or a dark frame, not for --sensor.
"""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from picamcal import CalibrationFileError, PicamcalWarning, RawFormatError, calibrate, load_calibration, read_raw
from picamcal.calibrate import calibrate_in_situ
from picamcal.cli import main
from picamcal.raw import RawImage, to_picamera2, write_dng, write_npz
from picamcal.raw.model import require_black_level
from picamcal.simulate import make_camera, simulate_references

#: What PiDNG's Picamera2Camera writes as Make and Model (UniqueCameraModel too): nothing names the sensor.
PIDNG = {"make": "RaspberryPi", "model": "PiDNG / PiCamera2"}
SIZE_NOTE = "do not name their sensor"
#: The registry sensors whose full-resolution mode is 1920x1080, in registry order.
FULL_HD = ["imx290", "imx462", "se327m12", "imx327", "imx662"]


@pytest.fixture(scope="module")
def refs() -> dict[str, RawImage]:
    """The simulator's IMX219 references at 410 x 308: 8 times that is the full 3280 x 2464, 4 times its 2x2 binned
    1640 x 1232 mode."""
    return simulate_references(make_camera("imx219", size=(410, 308)), seed=1)


def enlarged(raw: RawImage, factor: int) -> np.ndarray:
    """``raw``'s mosaic with each site of the 2x2 Bayer block repeated ``factor`` x ``factor`` times: a full-size frame
    from a small simulation (simulating 8 MP takes seconds; the size, not the content, is what is identified)."""
    height, width = raw.bayer.shape
    sites = raw.bayer.reshape(height // 2, 2, width // 2, 2)
    return np.repeat(np.repeat(sites, factor, axis=0), factor, axis=2).reshape(height * factor, width * factor)


def pidng(path: Path, raw: RawImage, factor: int = 1, sensor: str | None = None) -> Path:
    """``raw``, enlarged, written the way picamera2 writes DNGs through PiDNG: Make "RaspberryPi", Model and
    UniqueCameraModel "PiDNG / PiCamera2", no sensor name anywhere (unless ``sensor`` is given)."""
    meta = {**PIDNG, "exposure_time_s": raw.metadata["exposure_time_s"]}
    frame = RawImage(enlarged(raw, factor), raw.pattern, raw.black_level, raw.white_level, raw.bit_depth, sensor, meta)
    return write_dng(path, frame)


def picamcal(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", "from picamcal.cli import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def size_notes(caught: list[warnings.WarningMessage]) -> list[str]:
    return [str(w.message) for w in caught if SIZE_NOTE in str(w.message)]


def test_a_picamera2_dng_of_the_full_imx219_size_is_read_as_the_imx219(refs, tmp_path):
    path = pidng(tmp_path / "white.dng", refs["white"], 8)
    assert b"imx219" not in path.read_bytes().lower()  # the file does not name its sensor anywhere
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        raw = read_raw(path)
    assert (raw.width, raw.height, raw.sensor) == (3280, 2464, "imx219")
    assert raw.metadata["sensor_source"] == "size" and raw.metadata["sensor_known"] is True
    assert raw.metadata["model"] == "PiDNG / PiCamera2" and raw.black_level == (64.0,) * 4  # the file's own level
    assert size_notes(caught) == [
        "frames of 3280x2464 that do not name their sensor are taken as the imx219, the one sensor of that size "
        "(give --sensor if it is another)"
    ]
    assert [w for w in caught if SIZE_NOTE not in str(w.message)] == []


def test_a_binned_mode_only_one_sensor_has_is_that_sensor_in_every_format(refs, tmp_path):
    """Read through read_raw, whatever the format: a DNG, picamcal's .npz and a headless dump of 1640 x 1232."""
    white = refs["white"]
    frame = RawImage(enlarged(white, 4), white.pattern, white.black_level, white.white_level, white.bit_depth)
    dng = pidng(tmp_path / "white.dng", white, 4)
    npz = write_npz(tmp_path / "white.npz", frame)
    dump = tmp_path / "white.raw"
    dump.write_bytes(to_picamera2(frame)[0].tobytes())
    for path, options in ((dng, {}), (npz, {}), (dump, {"raw_format": "SBGGR10_CSI2P", "size": (1640, 1232)})):
        with pytest.warns(PicamcalWarning, match="frames of 1640x1232 that do not name their sensor are taken as the "):
            raw = read_raw(path, **options)
        assert raw.sensor == "imx219" and raw.metadata["sensor_source"] == "size", path.name
        np.testing.assert_array_equal(raw.bayer, frame.bayer)
    # The headless dump records no black level: the sensor's, from the registry (64 DN at 10 bits), not NaN.
    assert raw.black_level == (64.0,) * 4 and raw.metadata["black_level_source"] == "registry"


def test_a_file_that_names_its_sensor_keeps_it(refs, tmp_path):
    path = pidng(tmp_path / "white.dng", refs["white"], 4, sensor="imx708")  # 1640 x 1232, the IMX219's binned size
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        raw = read_raw(path)
    assert raw.sensor == "imx708" and "sensor_source" not in raw.metadata and size_notes(caught) == []


def test_a_given_sensor_is_taken_over_the_size(refs, tmp_path):
    path = pidng(tmp_path / "white.dng", refs["white"], 4)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        other = read_raw(path, sensor="imx298")
        named = read_raw(path, sensor="IMX-219")
    assert (other.sensor, other.metadata["sensor_known"]) == ("imx298", False) and "sensor_source" not in other.metadata
    assert (named.sensor, named.metadata["sensor_known"]) == ("imx219", True)
    # read_raw names no sensor outside the registry in a warning: the command line does, once for all the files.
    assert caught == []
    with pytest.raises(RawFormatError) as info:
        read_raw(path, sensor="imx2l9")
    assert str(info.value) == f"{path}: unknown sensor 'imx2l9'; did you mean imx219?"


def test_a_sensor_taken_from_the_size_gives_way_to_one_a_file_or_the_calibration_names(refs, tmp_path):
    path = pidng(tmp_path / "white.dng", refs["white"], 4)
    with pytest.warns(PicamcalWarning, match="taken as the imx219"):
        guessed = read_raw(path)
    # Calibrated with --sensor imx298: the same frames, read without it, still fit the calibration.
    cal = calibrate(white=read_raw(path, sensor="imx298"))
    assert cal.sensor == "imx298"
    cal.check_compatible(guessed)
    named = pidng(tmp_path / "named.dng", refs["black"], 4, sensor="imx708")
    with pytest.raises(CalibrationFileError, match="sensor imx708, calibration is for imx298"):
        cal.check_compatible(read_raw(named))  # a frame that names another sensor does not
    # A dark frame that names its sensor, with a white whose sensor was taken from its size: the named one.
    assert calibrate(white=guessed, black=read_raw(named)).sensor == "imx708"


def test_an_in_situ_calibration_of_a_white_that_does_not_name_its_sensor_has_the_jigs(refs):
    jig = calibrate(**{role: refs[role] for role in ("white", "red", "green", "blue")})
    white = refs["white"]
    unnamed = RawImage(white.bayer, white.pattern, white.black_level, white.white_level, white.bit_depth)
    assert jig.sensor == "imx219" and calibrate_in_situ(unnamed, jig).sensor == "imx219"


def test_a_size_several_sensors_share_is_not_guessed(tmp_path):
    dump = tmp_path / "frame.raw"
    dump.write_bytes(bytes(1920 * 3 // 2 * 1080))  # a zero 1920 x 1080 SRGGB12_CSI2P frame, 2880 bytes a row
    headless = {"raw_format": "SRGGB12_CSI2P", "size": (1920, 1080)}
    with pytest.warns(PicamcalWarning) as caught:
        raw = read_raw(dump, **headless)
    assert raw.sensor is None and raw.metadata["sensor_candidates"] == FULL_HD
    assert size_notes(caught) == [
        "frames of 1920x1080 that do not name their sensor could be from the imx290, imx462, se327m12, imx327 or "
        "imx662: give --sensor NAME to say which"
    ]
    with pytest.raises(RawFormatError) as info:
        require_black_level(raw)  # where a black level is needed, the error lists them too
    assert str(info.value) == (
        f"{dump}: no black level: the file records none, and a 1920x1080 frame could be from the imx290, imx462, "
        "se327m12, imx327 or imx662; give --sensor NAME (one of them) or --black-level N"
    )
    told = read_raw(dump, **headless, sensor="imx462")
    assert told.sensor == "imx462" and told.black_level == (240.0,) * 4  # imx462.json 3840 on the 16-bit scale


def test_a_monochrome_variant_is_not_chosen_by_size(tmp_path):
    mosaic = np.random.default_rng(3).integers(60, 1023, (1088, 1456), dtype=np.uint16)
    path = write_npz(tmp_path / "gs.npz", RawImage(mosaic, "BGGR", 60, 1023, 10))
    with pytest.warns(PicamcalWarning, match="taken as the imx296, the one sensor"):
        assert read_raw(path).sensor == "imx296"  # the Global Shutter Camera, not the imx296_mono


# ---------------------------------------------------------------------------------------------- the command line
def one_error_line(capsys, argv: list[str]) -> str:
    """``main(argv)`` in this process, which must fail: its one stderr line."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("picamcal: error: "), lines
    return lines[0]


@pytest.mark.parametrize(
    "argv",
    [
        ["calibrate", "--white", "white.dng"],
        ["correct", "cal.npz", "frame.dng", "--out", "out"],
        ["inspect", "frame.dng"],
        ["apply-tuning", "tuning.json", "frame.dng", "--out", "isp.tiff"],
    ],
    ids=lambda argv: argv[0],
)
def test_every_command_that_reads_raw_files_refuses_a_slip_of_a_sensor_name(argv, tmp_path, monkeypatch, capsys):
    """Refused as the options are read, before any file is: the files named need not exist."""
    monkeypatch.chdir(tmp_path)
    line = one_error_line(capsys, [*argv, "--sensor", "imx2l9"])
    assert line == (
        "picamcal: error: Invalid value for --sensor: unknown sensor 'imx2l9'; did you mean imx219? "
        f"(see picamcal {argv[0]} --help)"
    )
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["simulate", "demo"])
def test_the_simulating_commands_name_the_sensor_a_slip_meant(command, tmp_path, capsys):
    """They need a registry sensor (to simulate it), so any other name is refused, a slip with "did you mean"."""
    line = one_error_line(capsys, [command, "--sensor", "imx2l9", "--size", "96x64", "--out", str(tmp_path / "out")])
    assert line.endswith("did you mean imx219?") and "unknown sensor 'imx2l9'" in line
    assert not (tmp_path / "out").exists()


def test_a_sensor_outside_the_registry_is_warned_of_once_for_all_the_files(refs, tmp_path, capsys):
    paths = [pidng(tmp_path / f"{role}.dng", refs[role]) for role in ("white", "red")]  # 410 x 308: no registry size
    with pytest.raises(SystemExit) as exit_:
        main(["inspect", *map(str, paths), "--sensor", "IMX298", "--json"])
    assert exit_.value.code == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        "picamcal: warning: sensor 'imx298' is not in picamcal's registry: picamcal knows nothing of it (no black "
        "level, no stock tuning file); if it is the imx296 or imx290, give that name"
    ]
    assert captured.out.count('"sensor": "imx298"') == 2


def test_a_sensor_outside_the_registry_asks_for_a_black_level_or_a_dark_frame(refs, tmp_path, capsys):
    dump = tmp_path / "white.raw"
    dump.write_bytes(to_picamera2(refs["white"])[0].tobytes())
    argv = ["calibrate", "--white", str(dump), "--raw-format", "SBGGR10_CSI2P", "--size", "410x308"]
    line = one_error_line(capsys, [*argv, "--sensor", "imx298", "--out", str(tmp_path / "cal.npz")])
    assert line.startswith(
        f"picamcal: error: {dump}: no black level: the file records none, and picamcal does not know the black level "
        "of the imx298, a sensor outside its registry; give --black-level N or a dark frame (--black FILE) (after 1 "
        "warning(s): sensor 'imx298' is not in picamcal's registry"
    )
    assert not (tmp_path / "cal.npz").exists()


def test_a_headless_dump_of_a_size_several_sensors_share_lists_them_where_its_black_level_is_needed(tmp_path, capsys):
    dump = tmp_path / "white.raw"
    dump.write_bytes(bytes(1920 * 3 // 2 * 1080))
    argv = ["calibrate", "--white", str(dump), "--raw-format", "SRGGB12_CSI2P", "--size", "1920x1080"]
    line = one_error_line(capsys, [*argv, "--out", str(tmp_path / "cal.npz")])
    assert f"{dump}: no black level" in line and "could be from the imx290, imx462, se327m12, imx327 or imx662" in line
    assert "give --sensor NAME (one of them), --black-level N or a dark frame (--black FILE)" in line


@pytest.mark.slow
def test_calibrate_of_a_folder_of_picamera2_dngs_records_the_imx219_with_one_note_and_exports_tuning(refs, tmp_path):
    folder = tmp_path / "captures"
    folder.mkdir()
    for role in ("white", "red", "green", "blue"):
        pidng(folder / f"{role}.dng", refs[role], 8)
    cal = tmp_path / "cal.npz"
    result = picamcal("calibrate", str(folder), "--out", str(cal))
    assert result.returncode == 0, result.stderr
    notes = [line for line in result.stderr.splitlines() if SIZE_NOTE in line]
    assert notes == [  # one line for the four files
        "picamcal: warning: frames of 3280x2464 that do not name their sensor are taken as the imx219, the one sensor "
        "of that size (give --sensor if it is another)"
    ]
    assert f"wrote {cal}: imx219 3280x2464 BGGR" in result.stderr
    assert load_calibration(cal).sensor == "imx219"
    # The calibration says its sensor: the stock tuning files are the base, with no option.
    exported = picamcal("export-tuning", str(cal), "--out", str(tmp_path / "tuning"))
    assert exported.returncode == 0, exported.stderr
    assert sorted(p.name for p in (tmp_path / "tuning").iterdir()) == ["imx219_pisp.json", "imx219_vc4.json"]
