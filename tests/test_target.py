"""Tests of picamcal.target: the colour-wheel target's layout, its rendering and its files."""

from __future__ import annotations

import itertools
import json
import math
import warnings

import numpy as np
import pytest
from PIL import Image

from picamcal.cli import main
from picamcal.errors import OutputError, PicamcalError
from picamcal.references import ROLES, parse_colours
from picamcal.target import (
    SCREEN_COLOURS,
    is_screen_file,
    render_target,
    save_screens,
    save_target,
    target_layout,
)

NAMES = {"centre", "top-left", "top", "top-right", "left", "right", "bottom-left", "bottom", "bottom-right"}
SIZES = [(1920, 1080), (1080, 1080), (3508, 2480), (640, 480), (1080, 1920)]


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_layout_has_nine_wheels_and_five_fiducials_inside_the_frame_and_apart(size):
    width, height = size
    layout = target_layout(width, height)
    assert (layout["width"], layout["height"], layout["units"]) == (width, height, "pixels")
    assert {w["name"] for w in layout["wheels"]} == NAMES
    assert [s["name"] for s in layout["segments"]] == ["red", "yellow", "green", "cyan", "blue", "magenta"]
    assert [(s["start_deg"], s["end_deg"]) for s in layout["segments"]] == [(60 * k, 60 * k + 60) for k in range(6)]
    kinds = sorted(f["kind"] for f in layout["fiducials"])
    assert kinds == ["disc", "ring", "ring", "ring", "ring"]
    shapes = layout["wheels"] + layout["fiducials"]
    for shape in shapes:
        # Pixels span -0.5 to width - 0.5: every shape with at least a pixel of white round it.
        x, y, r = shape["x"], shape["y"], shape["radius"]
        assert r + 1 <= x + 0.5 and x + r + 1 <= width - 0.5, shape
        assert r + 1 <= y + 0.5 and y + r + 1 <= height - 0.5, shape
    for a, b in itertools.combinations(shapes, 2):
        gap = math.hypot(a["x"] - b["x"], a["y"] - b["y"]) - a["radius"] - b["radius"]
        assert gap > 0.01 * min(width, height), (a, b)


def test_wheels_sit_where_the_layout_says_the_centre_wheel_in_the_middle():
    layout = target_layout(1920, 1080)
    wheels = {w["name"]: w for w in layout["wheels"]}
    assert (wheels["centre"]["x"], wheels["centre"]["y"]) == (959.5, 539.5)
    assert wheels["top-left"]["x"] < wheels["top"]["x"] < wheels["top-right"]["x"]
    assert wheels["top"]["y"] < wheels["left"]["y"] == wheels["centre"]["y"] < wheels["bottom"]["y"]
    # The outer wheels as near the corners as the simulator's (15 % of the frame) or as the marks allow.
    assert wheels["top-left"]["x"] == pytest.approx(0.15 * 1920 - 0.5)
    assert wheels["top-left"]["y"] == pytest.approx(0.17 * 1080 - 0.5)


def test_orientation_disc_breaks_every_symmetry_of_the_rings():
    layout = target_layout(1920, 1080)
    rings = [f for f in layout["fiducials"] if f["kind"] == "ring"]
    (disc,) = [f for f in layout["fiducials"] if f["kind"] == "disc"]
    distances = sorted(math.hypot(r["x"] - disc["x"], r["y"] - disc["y"]) for r in rings)
    # Nearest one ring (top-left), and nearer its neighbour along the top (top-right) than the one below it.
    assert distances[0] < 0.5 * distances[1]
    nearest = min(rings, key=lambda r: math.hypot(r["x"] - disc["x"], r["y"] - disc["y"]))
    assert nearest["name"] == "top-left" and disc["y"] == nearest["y"] and disc["x"] > nearest["x"]
    assert disc["radius"] < rings[0]["radius"]


def test_render_has_the_layout_colours_and_black_marks_on_white():
    layout = target_layout(640, 360)
    image = render_target(layout)
    assert image.shape == (360, 640, 3) and image.dtype == np.uint8
    for wheel in layout["wheels"]:
        for segment in layout["segments"]:
            mid = math.radians(0.5 * (segment["start_deg"] + segment["end_deg"]))
            x = round(wheel["x"] + 0.6 * wheel["radius"] * math.cos(mid))
            y = round(wheel["y"] - 0.6 * wheel["radius"] * math.sin(mid))
            assert image[y, x].tolist() == [255 * c for c in segment["colour"]], (wheel["name"], segment["name"])
    for mark in layout["fiducials"]:
        x, y = round(mark["x"]), round(mark["y"])
        if mark["kind"] == "ring":
            assert image[y, x].tolist() == [255, 255, 255]  # the white dot
            ring = round(mark["x"] + 0.5 * (mark["radius"] + mark["hole_radius"]))
            assert image[y, ring].tolist() == [0, 0, 0]
        else:
            assert image[y, x].tolist() == [0, 0, 0]
    assert image[180, 200].tolist() == [255, 255, 255]  # between the left and centre wheels


