"""The sensor registry: every sensor Raspberry Pi's libcamera tunes, consistent entries, names found in free text."""

from __future__ import annotations

import warnings
from importlib import resources

import pytest

from picamcal._json import read_libcamera_yaml
from picamcal.errors import PicamcalError, PicamcalWarning
from picamcal.raw.model import PATTERNS
from picamcal.sensors import SENSORS, black_level_at, find_sensor_name, get_sensor, given_sensor, sensors_of_size

# rpi.black_level of Raspberry Pi's tuning files (raspberrypi/libcamera src/ipa/rpi/vc4/data/<name>.json), on the
# 16-bit scale: the numbers as published, so that the registry's conversion to native DN is what is checked.
TUNING_BLACK_16 = {
    "ov5647": 1024,
    "imx219": 4096,
    "imx477": 4096,
    "imx708": 4096,
    "imx296": 3840,
    "imx296_mono": 3840,
    "imx290": 3840,
    "imx462": 3840,
    "se327m12": 3840,
    "imx378": 4096,
    "imx519": 4096,
    "imx500": 4096,
    "imx283": 3200,
    "imx415": 3840,
    "imx335": 3200,
    "imx585": 3200,
    "imx585_mono": 3200,
    "imx662": 3200,  # black_level_func at analogue gain 1
    "ov64a40": 4096,
    "ov9281": 4096,
    "ov7251": 4096,
    "imx327": 3840,  # vc4/imx327.json (no pisp file)
    "vd55g1": 4096,
    "vd55g1_mono": 4096,
    "vd56g3": 4096,
    "vd56g3_mono": 4096,
}


def test_every_sensor_the_issue_names_is_known():
    wanted = {"ov5647", "imx219", "imx477", "imx708", "imx296", "imx290", "imx378", "imx519", "imx500", "imx283"}
    assert wanted | {"ov9281", "ov64a40"} <= set(SENSORS)
    assert set(TUNING_BLACK_16) == set(SENSORS)  # every entry has its published black level below


@pytest.mark.parametrize("name", sorted(SENSORS))
def test_black_levels_are_the_tuning_files_on_the_native_scale(name):
    sensor = SENSORS[name]
    # Powers of two apart, so exact: 4096 at 16 bits is 64 at 10 and 256 at 12.
    assert black_level_at(sensor, 16) == TUNING_BLACK_16[name]
    assert sensor.black_level == TUNING_BLACK_16[name] / 2 ** (16 - sensor.bit_depth)


@pytest.mark.parametrize("name", sorted(SENSORS))
def test_entries_are_consistent(name):
    sensor = SENSORS[name]
    assert sensor.name == name and name == name.lower()
    assert sensor.width % 2 == 0 and sensor.height % 2 == 0 and min(sensor.width, sensor.height) > 0
    for width, height in sensor.binned_modes:  # a binned mode of the whole array: smaller both ways, even
        assert width % 2 == 0 and height % 2 == 0 and width < sensor.width and height < sensor.height
        assert sensor.width / width == pytest.approx(sensor.height / height, rel=0.01)  # the whole field, not a crop
    assert 8 <= sensor.bit_depth <= 16 and 0 < sensor.black_level < sensor.white_level // 8
    assert 0.8 < sensor.pixel_pitch_um < 4.0
    assert (sensor.default_pattern is None) == sensor.monochrome
    assert sensor.monochrome or sensor.default_pattern in PATTERNS


def test_monochrome_sensors_are_marked():
    mono = {"ov9281", "ov7251", "imx296_mono", "imx585_mono", "vd55g1_mono", "vd56g3_mono"}
    assert {n for n, s in SENSORS.items() if s.monochrome} == mono


# Stock tuning files for one camera module rather than the sensor, with their own black level: Arducam's B0569
# (imx415_b0569.json, "vendor": "Arducam", "sku": "B0569"), tuned at 3200 where the IMX415's own file has 3840.
MODULE_BLACK_16 = {"imx415_b0569": 3200}


