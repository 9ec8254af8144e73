"""``picamcal correct --processed`` of images from every sensor mode, crop and zoom (issue 30, item 3), through the
real picamera2 on the virtual camera: an IMX219 at its full size (its four modes are the registry's), a Pi 5 (pisp)
and a Pi 4 (vc4), with a full-resolution calibration and the tuning exported from it.

Each image is the camera's own processed stream of the white (its ISP: the exported lens shading for the mode, the
crop to the ScalerCrop, the scaling, the colour matrix and the gamma curve), saved as an 8-bit PNG. Before the fix an
image of the 640x480 mode came out with corners at 0.44 of its centre, and the 1920x1080 one was refused asking for
a crop option that ``correct`` did not have. Now each is flat within 2 % with the option that places it, or refused
in one line naming that option.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from picamcal import calibrate
from picamcal.calibration.resample import resample_calibration
from picamcal.export.tuning import export_tuning, load_tuning, neutral_tuning, save_tuning, stock_tuning_path
from picamcal.geometry import default_scaler_crop, named_mode
from picamcal.simulate import make_camera, simulate_references
from test_virtualcam_picamera2 import run_script

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        importlib.util.find_spec("picamera2") is None,
        reason="picamera2 is not installed (pip install 'picamcal[virtual-camera]')",
    ),
]

PLATFORMS = {"pisp": "pisp", "vc4": "bcm2835"}

# Each image: the raw stream's size (which picks the sensor mode), the main stream's size and a ScalerCrop to set
# (None: libcamera's default for the stream).
IMAGES = {
    "full": [[3280, 2464], [820, 616], None],
    "binned": [[1640, 1232], [820, 616], None],
    "1920x1080": [[1920, 1080], [960, 540], None],
    "640x480": [[640, 480], [640, 480], None],
    "binned 16:9": [[1640, 1232], [960, 540], None],
    "binned 2x zoom": [[1640, 1232], [820, 616], [820, 616, 1640, 1232]],
}

CAPTURE = """
import json, sys
import numpy as np
from PIL import Image
from picamera2 import Picamera2
from picamcal.raw.npz import write_npz
from picamcal.raw.picamera2 import capture_raw

images, fixed_gains = json.loads(sys.argv[2]), json.loads(sys.argv[3])
with open(sys.argv[1]) as file:
    by_mode = json.load(file)["picamcal"]["colour_gains_by_mode"]
picam2 = Picamera2(tuning=sys.argv[1])
out = {}
for name, (raw, main, crop) in images.items():
    picam2.configure(
        picam2.create_still_configuration(main={"size": tuple(main), "format": "RGB888"}, raw={"size": tuple(raw)})
    )
    # The white balance frozen where it makes the calibration's white neutral at the centre in this mode: what
    # export-tuning prints per mode for its table; the raw white's own for a unity table (a PNG cannot say its gains,
    # so correct --processed keeps the centre's balance).
    sensor = picam2.camera_configuration()["sensor"]
    mode = f"{sensor['output_size'][0]}x{sensor['output_size'][1]}:{sensor['bit_depth']}"
    gains = tuple(fixed_gains or by_mode[mode])
    picam2.set_controls({"AwbEnable": False, "ColourGains": gains, "AeEnable": False, "ExposureTime": 9000})
    if crop:
        picam2.set_controls({"ScalerCrop": tuple(crop)})
    picam2.start()
    for _ in range(30):  # a frame with the controls in force
        with picam2.captured_request() as request:
            metadata = request.get_metadata()
            settled = np.allclose(metadata["ColourGains"], gains, rtol=1e-3) and metadata["ColourTemperature"] != 4500
            if settled and (crop is None or tuple(metadata["ScalerCrop"]) == tuple(crop)):
                Image.fromarray(request.make_array("main")[..., ::-1].copy()).save(f"{name}.png")  # B, G, R in memory
                break
    if name == "1920x1080":  # the raw frame too, for apply-tuning: picamera2 records the mode's crop
        write_npz("raw_1920x1080.npz", capture_raw(picam2))
    picam2.stop()
    sensor = picam2.camera_configuration()["sensor"]["output_size"]
    out[name] = {"scaler_crop": list(metadata["ScalerCrop"]), "sensor": list(sensor)}
