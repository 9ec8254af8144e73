"""Trust but verify: the declared Bayer order and black level checked against the data; overrides."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from picamcal import PicamcalWarning, RawFormatError, read_raw
from picamcal.raw import RawImage, check_metadata, override, write_dng
from picamcal.simulate import make_camera, simulate_references, simulate_target


@pytest.fixture(scope="module")
def scenes():
    camera = make_camera("imx219", size=(320, 240))
    refs = simulate_references(camera, seed=2)
    return {"white": refs["white"], "red": refs["red"], "black": refs["black"], "target": simulate_target(camera)[0]}


@pytest.mark.parametrize("scene", ["white", "red", "target"])
def test_true_pattern_passes_and_the_wrong_diagonal_is_caught(scenes, scene):
    raw = scenes[scene]
    assert check_metadata(raw) == []
    problems = check_metadata(override(raw, pattern="GBRG"))  # the real PiDNG case: BGGR data declared GBRG
    assert len(problems) == 1 and "greens sit on the other diagonal" in problems[0]
    assert "--pattern RGGB or BGGR" in problems[0]


def test_a_dark_frame_says_nothing_about_the_pattern(scenes):
    assert check_metadata(override(scenes["black"], pattern="GRBG")) == []  # no light, no evidence


def test_missing_black_level_is_reported_with_the_registry_value(scenes):
    problems = check_metadata(override(scenes["white"], black_level=0))
    assert len(problems) == 1 and "--black-level 64" in problems[0]


def test_read_raw_warns_and_overrides(tmp_path, scenes):
    lying = override(scenes["white"], pattern="GBRG", black_level=0)
    path = write_dng(tmp_path / "pidng_like.dng", lying)
    with pytest.warns(PicamcalWarning) as caught:
        raw = read_raw(path)
    messages = [str(w.message) for w in caught]
    assert any("other diagonal" in m for m in messages) and any("no black level" in m for m in messages)
    assert all(m.startswith(str(path)) for m in messages)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PicamcalWarning)
        fixed = read_raw(path, pattern="BGGR", black_level=64)
    assert fixed.pattern == "BGGR" and fixed.black_level == (64.0,) * 4
    assert fixed.metadata["declared_pattern"] == "GBRG" and fixed.metadata["declared_black_level"] == [0.0] * 4
    np.testing.assert_array_equal(fixed.bayer, raw.bayer)
    fixed4 = read_raw(path, pattern="BGGR", black_level=[60, 61, 62, 63])
    assert fixed4.black_level == (60.0, 61.0, 62.0, 63.0)
    with pytest.raises(RawFormatError, match="unknown Bayer pattern"):
        read_raw(path, pattern="RGBG")


def test_the_black_level_check_uses_the_registry_for_any_known_sensor():
    # An IMX283 (imx283.json: 3200 on the 16-bit scale, 200 DN at 12 bits) whose file declares black level 0.
    rng = np.random.default_rng(4)
    bayer = (200 + rng.integers(0, 40, (64, 64))).astype(np.uint16)
    problems = check_metadata(RawImage(bayer, "RGGB", 0, 4095, 12, "imx283"))
    assert len(problems) == 1 and "IMX283's is 200 DN at 12 bits" in problems[0] and "--black-level 200" in problems[0]


def test_an_unknown_black_level_is_not_checked_and_the_pattern_still_is(scenes):
    unknown = RawImage(scenes["white"].bayer, "BGGR", float("nan"), 1023, 10, "imx219")
    assert check_metadata(unknown) == []  # NaN is require_black_level's to report, where it is needed
    problems = check_metadata(override(unknown, pattern="GBRG"))
    assert len(problems) == 1 and "greens sit on the other diagonal" in problems[0]