def registry_name(stem: str) -> str:
    """The registry entry a stock tuning file is for, from libcamera's file name: a variant's suffix (``_noir``,
    ``_wide``, ``_6mm``, ``_16mm``, ``_scientific``, ``_v1``, a module's SKU) is the sensor's; ``_mono`` is the
    monochrome entry where the registry has one of its own (``imx296_mono``), else the sensor's (``ov9281``)."""
    if stem in SENSORS:
        return stem
    base = stem.split("_")[0]
    return f"{base}_mono" if stem.endswith("_mono") and f"{base}_mono" in SENSORS else base


def stock_tuning_files() -> list:
    root = resources.files("picamcal") / "data" / "libcamera-tuning"
    return sorted(
        (f for target in root.iterdir() if target.is_dir() for f in target.iterdir() if f.name.endswith(".json")),
        key=lambda f: (f.parent.name, f.name),
    )


def published_black_level(tuning_file) -> int:
    # Two stock files have trailing commas: read as libcamera reads them.
    algorithms = read_libcamera_yaml(tuning_file, PicamcalError, "a tuning file")["algorithms"]
    level = next(a["rpi.black_level"] for a in algorithms if "rpi.black_level" in a)
    return level["black_level"] if "black_level" in level else level["black_level_func"][1]


def test_every_sensor_with_a_bundled_stock_tuning_file_has_a_registry_entry_with_its_black_level():
    """Each libcamera tuning file shipped in the package is for a registry sensor (monochrome for a ``_mono`` file),
    whose black level is the file's rpi.black_level (on its 16-bit scale; exact, powers of two apart)."""
    files = stock_tuning_files()
    checked = set()
    for tuning_file in files:
        stem = tuning_file.name.removesuffix(".json")
        if stem == "uncalibrated":  # libcamera's file for a sensor it has no tuning for
            continue
        name = registry_name(stem)
        assert name in SENSORS, f"{tuning_file.parent.name}/{tuning_file.name}: no registry entry {name}"
        assert SENSORS[name].monochrome == stem.endswith("_mono"), tuning_file.name
        expected = MODULE_BLACK_16.get(stem, black_level_at(SENSORS[name], 16))
        assert published_black_level(tuning_file) == expected, f"{tuning_file.parent.name}/{tuning_file.name}"
        checked.add(name)
    assert {"ov5647", "imx219", "imx477", "imx708"} <= checked  # the four the package has always shipped


@pytest.mark.parametrize(
    ("size", "names"),
    [
        ((3280, 2464), ("imx219",)),
        ((1640, 1232), ("imx219",)),  # its 2x2 binned mode, which no other sensor has
        ((2304, 1296), ("imx708",)),
        ((1456, 1088), ("imx296",)),  # not the imx296_mono: a colour sensor is what picamcal calibrates
        ((804, 704), ("vd55g1",)),
        ((4056, 3040), ("imx477", "imx378", "imx500")),
        ((2028, 1520), ("imx477", "imx378", "imx500")),
        # Cropped modes of the drivers count: the IMX219's and the OV5647's 1920x1080, the HQ camera's 1332x990.
        ((1920, 1080), ("ov5647", "imx219", "imx290", "imx462", "se327m12", "imx327", "imx662")),
        ((1332, 990), ("imx477",)),
        ((640, 480), ("ov5647", "imx219")),
        ((1280, 800), ()),  # the OV9281's: monochrome only
        ((320, 240), ()),
    ],
)
def test_the_sensors_of_a_frame_size(size, names):
    assert sensors_of_size(*size) == names


def test_a_frame_deeper_than_a_sensor_s_deepest_mode_is_not_its():
    """A 1920x1080 SBGGR10 dump may be the IMX219's crop, its most common source; a 12-bit one cannot (10 bits at
    most), and 16 bits is the Pi 5's container for any depth."""
    assert "imx219" in sensors_of_size(1920, 1080, 10)
    assert sensors_of_size(1920, 1080, 12) == ("imx290", "imx462", "se327m12", "imx327", "imx662")
    assert sensors_of_size(1920, 1080, 16) == sensors_of_size(1920, 1080)