picam2.close()
print(json.dumps(out))
"""


def cli(folder: Path, *args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "picamcal", *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, cwd=folder, timeout=600)


def corners_over_centre(rgb: np.ndarray) -> np.ndarray:
    h, w = rgb.shape[:2]
    a, b = h // 10, w // 10
    centre = rgb[h // 2 - a : h // 2 + a, w // 2 - b : w // 2 + b].reshape(-1, 3).mean(0)
    corners = [rgb[:a, :b], rgb[:a, -b:], rgb[-a:, :b], rgb[-a:, -b:]]
    return np.array([c.reshape(-1, 3).mean(0) / centre for c in corners])


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    """A full-resolution calibration of the virtual camera's optics (the simulator's, noiseless); for each platform the
    tuning exported from it (with its colour matrix) and the same with a unity lens shading table; and the calibration
    cut to the 1920x1080 mode's crop."""
    folder = tmp_path_factory.mktemp("processed_modes")
    cal = calibrate(**simulate_references(make_camera("imx219"), noise=False))
    cal.save(folder / "cal.npz")
    resample_calibration(cal, named_mode("imx219", "1920x1080")).save(folder / "cal_1920x1080.npz")
    for label, target in PLATFORMS.items():
        exported = export_tuning(cal, load_tuning(stock_tuning_path("imx219", target)), ccm=True)
        for algorithm in exported["algorithms"]:
            if "rpi.contrast" in algorithm:
                algorithm["rpi.contrast"]["ce_enable"] = 0  # a fixed gamma curve, which --tuning undoes
        save_tuning(folder / f"exported_{label}.json", exported)
        save_tuning(folder / f"unity_{label}.json", neutral_tuning(exported))
    # The white balance a camera with the unity table freezes on the white, measured at the centre (the central ninth,
    # where correct --processed takes an image's balance without its gains): the white's there, green over red and
    # blue. (calibration_colour_gains' central half left the centre 2.7 % red-short, and the unmixing then mixed 3.6 %
    # into the corners.)
    top, bottom, left, right = cal.centre_region
    red, green, blue = cal.white[top:bottom, left:right].reshape(-1, 3).mean(axis=0)
    return {"folder": folder, "gains": (float(green / red), float(green / blue))}


def capture(calibration: dict, platform: str, table: str, folder: Path) -> dict:
    """The camera's processed white in each mode, crop and zoom, through one tuning on one platform."""
    tuning = calibration["folder"] / f"{table}_{platform}.json"
    gains = list(calibration["gains"]) if table == "unity" else None
    result = run_script(
        folder,
        CAPTURE,
        f"--platform={platform}",
        "--sensor=imx219",
        args=(str(tuning), json.dumps(IMAGES), json.dumps(gains)),
    )
    assert result.returncode == 0, result.stderr
    return {
        "platform": platform,
        "table": table,
        "folder": folder,
        "tuning": tuning,
        "cal": calibration["folder"] / "cal.npz",
        "cropped_cal": calibration["folder"] / "cal_1920x1080.npz",
        "recorded": json.loads(result.stdout.strip().splitlines()[-1]),
    }


@pytest.fixture(scope="module", params=list(PLATFORMS))
def images(request, calibration, tmp_path_factory):
    """Through the unity table: the ISP leaves the optics' vignetting (corners near half the centre) and colour
    shading, and correct --processed divides out the calibration's flat field, so a misplaced image comes out far
    from flat. (Through the calibration's own table the image is flat already and a placement that is wrong for the
    field and the table alike cancels out.)"""
    return capture(calibration, request.param, "unity", tmp_path_factory.mktemp(f"images_{request.param}"))


