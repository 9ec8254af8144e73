"""Finding reference images in a folder by name."""

from __future__ import annotations

import json

import pytest

from picamcal import CalibrationInputError, PicamcalWarning, calibrate
from picamcal.calibration import LIGHTS
from picamcal.manifest import ILLUMINATOR_LIGHTS, AcquisitionError
from picamcal.references import find_references, read_manifest, reference_light, role_of


@pytest.mark.parametrize(
    ("name", "role"),
    [
        ("white.dng", "white"),
        ("Run2_RED.dng", "red"),
        ("img_r0_g255_b0.dng", "green"),
        ("img_r0_g0_b255.npz", "blue"),
        ("white_2.raw", "white"),
        ("white2.dng", "white"),  # a frame number straight after the role, as camera apps count shots
        ("IMG_Black10.dng", "black"),
        ("whites.dng", None),
        ("img_r255_g255_b255.dng", "white"),
        ("img_r0_g0_b0.dng", "black"),
        ("img_r255_g255_b0.dng", None),
        ("target.dng", None),
        ("redwhite.dng", None),
        ("colour_cyan.dng", "colour_cyan"),
        ("colour_cyan_2.dng", "colour_cyan"),
        ("run3_Colour_LED-590_1.dng", "colour_led-590"),
        ("colour_white.dng", "colour_white"),  # an extra named white, not the white
        ("colour_cyan_white.dng", None),  # colour and a role: neither
        ("colour_.dng", None),
        ("colour.dng", None),
    ],
)
def test_role_of(name, role):
    assert role_of(name) == role


def test_find_references(tmp_path):
    for name in ("white.dng", "red.dng", "green.dng", "blue.dng", "black.dng", "target.dng", "notes.txt"):
        (tmp_path / name).write_bytes(b"x")
    found = find_references(tmp_path)
    assert {k: v.name for k, v in found.items()} == {
        "white": "white.dng",
        "red": "red.dng",
        "green": "green.dng",
        "blue": "blue.dng",
        "black": "black.dng",
    }


def test_white_alone_is_a_flat_field_and_colours_come_all_or_none(tmp_path):
    (tmp_path / "white.dng").write_bytes(b"x")
    (tmp_path / "black.dng").write_bytes(b"x")
    assert {k: v.name for k, v in find_references(tmp_path).items()} == {"white": "white.dng", "black": "black.dng"}
    (tmp_path / "red.dng").write_bytes(b"x")
    (tmp_path / "green.dng").write_bytes(b"x")
    with pytest.raises(CalibrationInputError, match="no blue reference found: give red, green and blue references"):
        find_references(tmp_path)
    # In situ the colours come from the jig: the folder's are not looked for, a partial set included.
    assert set(find_references(tmp_path, in_situ=True)) == {"white", "black"}


def test_several_frames_of_a_role_are_a_list_in_natural_order(tmp_path):
    names = ("white_10.dng", "white_2.dng", "white_1.raw", "white_5.bin", "black.dng", "notes.txt", "white_3.txt")
    for name in names:
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / "white_4.dng").mkdir()  # a folder is not a frame, whatever its name
    found = find_references(tmp_path)
    # headless dumps (.raw, .bin) count: calibrate is told their sensor and size
    assert [p.name for p in found["white"]] == ["white_1.raw", "white_2.dng", "white_5.bin", "white_10.dng"]
    assert found["black"].name == "black.dng"


def test_a_white_and_a_numbered_white_are_both_frames_of_the_white(tmp_path):
    # white.dng and white2.dng: neither is left out without a word; both are frames of the white, to average.
    for name in ("white.dng", "white2.dng", "black.dng"):
        (tmp_path / name).write_bytes(b"x")
    assert [p.name for p in find_references(tmp_path)["white"]] == ["white.dng", "white2.dng"]


def test_a_name_of_two_references_is_passed_over_with_a_warning(tmp_path):
    for name in ("white.dng", "white_red.dng", "notes_black_white.txt", "target.dng"):
        (tmp_path / name).write_bytes(b"")
    with pytest.warns(PicamcalWarning) as caught:
        found = find_references(tmp_path)
    assert {role: path.name for role, path in found.items()} == {"white": "white.dng"}
    # Only reference files are looked at: the .txt and the target say nothing.
    assert [str(w.message) for w in caught] == [
        "white_red.dng names white and red: passed over (name a file for one reference)"
    ]


def test_a_file_given_as_the_folder_is_named_for_what_it_is(tmp_path, linear_refs):
    # A calibration is recognised by its content, whatever its name, as load_calibration reads it.
    calibrate(linear_refs["white"]).save(tmp_path / "flat.npz")
    (tmp_path / "flat.npz").rename(tmp_path / "jig.data")
    with pytest.raises(CalibrationInputError) as caught:
        find_references(tmp_path / "jig.data")
    assert str(caught.value).startswith(f"{tmp_path / 'jig.data'} is a picamcal calibration, not a folder of reference")
    (tmp_path / "white.dng").write_bytes(b"x")
    with pytest.raises(CalibrationInputError, match=r"white\.dng: a file, not a folder of reference images: give its"):
        find_references(tmp_path / "white.dng")


def test_a_folder_without_a_white(tmp_path):
    (tmp_path / "red.dng").write_bytes(b"x")
    with pytest.raises(CalibrationInputError, match="no white reference found"):
        find_references(tmp_path)
    with pytest.raises(CalibrationInputError, match="no such folder"):
        find_references(tmp_path / "missing")


