"""Acquisition: auto-exposure, the captured run against the simulator, resuming, bad input, and the thin adapters.

The simulated camera (SimCamera + SimIlluminator) runs the real acquisition code everywhere; picamera2 and the
CircuitPython NeoPixel library are replaced by stand-ins only to check the adapters' wiring (the hardware is the
one place a fake is allowed).
"""

from __future__ import annotations

import errno
import json
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from picamcal import calibrate, read_raw
from picamcal._atomic import atomic_path
from picamcal.acquire import acquisition
from picamcal.acquire.acquisition import (
    AcquisitionError,
    AcquisitionInterrupted,
    acquire,
    load_manifest,
    open_rig,
    read_manifest,
)
from picamcal.acquire.base import IlluminatorError
from picamcal.acquire.cameras import CameraError, Picamera2Camera, SimCamera
from picamcal.acquire.illuminators import GpioIlluminator, ManualIlluminator, SimIlluminator, open_illuminator
from picamcal.errors import OutputError, PicamcalError
from picamcal.export.tuning import neutral_tuning
from picamcal.simulate import make_camera, simulate_references, simulate_target

SIZE = (320, 240)
SEED = 3
REFERENCES = ("white", "red", "green", "blue", "black")
STOCK_TUNING = Path(__file__).resolve().parent / "data" / "libcamera-tuning"


def sim_camera(**kwargs) -> SimCamera:
    return SimCamera("imx219", size=SIZE, seed=SEED, **kwargs)


def run(camera: SimCamera, folder: Path, **kwargs) -> dict:
    acquire(camera, camera.light, folder, settle_s=0, **kwargs)
    return load_manifest(folder)


def direct_camera(camera: SimCamera, record: dict):
    """The simulator's camera at the acquisition's frozen settings: make_camera with the same exposure fraction."""
    settings = record["settings"]
    fraction = camera.exposure_fraction(settings["exposure_time_us"], settings["analogue_gain"])
    assert 0.7 < fraction < 0.85  # what a 99.9th percentile at 80 % of the range means for this sensor
    return make_camera("imx219", size=SIZE, exposure=fraction)


def white_statistics(raw) -> tuple[float, int]:
    signal = raw.black_subtracted()
    return float(np.percentile(signal, 99.9)) / (raw.white_level - raw.black_level[0]), int(
        np.count_nonzero(raw.bayer >= raw.white_level)
    )


@pytest.fixture(scope="module")
def complete_run(tmp_path_factory) -> tuple[Path, dict, SimCamera]:
    folder = tmp_path_factory.mktemp("acq") / "run"
    camera = sim_camera()
    return folder, run(camera, folder), camera


# --- the acquired run against the simulator ----------------------------------------------------------------------


def test_acquired_frames_are_the_simulator_frames_bit_for_bit_and_calibrate_the_same(complete_run):
    folder, record, camera = complete_run
    direct = simulate_references(direct_camera(camera, record), seed=SEED)
    files = read_manifest(folder)
    assert list(files) == list(REFERENCES)
    for role, path in files.items():
        np.testing.assert_array_equal(read_raw(path).bayer, direct[role].bayer, err_msg=role)
    # "The same calibration" means every array of the calibration is identical, not merely close.
    acquired, simulated = calibrate(**files), calibrate(**direct)
    acquired_arrays, simulated_arrays = acquired.to_arrays(), simulated.to_arrays()
    assert acquired_arrays.keys() == simulated_arrays.keys()
    for name, array in acquired_arrays.items():
        np.testing.assert_array_equal(array, simulated_arrays[name], err_msg=name)


def test_the_manifest_names_each_file_its_role_the_settings_and_the_illuminator(complete_run):
    folder, record, _ = complete_run
    assert record["complete"] and record["roles"] == list(REFERENCES)
    assert record["camera"]["kind"] == "sim" and record["camera"]["size"] == list(SIZE)
    assert record["illuminator"] == {"kind": "sim"}
    assert record["settings"]["analogue_gain"] == 1.0 and isinstance(record["settings"]["exposure_time_us"], int)
    lights = {e["role"]: e["light"] for e in record["entries"]}
    assert lights == {
        "white": [255] * 3,
        "red": [255, 0, 0],
        "green": [0, 255, 0],
        "blue": [0, 0, 255],
        "black": [0] * 3,
    }
    for entry in record["entries"]:
        sidecar = json.loads((folder / entry["sidecar"]).read_text())
        assert sidecar["role"] == entry["role"] and sidecar["sha256"] == entry["sha256"]
        assert sidecar["settings"] == record["settings"]
        assert sidecar["metadata"]["exposure_time_s"] == pytest.approx(record["settings"]["exposure_time_us"] * 1e-6)
    raw = read_raw(folder / "white.dng")
    assert raw.metadata["role"] == "white" and raw.metadata["colour_gains"] == record["settings"]["colour_gains"]