@pytest.fixture(scope="module")
def exported_images(calibration, tmp_path_factory):
    """Through the table exported from the calibration, on a Pi 5: the ISP's gains sampled per mode, crop and zoom."""
    return capture(calibration, "pisp", "exported", tmp_path_factory.mktemp("exported_images"))


def corrected(images: dict, name: str, *options: str, image: str | None = None) -> np.ndarray:
    folder = images["folder"]
    out = folder / f"out_{name}_{'_'.join(options)}".replace(" ", "_").replace(":", "_").replace(",", "_")
    source = image or f"{name}.png"
    done = cli(folder, "correct", images["cal"], source, "--processed", "--tuning", images["tuning"], "--out", out,
               *options)  # fmt: skip
    assert done.returncode == 0, done.stderr
    return tifffile.imread(out / f"{Path(source).stem}.tiff")


def assert_flat(rgb: np.ndarray, what: str) -> None:
    ratios = corners_over_centre(rgb)
    worst = float(np.abs(ratios - 1).max())
    print(f"{what}: corners / centre {ratios.round(3).tolist()}, worst {worst:.2%}")
    # The figure, 2 %: a wrong placement is off by 10 % or more (the corners of the 640x480 mode's image
    # came out at 0.44 of the centre).
    assert worst < 0.02, (what, ratios.round(4).tolist())


def test_the_camera_said_what_libcamera_would(images):
    # The modes the raw stream picked, and the ScalerCrops libcamera gave: the whole mode for a 4:3 stream of a 4:3
    # mode, its centred 16:9 area for a 16:9 stream, the zoom as set.
    recorded = images["recorded"]
    assert {name: case["sensor"] for name, case in recorded.items()} == {
        name: raw for name, (raw, _, _) in IMAGES.items()
    }
    assert recorded["full"]["scaler_crop"] == [0, 0, 3280, 2464]
    assert recorded["1920x1080"]["scaler_crop"] == [680, 692, 1920, 1080]
    assert recorded["640x480"]["scaler_crop"] == [1000, 752, 1280, 960]
    assert recorded["binned 16:9"]["scaler_crop"] == [0, 310, 3280, 1844]
    assert default_scaler_crop(named_mode("imx219", "1640x1232"), (960, 540)) == (0, 310, 3280, 1844)
    assert recorded["binned 2x zoom"]["scaler_crop"] == [820, 616, 1640, 1232]


def mode_options(name: str) -> list[str]:
    raw, _, crop = IMAGES[name]
    return ["--sensor-mode", f"{raw[0]}x{raw[1]}", *(["--sensor-crop", ",".join(map(str, crop))] if crop else [])]


@pytest.mark.parametrize("name", list(IMAGES))
def test_each_mode_is_flat_with_the_sensor_mode_that_took_it(images, name):
    options = mode_options(name)
    assert_flat(corrected(images, name, *options), f"{images['platform']} unity table, {name} {' '.join(options)}")


@pytest.mark.parametrize("name", list(IMAGES))
def test_each_mode_is_flat_through_the_exported_table(exported_images, name):
    options = mode_options(name)
    assert_flat(corrected(exported_images, name, *options), f"pisp exported table, {name} {' '.join(options)}")


@pytest.mark.parametrize("name", ["1920x1080", "640x480", "binned 16:9", "binned 2x zoom"])
def test_the_sensor_crop_alone_places_each_image(images, name):
    # --sensor-crop: the sensor area the image shows (picamera2's ScalerCrop of the capture), the lens shading taken
    # for the calibration's own mode (its colour tables differ from the mode's by a constant, which the centre's
    # balance takes out).
    crop = images["recorded"][name]["scaler_crop"]
    what = f"{images['platform']} {name} --sensor-crop"
    assert_flat(corrected(images, name, "--sensor-crop", ",".join(map(str, crop))), what)


