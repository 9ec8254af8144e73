"""Finding reference images in a folder by name."""

from __future__ import annotations

import pytest

from picamcal import CalibrationInputError
from picamcal.references import find_references, role_of


@pytest.mark.parametrize(
    ("name", "role"),
    [
        ("white.dng", "white"),
        ("Run2_RED.dng", "red"),
        ("img_r0_g255_b0.dng", "green"),
        ("img_r0_g0_b255.npz", "blue"),
        ("img_r255_g255_b255.dng", "white"),
        ("img_r0_g0_b0.dng", "black"),
        ("img_r255_g255_b0.dng", None),
        ("target.dng", None),
        ("redwhite.dng", None),
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


def test_missing_and_ambiguous_references(tmp_path):
    (tmp_path / "white.dng").write_bytes(b"x")
    with pytest.raises(CalibrationInputError, match="no red, green, blue reference found"):
        find_references(tmp_path)
    for name in ("red.dng", "green.dng", "blue.dng", "white_2.dng"):
        (tmp_path / name).write_bytes(b"x")
    with pytest.raises(CalibrationInputError, match="several files for the white reference"):
        find_references(tmp_path)