def test_auto_exposure_lands_the_white_percentile_on_the_target_without_clipping(complete_run):
    folder, record, camera = complete_run
    camera.set_controls(camera.REFERENCE_EXPOSURE_US, 1.0)
    camera.light.set_rgb(255, 255, 255)
    _, clipped_at_start = white_statistics(camera.capture())
    assert clipped_at_start > 1000  # the starting 10 ms clips: the auto-exposure had to find the exposure
    fraction, clipped = white_statistics(read_raw(folder / "white.dng"))
    # The loop stops within 3 % (relative) of the target; the frame is the one it measured.
    assert fraction == pytest.approx(0.8, rel=0.03) and clipped == 0
    assert record["auto_exposure"]["white_fraction"] == pytest.approx(fraction, abs=1e-4)


def test_auto_exposure_follows_the_target_fraction(tmp_path):
    record = run(sim_camera(brightness=0.05), tmp_path / "run", target_fraction=0.5)
    fraction, clipped = white_statistics(read_raw(tmp_path / "run" / "white.dng"))
    assert fraction == pytest.approx(0.5, rel=0.03) and clipped == 0
    assert record["settings"]["exposure_time_us"] > 40_000  # a dim light needs a longer exposure than 10 ms


def test_gain_is_raised_only_beyond_the_longest_exposure(tmp_path):
    record = run(sim_camera(brightness=0.01), tmp_path / "run", max_exposure_s=0.1)
    assert record["settings"]["exposure_time_us"] == 100_000
    # 100 ms gives a tenth of full scale; the gain makes up the rest (5 %: percentile versus noiseless peak).
    assert record["settings"]["analogue_gain"] == pytest.approx(0.8 / 0.1, rel=0.05)


@pytest.mark.parametrize(
    ("brightness", "message"),
    [
        (
            1000.0,
            r"the white clips .* even at the shortest exposure and lowest gain \(100 µs at gain 1\): dim the light",
        ),
        (1e-5, r"the white is too dark .* highest gain \(1000000 µs at gain 16; 80 % wanted\): brighten the light"),
    ],
)
def test_a_light_out_of_the_cameras_reach_is_refused_with_what_to_change(tmp_path, brightness, message):
    with pytest.raises(AcquisitionError, match=message):
        run(sim_camera(brightness=brightness), tmp_path / "run")
    assert list((tmp_path / "run").iterdir()) == []  # nothing is frozen or captured


# --- extras, interruption and resuming ---------------------------------------------------------------------------


def test_extras_prompt_before_each_and_use_the_frozen_settings(tmp_path):
    with open_rig("sim", "sim", size=SIZE, seed=SEED) as rig:
        asked = []

        def prompt(message):
            asked.append(message)
            return rig.prompt(message)  # the simulated user puts the colour-wheel target in front

        acquire(rig.camera, rig.illuminator, tmp_path, extras=["target", "target-2"], settle_s=0, prompt=prompt)
        camera = rig.camera
    assert asked == [
        "Put the target in front of the camera and press Enter",
        "Put the target-2 in front of the camera and press Enter",
    ]
    record = load_manifest(tmp_path)
    assert [e["role"] for e in record["entries"]] == [*REFERENCES, "target", "target-2"]
    assert [e["extra"] for e in record["entries"]] == [False] * 5 + [True] * 2
    assert list(read_manifest(tmp_path)) == list(REFERENCES)
    assert read_manifest(tmp_path, extras=True)["target"] == tmp_path / "target.dng"
    target, _ = simulate_target(direct_camera(camera, record), seed=SEED)
    np.testing.assert_array_equal(read_raw(tmp_path / "target.dng").bayer, target.bayer)