def test_full_field_images_need_no_option(images):
    for name in ("full", "binned"):
        assert_flat(corrected(images, name), f"{images['platform']} {name}, no option")


def assert_refused(images: dict, args: list, *expected: str) -> str:
    folder = images["folder"]
    out = folder / "refused"
    done = cli(folder, "correct", *args, "--processed", "--tuning", images["tuning"], "--out", out)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1, lines
    for text in expected:
        assert text in lines[0], lines[0]
    assert not out.exists() or not any(out.iterdir())  # nothing written
    return lines[0]


def test_an_image_nothing_places_is_refused_naming_the_option(images):
    cal = images["cal"]
    # A 16:9 image of a 4:3 calibration: which area it shows, no size can say.
    line = assert_refused(images, [cal, "1920x1080.png"], "aspect ratios differ", "--sensor-crop", "--sensor-mode")
    assert line.startswith("picamcal: error: 1920x1080.png: image is 960x540 but shows a 3280x2464 sensor area")
    # A 4:3 image of the 640x480 mode's very size: that mode's area, or the whole sensor scaled.
    line = assert_refused(images, [cal, "640x480.png"], "--sensor-mode 640x480", "--sensor-crop")
    assert "may come from the imx219's 640x480 mode (the 1280x960 area at (1000, 752))" in line
    # And the placement matters: the same image taken for the whole sensor (what correct --processed assumed before)
    # has its corners far off (measured 8 % to 53 %; the run 0.44 of the centre).
    wrong = corners_over_centre(corrected(images, "640x480", "--sensor-crop", "0,0,3280,2464"))
    print(f"{images['platform']} 640x480 taken for the whole sensor: corners / centre {wrong.round(3).tolist()}")
    assert np.abs(wrong - 1).max() > 0.1, wrong


def test_bad_geometry_is_one_line_and_nothing_written(images):
    cal = images["cal"]
    assert_refused(images, [cal, "full.png", "--sensor-crop", "3000,0,1000,1000"], "lies outside the 3280x2464 sensor")
    # A crop that does not match the image: an 820x616 image cannot show a 3280x1000 area.
    assert_refused(
        images, [cal, "full.png", "--sensor-crop", "0,0,3280,1000"], "image is 820x616 but shows a 3280x1000"
    )
    assert_refused(images, [cal, "full.png", "--sensor-mode", "1000x1000"], "the imx219 has no such mode", "640x480")
    # A ScalerCrop outside the mode it names: the stream shows only what its mode reads.
    assert_refused(
        images,
        [cal, "1920x1080.png", "--sensor-mode", "1920x1080", "--sensor-crop", "0,0,3280,2464"],
        "lies outside the sensor mode's crop (the 1920x1080 area at (680, 692)",
    )
    # A whole-field image and a calibration of the 1920x1080 mode's crop only: what would cover it is said.
    assert_refused(
        images,
        [images["cropped_cal"], "full.png", "--sensor-mode", "3280x2464"],
        "full.png: image does not match the calibration: it shows the sensor area 3280x2464 at (0, 0), outside the "
        "calibration's 1920x1080 at (680, 692): calibrate in a mode that covers it",
    )


def test_apply_tuning_records_the_mode_that_correct_processed_reads(images):
    # The emulated ISP on a raw frame of the 1920x1080 mode (picamera2 recorded its crop): its output says its mode
    # and area, so correct --processed needs no option (before, a 16:9 image of a 4:3 calibration was refused).
    folder = images["folder"]
    done = cli(folder, "apply-tuning", images["tuning"], "raw_1920x1080.npz", "--ccm", "--out", "isp_1920x1080.tiff")
    assert done.returncode == 0, done.stderr
    assert_flat(corrected(images, "isp", image="isp_1920x1080.tiff"), f"{images['platform']} apply-tuning 1920x1080")
