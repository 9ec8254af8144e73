"""Finding reference images in a folder by name."""

from __future__ import annotations

import json

import pytest

from picamcal import CalibrationInputError
from picamcal.manifest import AcquisitionError
from picamcal.references import find_references, read_manifest, role_of


@pytest.mark.parametrize(
    ("name", "role"),
    [
        ("white.dng", "white"),
        ("Run2_RED.dng", "red"),
        ("img_r0_g255_b0.dng", "green"),
        ("img_r0_g0_b255.npz", "blue"),
        ("white_2.raw", "white"),
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