def centre_mean(path: Path) -> np.ndarray:
    """The black-subtracted mean of each 2x2 site over the central quarter of a frame (DN)."""
    raw = read_raw(path)
    signal = raw.black_subtracted()[60:180, 80:240]
    return np.array([signal[k // 2 :: 2, k % 2 :: 2].mean(dtype=np.float64) for k in range(4)])


def test_extra_colours_are_captured_after_the_five_at_the_frozen_settings(tmp_path, complete_run):
    colours = {"cyan": (0, 255, 255), "Amber": (255, 191, 0)}
    record = run(sim_camera(), tmp_path, colours=colours)
    assert record["roles"] == [*REFERENCES, "colour_cyan", "colour_amber"] and record["complete"]
    assert record["colours"] == {"colour_cyan": [0, 255, 255], "colour_amber": [255, 191, 0]}
    entries = {e["role"]: e for e in record["entries"]}
    assert entries["colour_amber"]["file"] == "colour_amber.dng" and entries["colour_amber"]["light"] == [255, 191, 0]
    assert not any(e["extra"] for e in record["entries"])  # references, not test images
    assert list(read_manifest(tmp_path)) == [*REFERENCES, "colour_cyan", "colour_amber"]
    # The five are the frames of a run without colours: same frozen settings, same noise streams.
    reference_folder, reference_record, _ = complete_run
    assert record["settings"] == reference_record["settings"]
    for role in REFERENCES:
        np.testing.assert_array_equal(
            read_raw(tmp_path / f"{role}.dng").bayer, read_raw(reference_folder / f"{role}.dng").bayer, err_msg=role
        )
    # Light adds: cyan is green plus blue, amber red plus 191/255 of green. Each mean is over 19200 pixels of a few
    # hundred DN, so shot and read noise move it by well under 0.5 %.
    mean = {role: centre_mean(tmp_path / f"{role}.dng") for role in (*REFERENCES, "colour_cyan", "colour_amber")}
    np.testing.assert_allclose(mean["colour_cyan"], mean["green"] + mean["blue"], rtol=0.005)
    np.testing.assert_allclose(mean["colour_amber"], mean["red"] + 191 / 255 * mean["green"], rtol=0.005)


class _FailsOnCyan(SimIlluminator):
    """A device that stops answering at the extra colour."""

    def set_rgb(self, red, green, blue):
        if (red, green, blue) == (0, 255, 255):
            raise IlluminatorError("no answer from the illuminator on /dev/ttyACM0")
        super().set_rgb(red, green, blue)


def test_a_run_with_colours_resumes_with_the_colours_it_planned(tmp_path):
    camera = sim_camera(light=_FailsOnCyan())
    with pytest.raises(IlluminatorError, match="white, red, green, blue, black captured and kept"):
        acquire(camera, camera.light, tmp_path, colours={"cyan": (0, 255, 255)}, settle_s=0)
    assert load_manifest(tmp_path)["roles"][-1] == "colour_cyan"
    with pytest.raises(
        AcquisitionError, match=r"its colour cyan is \(0, 255, 255\), not \(0, 255, 254\); give --colour"
    ):
        run(sim_camera(), tmp_path, colours={"cyan": (0, 255, 254)})
    again = _CountingSimCamera("imx219", size=SIZE, seed=SEED)
    acquire(again, again.light, tmp_path, settle_s=0)  # the colour need not be given again
    record = load_manifest(tmp_path)
    assert again.captures == 1 and record["complete"] and record["entries"][-1]["light"] == [0, 255, 255]
    # A colour added on a re-run is planned after those before it.
    record = run(sim_camera(), tmp_path, colours={"cyan": (0, 255, 255), "magenta": (255, 0, 255)})
    assert record["roles"][-2:] == ["colour_cyan", "colour_magenta"] and record["complete"]


@pytest.mark.parametrize(
    ("colours", "message"),
    [
        ({"cyan": (0, 256, 0)}, "R, G and B must be whole numbers from 0 to 255"),
        ({"cyan": (0, 0.5, 0)}, "R, G and B must be whole numbers from 0 to 255"),
        ({"cy an": (0, 255, 255)}, "the name must be 1 to 40 letters, digits or '-'"),
        ({"cyan_2": (0, 255, 255)}, "the name must be 1 to 40 letters, digits or '-'"),
        ({"Black": (1, 1, 1)}, "Black is a reference already"),
        ({"cyan": (0, 255, 255), "CYAN": (0, 250, 250)}, "the colour CYAN is given twice"),
    ],
)
def test_bad_colours_are_refused_before_anything_is_written(tmp_path, colours, message):
    camera = sim_camera()
    with pytest.raises(PicamcalError, match=message):
        acquire(camera, camera.light, tmp_path / "run", colours=colours, settle_s=0)
    assert not (tmp_path / "run").exists()


class _FailsOnGreen(SimIlluminator):
    """A device that stops answering at the third colour."""

    def set_rgb(self, red, green, blue):
        if (red, green, blue) == (0, 255, 0):
            raise IlluminatorError("no answer from the illuminator on /dev/ttyACM0")
        super().set_rgb(red, green, blue)


class _CountingSimCamera(SimCamera):
    captures = 0

    def capture(self):
        self.captures += 1
        return super().capture()


def test_a_device_that_stops_answering_keeps_the_frames_and_a_rerun_resumes(tmp_path, complete_run):
    folder = tmp_path / "run"
    camera = sim_camera(light=_FailsOnGreen())
    with pytest.raises(IlluminatorError) as failure:
        acquire(camera, camera.light, folder, settle_s=0)
    message = str(failure.value)
    assert message.startswith("no answer from the illuminator on /dev/ttyACM0; white, red captured and kept")
    assert message.endswith("run the same command again to resume")
    record = load_manifest(folder)
    assert [e["role"] for e in record["entries"]] == ["white", "red"] and not record["complete"]
    white_sha = record["entries"][0]["sha256"]

    again = _CountingSimCamera("imx219", size=SIZE, seed=SEED)
    acquire(again, again.light, folder, settle_s=0)
    assert again.captures == 3  # green, blue and black: no new auto-exposure, white and red kept
    record = load_manifest(folder)
    assert record["complete"] and [e["role"] for e in record["entries"]] == list(REFERENCES)
    assert record["entries"][0]["sha256"] == white_sha
    reference_folder = complete_run[0]
    for role in REFERENCES:  # the same frames as the run that was never interrupted
        np.testing.assert_array_equal(
            read_raw(folder / f"{role}.dng").bayer, read_raw(reference_folder / f"{role}.dng").bayer
        )


def test_ctrl_c_at_a_prompt_keeps_the_frames_and_a_rerun_captures_only_the_rest(tmp_path):
    def interrupt(message):
        raise KeyboardInterrupt

    with open_rig("sim", "sim", size=SIZE, seed=SEED) as rig:
        with pytest.raises(AcquisitionInterrupted, match=r"interrupted; white, red, green, blue, black captured"):
            acquire(rig.camera, rig.illuminator, tmp_path, extras=["target"], settle_s=0, prompt=interrupt)
    record = load_manifest(tmp_path)
    assert len(record["entries"]) == 5 and not record["complete"] and record["roles"][-1] == "target"
    with open_rig("sim", "sim", size=SIZE, seed=SEED) as rig:
        acquire(rig.camera, rig.illuminator, tmp_path, extras=["target"], settle_s=0, prompt=rig.prompt)
    record = load_manifest(tmp_path)
    assert record["complete"] and [e["role"] for e in record["entries"]][-1] == "target"


def test_a_full_disk_is_reported_and_the_written_frames_are_kept(tmp_path, monkeypatch):
    real_write, calls = acquisition.write_dng, []

    def write_dng(path, raw, overwrite=True):  # the third frame's write finds the disk full, as the OS says it
        calls.append(1)
        if len(calls) == 3:
            with atomic_path(path, overwrite=overwrite):
                raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(path, raw, overwrite=overwrite)

    monkeypatch.setattr(acquisition, "write_dng", write_dng)
    camera = sim_camera()
    with pytest.raises(OutputError, match=r"the disk is full: free some space; white, red captured and kept"):
        acquire(camera, camera.light, tmp_path, settle_s=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "manifest.json",
        "red.dng",
        "red.json",
        "white.dng",
        "white.json",
    ]
    monkeypatch.setattr(acquisition, "write_dng", real_write)
    acquire(camera, camera.light, tmp_path, settle_s=0)
    assert load_manifest(tmp_path)["complete"]


def test_a_changed_frame_is_captured_again(tmp_path):
    record = run(sim_camera(), tmp_path)
    first = read_raw(tmp_path / "red.dng").bayer
    (tmp_path / "red.dng").write_bytes(b"not the frame")
    with pytest.warns(UserWarning, match="red.dng: missing or changed since it was captured"):
        again = run(sim_camera(), tmp_path)
    assert again["complete"]
    # The same frame again (its noise is keyed by the light), though not the same bytes: the DNG's capture time
    # is the time it was written, which may fall in another second.
    np.testing.assert_array_equal(read_raw(tmp_path / "red.dng").bayer, first)
    kept = {e["role"]: e["sha256"] for e in record["entries"] if e["role"] != "red"}
    assert {e["role"]: e["sha256"] for e in again["entries"] if e["role"] != "red"} == kept


def test_a_run_is_resumed_only_with_the_same_camera_and_illuminator_kind(tmp_path):
    run(sim_camera(), tmp_path)
    other = SimCamera("imx219", size=(160, 120), seed=SEED)
    with pytest.raises(AcquisitionError, match=r"cannot resume this run: it was started with another camera"):
        acquire(other, other.light, tmp_path, settle_s=0)
    camera = sim_camera()
    with pytest.raises(AcquisitionError, match="started with the sim illuminator, not manual"):
        acquire(camera, ManualIlluminator(input_fn=lambda prompt: ""), tmp_path, settle_s=0)


def test_bad_folders_and_names_are_refused(tmp_path):
    (tmp_path / "white.dng").write_bytes(b"someone else's file")
    camera = sim_camera()
    with pytest.raises(AcquisitionError, match=r"holds white.dng but no manifest.json: use an empty folder"):
        acquire(camera, camera.light, tmp_path, settle_s=0)
    for name in ("white", "red_card", "a/b", "manifest", ""):
        with pytest.raises(AcquisitionError, match="extra name"):
            acquire(camera, camera.light, tmp_path / "new", extras=[name], settle_s=0)
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "manifest.json").write_text("{not json")
    with pytest.raises(AcquisitionError, match="corrupt manifest"):
        read_manifest(tmp_path / "bad")
    with pytest.raises(AcquisitionError, match="no acquisition manifest"):
        read_manifest(tmp_path)


def test_read_manifest_refuses_an_incomplete_run(tmp_path):
    camera = sim_camera(light=_FailsOnGreen())
    with pytest.raises(IlluminatorError):
        acquire(camera, camera.light, tmp_path, settle_s=0)
    with pytest.raises(AcquisitionError, match=r"incomplete \(no green, blue yet\): run picamcal acquire again"):
        read_manifest(tmp_path)


# --- rigs and illuminators ---------------------------------------------------------------------------------------


def test_the_sim_camera_goes_with_the_sim_illuminator_only():
    with pytest.raises(PicamcalError, match="the sim camera sees only the sim illuminator or a screen"):
        open_rig("sim", "manual")
    with pytest.raises(PicamcalError, match="the sim illuminator lights only the sim camera"):
        open_rig("picamera2", "sim")


def test_manual_illuminator_asks_for_each_new_colour():
    asked, said = [], []
    light = ManualIlluminator(input_fn=lambda prompt: asked.append(prompt) or "", output=said.append)
    light.set_rgb(255, 0, 0)
    light.set_rgb(255, 0, 0)
    light.set_rgb(0, 0, 0)
    light.set_rgb(0, 255, 0)
    light.close()
    assert asked == [
        "Set the light to red (255, 0, 0) and press Enter",
        "Turn the light off (0, 0, 0) and press Enter",
        "Set the light to green (0, 255, 0) and press Enter",
    ]
    assert said == ["You can turn the light off now."] and light.describe() == {"kind": "manual"}
    light = open_illuminator("manual", colours={"amber": (255, 191, 0)}, input_fn=asked.append)
    light.set_rgb(255, 191, 0)
    light.set_rgb(1, 2, 3)
    assert asked[-2:] == [
        "Set the light to amber (255, 191, 0) and press Enter",
        "Set the light to the colour (1, 2, 3) and press Enter",
    ]

    def closed_input(prompt):
        raise EOFError

    with pytest.raises(IlluminatorError, match="no answer"):
        ManualIlluminator(input_fn=closed_input).set_rgb(0, 0, 255)
    with pytest.raises(IlluminatorError, match="three whole numbers 0-255"):
        light.set_rgb(256, 0, 0)


def test_gpio_illuminator_without_the_library_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "board", None)
    monkeypatch.setitem(sys.modules, "neopixel", None)
    with pytest.raises(
        IlluminatorError, match=r"CircuitPython NeoPixel library: on a Raspberry Pi install picamcal\[pi\]"
    ):
        open_illuminator("gpio")


class _FakePixels:
    def __init__(self, pin, count, *, brightness, auto_write, pixel_order):
        self.pin, self.count, self.order, self.auto_write = pin, count, pixel_order, auto_write
        self.log: list = []

    def fill(self, colour):
        self.log.append(("fill", colour))

    def show(self):
        self.log.append("show")

    def deinit(self):
        self.log.append("deinit")


def test_gpio_illuminator_drives_the_neopixel(monkeypatch):
    board = types.SimpleNamespace(D18="pin 18", D12="pin 12")
    neopixel = types.SimpleNamespace(NeoPixel=_FakePixels, GRB="grb", RGB="rgb")
    monkeypatch.setitem(sys.modules, "board", board)
    monkeypatch.setitem(sys.modules, "neopixel", neopixel)
    light = open_illuminator("gpio:d12")
    assert isinstance(light, GpioIlluminator)
    pixels = light._pixels
    assert (pixels.pin, pixels.count, pixels.order, pixels.auto_write) == ("pin 12", 1, "grb", False)
    light.set_rgb(255, 0, 0)
    light.close()
    assert pixels.log == [("fill", (255, 0, 0)), "show", ("fill", (0, 0, 0)), "show", "deinit"]
    assert light.describe() == {"kind": "gpio", "pin": "D12", "count": 1, "pixel_order": "GRB"}
    with pytest.raises(IlluminatorError, match="the board has no pin D99"):
        open_illuminator("gpio:D99")


def test_open_illuminator_names(monkeypatch):
    assert isinstance(open_illuminator("sim"), SimIlluminator)
    assert isinstance(open_illuminator("manual"), ManualIlluminator)
    opened = []
    serial = types.ModuleType("picamcal.acquire.serial_illuminator")
    serial.open_serial_illuminator = lambda spec: opened.append(spec) or "serial illuminator"
    monkeypatch.setitem(sys.modules, "picamcal.acquire.serial_illuminator", serial)
    assert open_illuminator("serial:/dev/ttyACM0") == "serial illuminator"
    assert open_illuminator("serial") == "serial illuminator"
    assert opened == ["serial:/dev/ttyACM0", "serial"]
    with pytest.raises(PicamcalError, match=r"unknown illuminator 'usb' \(expected serial, serial:PORT"):
        open_illuminator("usb")


# --- picamera2 (the adapter runs on the real picamera2 and the virtual camera: test_virtualcam_pi_path.py) -------


def test_picamera2_camera_without_picamera2_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "picamera2", None)
    with pytest.raises(CameraError, match=r"picamera2 is not installed: on a Raspberry Pi install picamcal\[pi\]"):
        Picamera2Camera()


@pytest.mark.parametrize("target", ["vc4", "pisp"])
def test_neutral_tuning_of_the_stock_files(target):
    path = STOCK_TUNING / target / "imx219.json"
    stock = json.loads(path.read_text())
    tuning = neutral_tuning(stock)
    cells = {"vc4": 16 * 12, "pisp": 32 * 32}[target]
    alsc = next(a["rpi.alsc"] for a in tuning["algorithms"] if "rpi.alsc" in a)
    assert alsc["n_iter"] == 0 and alsc["luminance_lut"] == [1.0] * cells
    assert [len(c["table"]) for c in alsc["calibrations_Cb"]] == [cells]
    assert [next(iter(a)) for a in tuning["algorithms"]] == [next(iter(a)) for a in stock["algorithms"]]
    assert stock == json.loads(path.read_text())  # the stock tuning is not modified