def manifest(entries: list[dict]) -> dict:
    """A manifest as picamcal acquire writes it (the format in picamcal.manifest's docstring)."""
    return {
        "format": "picamcal-acquisition",
        "version": 1,
        "camera": {"kind": "sim", "sensor": "imx219", "size": [64, 48]},
        "illuminator": {"kind": "sim"},
        "settings": {"exposure_time_us": 4000, "analogue_gain": 1.0, "colour_gains": [1.8, 1.3]},
        "roles": ["white", "red", "green", "blue", "black", "target"],
        "entries": entries,
    }


def test_a_folder_with_a_manifest_is_read_through_it_not_by_names(tmp_path):
    files = {"white": "a.dng", "red": "b.dng", "green": "c.dng", "blue": "d.dng", "target": "e.dng"}
    for name in (*files.values(), "black.dng"):  # black.dng is not in the manifest: not captured by this run
        (tmp_path / name).write_bytes(b"x")
    entries = [{"role": role, "file": name} for role, name in files.items()]
    (tmp_path / "manifest.json").write_text(json.dumps(manifest(entries)))
    expected = {"white": "a.dng", "red": "b.dng", "green": "c.dng", "blue": "d.dng"}
    assert {role: path.name for role, path in find_references(tmp_path).items()} == expected
    assert read_manifest(tmp_path, extras=True)["target"] == tmp_path / "e.dng"


def test_a_manifest_without_the_colours_yet_is_an_incomplete_run(tmp_path):
    (tmp_path / "white.dng").write_bytes(b"x")
    (tmp_path / "manifest.json").write_text(json.dumps(manifest([{"role": "white", "file": "white.dng"}])))
    with pytest.raises(AcquisitionError, match=r"incomplete \(no red, green, blue yet\): run picamcal acquire again"):
        find_references(tmp_path)


def test_extra_colour_references_are_found_by_name_frames_and_all(tmp_path):
    names = (
        "white.dng",
        "red.dng",
        "green.dng",
        "blue.dng",
        "colour_cyan.dng",
        "colour_amber_2.dng",
        "colour_amber_1.dng",
        "colour_amber_10.dng",
    )
    for name in names:
        (tmp_path / name).write_bytes(b"x")
    found = find_references(tmp_path)
    assert found["colour_cyan"].name == "colour_cyan.dng"
    assert [p.name for p in found["colour_amber"]] == [
        "colour_amber_1.dng",
        "colour_amber_2.dng",
        "colour_amber_10.dng",
    ]
    # In situ the colours come from the jig: extras are not looked for either.
    assert set(find_references(tmp_path, in_situ=True)) == {"white"}


def test_extra_colours_without_the_primaries_are_refused(tmp_path):
    for name in ("white.dng", "colour_cyan.dng"):
        (tmp_path / name).write_bytes(b"x")
    with pytest.raises(CalibrationInputError, match=r"colour_cyan\.dng is an extra colour reference, but there is no"):
        find_references(tmp_path)


def test_a_manifest_lists_extra_colours_as_references(tmp_path):
    files = {
        "white": "white.dng",
        "red": "red.dng",
        "green": "green.dng",
        "blue": "blue.dng",
        "colour_cyan": "colour_cyan.dng",
        "target": "target.dng",
    }
    for name in files.values():
        (tmp_path / name).write_bytes(b"x")
    record = manifest([{"role": role, "file": name} for role, name in files.items()])
    record["roles"] = list(files)
    (tmp_path / "manifest.json").write_text(json.dumps(record))
    found = {role: path.name for role, path in find_references(tmp_path).items()}
    assert found == {role: name for role, name in files.items() if role != "target"}


def test_the_light_of_each_illuminator_is_one_the_accuracy_figures_know():
    # Every illuminator picamcal acquire opens gives a known light, but the manual one (the user sets anything).
    assert set(ILLUMINATOR_LIGHTS) | {"manual"} == {"serial", "gpio", "sim", "virtual", "screen", "manual"}
    assert set(ILLUMINATOR_LIGHTS.values()) <= set(LIGHTS)


@pytest.mark.parametrize(
    ("kind", "light"), [("serial", "jig"), ("gpio", "jig"), ("screen", "screen"), ("manual", None)]
)
def test_the_light_of_an_acquisition_comes_from_its_manifest(tmp_path, kind, light):
    record = manifest([])
    record["illuminator"] = {"kind": kind}
    (tmp_path / "manifest.json").write_text(json.dumps(record))
    assert reference_light(tmp_path) == light
    if light is None:  # a manual run's light is whatever the user says
        assert reference_light(tmp_path, "sheets") == "sheets"
    else:  # another light than the manifest's is refused, naming the manifest
        other = "sheets"
        with pytest.raises(CalibrationInputError, match=f"manifest.json: the acquisition's illuminator was {kind},"):
            reference_light(tmp_path, other)


def test_a_light_is_one_of_the_known_ones_or_unknown(tmp_path):
    assert reference_light(tmp_path) is None and reference_light(None) is None  # no manifest: not known
    assert reference_light(tmp_path, "Screen") == "screen"
    with pytest.raises(
        CalibrationInputError, match=r"unknown light 'scren' \(expected jig, screen, sheets\); did you "
    ):
        reference_light(tmp_path, "scren")