@pytest.mark.parametrize(
    ("value", "name"),
    [
        ("imx219", "imx219"),
        ("IMX219", "imx219"),
        ("imx-219", "imx219"),
        (" imx 219 ", "imx219"),
        ("imx708_wide_noir", "imx708"),  # a variant's tuning file names the sensor
        ("imx477_16mm", "imx477"),
        ("imx296-mono", "imx296_mono"),
        ("imx327lqr", "imx327"),  # the driver's model name
    ],
)
def test_a_given_registry_sensor_is_its_registry_name(value, name):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert given_sensor(value) == name


@pytest.mark.parametrize(
    ("value", "meant"),
    [
        ("imx2l9", "imx219"),  # a letter for a digit
        ("imz219", "imx219"),
        ("imx21", "imx219"),  # a character left out
        ("imx4777", "imx477"),  # one added
        ("imx129", "imx219"),  # two swapped
        ("ov5674", "ov5647"),
        ("vd55g1_mnoo", "vd55g1_mono"),
    ],
)
def test_a_near_miss_of_a_registry_name_is_refused_with_did_you_mean(value, meant):
    with pytest.raises(PicamcalError) as info:
        given_sensor(value)
    assert str(info.value) == f"unknown sensor {value!r}; did you mean {meant}?"


def test_a_near_miss_of_several_names_lists_them():
    with pytest.raises(PicamcalError, match=r"^unknown sensor 'imx29'; did you mean imx219, imx296 or imx290\?$"):
        given_sensor("imx29")


@pytest.mark.parametrize(
    ("value", "neighbours"), [("imx298", "imx296 or imx290"), ("ar0234", None), ("OV5648", "ov5647")]
)
def test_a_sensor_outside_the_registry_is_kept_with_one_warning(value, neighbours):
    """A digit for a digit is another sensor's model number, not a slip: kept, with the registry's neighbours named."""
    with pytest.warns(PicamcalWarning) as caught:
        assert given_sensor(value) == value.lower()
    assert len(caught) == 1
    message = str(caught[0].message)
    assert message.startswith(f"sensor {value.lower()!r} is not in picamcal's registry: picamcal knows nothing of it")
    assert "(no black level, no stock tuning file)" in message
    assert (f"if it is the {neighbours}, give that name" in message) == (neighbours is not None)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert given_sensor(value, warn=False) == value.lower()  # a reader told the same name for every file


@pytest.mark.parametrize("value", ["", " - ", 219, None])
def test_a_sensor_is_a_name(value):
    with pytest.raises(PicamcalError, match="the sensor is a name such as 'imx219'"):
        given_sensor(value)


@pytest.mark.parametrize(
    ("text", "name"),
    [
        ("RP_imx477", "imx477"),
        ("imx708_wide", "imx708"),  # picamera2's model of the wide Camera Module 3
        ("imx708_wide_noir", "imx708"),
        ("IMX296_MONO", "imx296_mono"),  # the longest name wins: not the colour imx296
        ("imx296_16mm", "imx296"),
        ("/base/soc/i2c0mux/i2c@1/imx519@1a", "imx519"),
        ("ov9281_mono", "ov9281"),
        ("Canon EOS 5D", None),
        ("", None),
        (None, None),
    ],
)
def test_find_sensor_name_prefers_the_longest_match(text, name):
    assert find_sensor_name(text) == name


@pytest.mark.parametrize("name", sorted(SENSORS))
def test_no_name_is_shadowed_by_a_shorter_one(name):
    assert find_sensor_name(f"model {name.upper()} v2") == name


def test_get_sensor_is_case_insensitive_and_lists_the_known_names():
    assert get_sensor("IMX283").width == 5472
    with pytest.raises(PicamcalError) as info:
        get_sensor("imx2199")
    message = str(info.value)
    assert "unknown sensor 'imx2199'" in message and all(name in message for name in SENSORS)
    assert message.endswith("did you mean imx219?") and "\n" not in message
    with pytest.raises(PicamcalError, match=r"did you mean imx219\?$"):  # a slip, not the nearest by letters
        get_sensor("imx2l9")
