"""The sensor registry: every sensor Raspberry Pi's libcamera tunes, consistent entries, names found in free text."""

from __future__ import annotations

import json
from importlib import resources

import pytest

from picamcal.errors import PicamcalError
from picamcal.raw.model import PATTERNS
from picamcal.sensors import SENSORS, black_level_at, find_sensor_name, get_sensor

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
    assert sensor.width % 2 == 0 and sensor.height % 2 == 0 and sensor.width > sensor.height > 0
    assert 8 <= sensor.bit_depth <= 16 and 0 < sensor.black_level < sensor.white_level // 8
    assert 0.8 < sensor.pixel_pitch_um < 4.0
    assert (sensor.default_pattern is None) == sensor.monochrome
    assert sensor.monochrome or sensor.default_pattern in PATTERNS


def test_monochrome_sensors_are_marked():
    assert {n for n, s in SENSORS.items() if s.monochrome} == {"ov9281", "ov7251", "imx296_mono", "imx585_mono"}


def test_bundled_tuning_files_agree_with_the_registry():
    """Each libcamera tuning file shipped in the package for a registry sensor has the registry's black level."""
    root = resources.files("picamcal") / "data" / "libcamera-tuning"
    files = [f for target in root.iterdir() if target.is_dir() for f in target.iterdir() if f.name.endswith(".json")]
    checked = set()
    for tuning_file in files:
        name = find_sensor_name(tuning_file.name.removesuffix(".json"))
        if name is None:  # uncalibrated.json, or a sensor the registry does not hold
            continue
        checked.add(name)
        algorithms = json.loads(tuning_file.read_text())["algorithms"]
        level = next(a["rpi.black_level"] for a in algorithms if "rpi.black_level" in a)
        published = level["black_level"] if "black_level" in level else level["black_level_func"][1]
        assert black_level_at(SENSORS[name], 16) == published, tuning_file.name
    assert {"ov5647", "imx219", "imx477", "imx708"} <= checked  # the four the package has always shipped


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