def test_render_is_anti_aliased_at_the_edges():
    layout = target_layout(640, 360)
    image = render_target(layout)
    wheel = layout["wheels"][0]
    # A pixel on the rim of the red segment is partly red, partly white: blue strictly between 0 and 255.
    row = image[round(wheel["y"]) - 5]
    rim = row[round(wheel["x"] + wheel["radius"]) - 2 : round(wheel["x"] + wheel["radius"]) + 3, 2]
    assert np.any((rim > 0) & (rim < 255)), rim
    assert not np.array_equal(render_target(layout, supersample=1), image)


def test_save_target_writes_png_pdf_and_the_layout_beside_them(tmp_path):
    png, png_layout = save_target(tmp_path / "wheels.png", 800, 600)
    assert png_layout == tmp_path / "wheels.json"
    with Image.open(png) as picture:
        assert picture.format == "PNG" and picture.size == (800, 600)
        np.testing.assert_array_equal(np.asarray(picture.convert("RGB")), render_target(target_layout(800, 600)))
    assert json.loads(png_layout.read_text()) == target_layout(800, 600)

    pdf, pdf_layout = save_target(tmp_path / "print.pdf", 1200, 900)
    content = pdf.read_bytes()
    assert content.startswith(b"%PDF") and len(content) > 1000
    # One page 11.69 inches (841.68 points) wide, the whole image embedded losslessly at its own size.
    assert b"/MediaBox [ 0 0 841.68 631.26 ]" in content
    assert b"/Width 1200" in content and b"/Height 900" in content and b"/DCTDecode" not in content
    assert json.loads(pdf_layout.read_text())["width"] == 1200
    assert sorted(p.name for p in tmp_path.iterdir()) == ["print.json", "print.pdf", "wheels.json", "wheels.png"]


def test_save_target_refuses_other_suffixes_and_existing_files_when_asked(tmp_path):
    with pytest.raises(PicamcalError, match=r"\.png or \.pdf"):
        save_target(tmp_path / "wheels.jpg")
    save_target(tmp_path / "wheels.png", 320, 240)
    with pytest.raises(OutputError, match="exists already"):
        save_target(tmp_path / "wheels.png", 320, 240, overwrite=False)


def test_too_small_a_target_is_refused():
    with pytest.raises(PicamcalError, match="at least 64"):
        target_layout(50, 400)


# --- the full-screen references ----------------------------------------------------------------------------------

SCREEN_FILES = [f"screen_{role}.png" for role in ROLES]


def test_screens_are_flat_exact_srgb_colours_at_the_size_asked(tmp_path):
    paths = save_screens(tmp_path / "screens", 1366, 768, {"cyan": (0, 255, 255), "Amber": (255, 191, 1)})
    assert [p.name for p in paths] == [*SCREEN_FILES, "screen_colour_cyan.png", "screen_colour_amber.png"]
    expected = [*SCREEN_COLOURS.values(), (0, 255, 255), (255, 191, 1)]
    for path, rgb in zip(paths, expected, strict=True):
        with Image.open(path) as image:
            # 8-bit RGB, tagged sRGB (rendering intent 0), every pixel the exact code values: nothing dithered.
            assert (image.format, image.mode, image.size, image.info["srgb"]) == ("PNG", "RGB", (1366, 768), 0)
            pixels = np.asarray(image)
        assert np.all(pixels == np.array(rgb, dtype=np.uint8)), path.name
        assert is_screen_file(path)
    assert SCREEN_COLOURS == {
        "white": (255, 255, 255),
        "red": (255, 0, 0),
        "green": (0, 255, 0),
        "blue": (0, 0, 255),
        "black": (0, 0, 0),
    }
    assert list(SCREEN_COLOURS) == list(ROLES)


def test_screens_never_replace_what_picamcal_did_not_write(tmp_path):
    save_screens(tmp_path, 64, 48)
    with pytest.raises(OutputError, match=r"screen_white.png: exists already \(use --overwrite"):
        save_screens(tmp_path, 32, 32)
    save_screens(tmp_path, 32, 32, overwrite=True)
    with Image.open(tmp_path / "screen_red.png") as image:
        assert image.size == (32, 32)
    Image.new("RGB", (64, 48), (0, 0, 255)).save(tmp_path / "screen_blue.png")  # a PNG someone else made
    with pytest.raises(OutputError, match=r"screen_blue\.png: exists and is not a screen picamcal wrote"):
        save_screens(tmp_path, 64, 48, overwrite=True)
    with Image.open(tmp_path / "screen_red.png") as image:
        assert image.size == (32, 32)  # refused before anything was written
    assert not is_screen_file(tmp_path / "screen_blue.png") and not is_screen_file(tmp_path)
    save_target(tmp_path / "wheels.png", 320, 240)
    assert not is_screen_file(tmp_path / "wheels.png")  # a target is not a screen


def test_screen_sizes_and_colours_are_checked(tmp_path, monkeypatch):
    with pytest.raises(PicamcalError, match="at least one pixel each way, got 0 x 10"):
        save_screens(tmp_path, 0, 10)
    monkeypatch.setenv("PICAMCAL_MAX_PIXELS", "1000")
    with pytest.raises(PicamcalError, match="a screen of 64x48 pixels is over the limit"):
        save_screens(tmp_path, 64, 48)
    monkeypatch.delenv("PICAMCAL_MAX_PIXELS")
    with pytest.raises(PicamcalError, match="R, G and B must be whole numbers from 0 to 255"):
        save_screens(tmp_path, 64, 48, {"cyan": (0, 255, 256)})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("specs", "message"),
    [
        (["cyan 0,255,255"], "is not NAME=R,G,B"),
        (["cyan=0,255,255,0"], "is not NAME=R,G,B"),
        (["cyan=a,b,c"], "R, G and B must be whole numbers from 0 to 255"),
        (["cyan=0,255,1e2"], "R, G and B must be whole numbers from 0 to 255"),
        (["cyan=0,255,٣"], "R, G and B must be whole numbers from 0 to 255"),  # an Arabic-Indic three
        (["=0,255,255"], "the name must be 1 to 40 letters, digits or '-'"),
        (["é=0,255,255"], "the name must be 1 to 40 letters, digits or '-'"),
        (["x" * 41 + "=0,255,255"], "the name must be 1 to 40 letters, digits or '-'"),
        (["WHITE=1,1,1"], "WHITE is a reference already"),
        (["a=1,2,3", "A=1,2,3"], "the colour A is given twice"),
    ],
)
def test_parse_colours_refuses_in_one_line(specs, message):
    with pytest.raises(PicamcalError, match=message) as refused:
        parse_colours(specs)
    assert "\n" not in str(refused.value)


def test_parse_colours_keeps_the_order_and_the_values():
    assert parse_colours([" led-590 = 255, 140 ,0", "cyan=0,255,255"]) == {
        "led-590": (255, 140, 0),
        "cyan": (0, 255, 255),
    }


def target_cli(args: list[str], monkeypatch, capfd) -> tuple[int, list[str]]:
    """``picamcal target ARGS`` in this process: its exit status and its stderr lines."""
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # main's global settings are put back
    with pytest.raises(SystemExit) as exit:
        main(["target", *args])
    return exit.value.code, capfd.readouterr().err.splitlines()


def test_target_screens_writes_a_folder_of_screens_or_the_screens_beside_the_target(tmp_path, monkeypatch, capfd):
    code, _ = target_cli(
        ["--screens", "--out", str(tmp_path / "shows"), "--size", "64x48", "--colour", "cyan=0,255,255"],
        monkeypatch,
        capfd,
    )
    assert code == 0
    assert sorted(p.name for p in (tmp_path / "shows").iterdir()) == sorted([*SCREEN_FILES, "screen_colour_cyan.png"])
    code, _ = target_cli(
        ["--screens", "--out", str(tmp_path / "both" / "t.png"), "--size", "320x240"], monkeypatch, capfd
    )
    assert code == 0
    assert sorted(p.name for p in (tmp_path / "both").iterdir()) == sorted([*SCREEN_FILES, "t.json", "t.png"])
    with Image.open(tmp_path / "both" / "screen_green.png") as image:
        assert image.size == (320, 240)


def test_target_screens_refuses_in_one_line_before_writing(tmp_path, monkeypatch, capfd):
    shows = str(tmp_path / "shows")
    mistakes = {
        ("--out", shows, "--colour", "cyan=0,255,255"): "Invalid value for --colour: it names a full-screen colour: "
        "give --screens too",
        ("--screens", "--out", shows, "--colour", "cyan=0,255"): "Invalid value for --colour: 'cyan=0,255' is not "
        "NAME=R,G,B (e.g. cyan=0,255,255)",
        ("--screens", "--out", shows, "--colour", "blue=0,0,255"): "Invalid value for --colour: 'blue=0,0,255': blue "
        "is a reference already (white, red, green, blue, black); name the extra colour otherwise",
        ("--out", shows): "Invalid value for --out: the target is written as .png or .pdf",
    }
    for args, line in mistakes.items():
        assert target_cli(list(args), monkeypatch, capfd) == (
            2,
            [f"picamcal: error: {line} (see picamcal target --help)"],
        )
    assert not (tmp_path / "shows").exists()
    (tmp_path / "file").write_text("not a folder")
    code, lines = target_cli(["--screens", "--out", str(tmp_path / "file")], monkeypatch, capfd)
    assert (code, lines) == (2, [f"picamcal: error: {tmp_path / 'file'}: cannot create the folder: File exists"])
    save_screens(tmp_path / "shows", 64, 48)
    code, lines = target_cli(["--screens", "--out", str(tmp_path / "shows" / "t.png")], monkeypatch, capfd)
    assert (code, lines) == (2, [f"picamcal: error: {tmp_path / 'shows' / 'screen_white.png'}: exists already (use "
                                 "--overwrite to replace it)"])  # fmt: skip
    assert not (tmp_path / "shows" / "t.png").exists()  # the target is not written either
