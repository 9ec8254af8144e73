"""The calibration jig in hardware/: every OpenSCAD source renders to a closed STL, without warnings."""

from __future__ import annotations

import os
import re
import shutil
import struct
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

HARDWARE = Path(__file__).resolve().parents[1] / "hardware"
PARTS = ("led_holder", "collimation_tube", "camera_holder", "rotation_seat")
OPENSCAD = shutil.which("openscad")
needs_openscad = pytest.mark.skipif(OPENSCAD is None, reason="openscad is not installed: apt-get install openscad")

# 32 facets per circle keeps each render to seconds (the assembly to about 20 s) with every feature still there;
# `make -C hardware` renders at the sources' finer default.
QUICK = ("$fn=32",)
TILT = 20
LONG_TUBE = 80
# STL stores float32 coordinates (rounding below 0.1 um here); 0.01 mm is well above that and far below what a
# printer resolves.
MM_TOLERANCE = 0.01


def openscad(scad: Path, out: Path, *defines: str) -> subprocess.CompletedProcess:
    """Render ``scad`` to ``out`` (binary STL, or the echo output for ``.echo``) with ``-D`` assignments."""
    command = [OPENSCAD, "--export-format", "binstl"] if out.suffix == ".stl" else [OPENSCAD]
    for define in (*QUICK, *defines):
        command += ["-D", define]
    return subprocess.run([*command, "-o", str(out), str(scad)], capture_output=True, text=True, timeout=300)


def problems(result: subprocess.CompletedProcess) -> list[str]:
    """OpenSCAD's warnings and errors. It does not always start them on a new line, so search, don't split."""
    return re.findall(r"(?:WARNING|ERROR)[^\n]*", result.stderr)


def read_stl(path: Path) -> np.ndarray:
    """Triangles of an ASCII or binary STL file as an (n, 3, 3) array of vertex coordinates."""
    data = path.read_bytes()
    if len(data) >= 84 and len(data) == 84 + 50 * struct.unpack_from("<I", data, 80)[0]:
        record = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])
        return np.frombuffer(data, dtype=record, offset=84)["vertices"].astype(float)
    numbers = re.findall(rb"^\s*vertex\s+(\S+)\s+(\S+)\s+(\S+)", data, re.MULTILINE)
    return np.array(numbers, dtype=float).reshape(-1, 3, 3)


def unpaired_edges(triangles: np.ndarray) -> int:
    """Directed edges not matched by exactly one reverse edge: 0 for a closed, consistently oriented mesh.

    OpenSCAD writes a shared vertex with identical coordinates every time, so vertices are matched exactly.
    """
    _, index = np.unique(triangles.reshape(-1, 3), axis=0, return_inverse=True)
    corners = index.reshape(-1, 3)
    n = corners.max() + 1
    edges = np.concatenate([corners[:, [0, 1]], corners[:, [1, 2]], corners[:, [2, 0]]])
    forward = edges[:, 0] * n + edges[:, 1]
    backward = edges[:, 1] * n + edges[:, 0]
    codes, counts = np.unique(forward, return_counts=True)
    duplicated = int((counts > 1).sum())
    return duplicated + int((~np.isin(backward, codes)).sum())


def nearly_coincident_vertices(triangles: np.ndarray) -> int:
    """Distinct vertices that fall together when rounded to 0.1 um.

    Real features are thousands of times larger; such pairs come from two surfaces that nearly, but not exactly,
    meet, and leave sliver triangles that slicers handle badly.
    """
    vertices = triangles.reshape(-1, 3)
    return len(np.unique(vertices, axis=0)) - len(np.unique(np.round(vertices, 4), axis=0))


def parameters(tmp_path: Path, *names: str) -> dict[str, float]:
    """Values of the shared parameters (including derived ones) as OpenSCAD computes them."""
    probe = tmp_path / "probe.scad"
    probe.write_text(f"include <{HARDWARE / 'parameters.scad'}>\necho({', '.join(names)});\n")
    result = openscad(probe, tmp_path / "probe.echo")
    assert result.returncode == 0, result.stderr
    values = re.search(r"ECHO: (.*)", (tmp_path / "probe.echo").read_text()).group(1)
    return dict(zip(names, map(float, values.split(", ")), strict=True))


@pytest.fixture(scope="module")
def renders(tmp_path_factory) -> dict[str, tuple[subprocess.CompletedProcess, Path]]:
    """Every part, a longer tube and the tilted assembly, rendered once, in parallel."""
    out = tmp_path_factory.mktemp("stl")
    jobs = {part: (part, ()) for part in PARTS}
    jobs["long_tube"] = ("collimation_tube", (f"tube_length={LONG_TUBE}",))
    jobs["assembly"] = ("assembly", (f"tilt={TILT}",))
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 2) as pool:
        futures = {
            name: pool.submit(openscad, HARDWARE / f"{scad}.scad", out / f"{name}.stl", *defines)
            for name, (scad, defines) in jobs.items()
        }
        return {name: (future.result(), out / f"{name}.stl") for name, future in futures.items()}


def check_render(result: subprocess.CompletedProcess, stl: Path) -> np.ndarray:
    assert result.returncode == 0, result.stderr
    assert problems(result) == []
    triangles = read_stl(stl)
    assert len(triangles) > 0
    assert unpaired_edges(triangles) == 0, "the mesh is not closed"
    assert nearly_coincident_vertices(triangles) == 0
    return triangles


@pytest.mark.slow
@needs_openscad
@pytest.mark.parametrize("part", PARTS)
def test_each_part_renders_on_its_own_to_a_closed_mesh_without_warnings(renders, part):
    check_render(*renders[part])


@pytest.mark.slow
@needs_openscad
def test_tube_length_sets_the_printed_tube_height(renders, tmp_path):
    default = parameters(tmp_path, "tube_length")["tube_length"]
    for name, length in (("collimation_tube", default), ("long_tube", LONG_TUBE)):
        vertices = check_render(*renders[name]).reshape(-1, 3)
        height = vertices[:, 2].max() - vertices[:, 2].min()
        assert height == pytest.approx(length, abs=MM_TOLERANCE)


@pytest.mark.slow
@needs_openscad
def test_parts_come_out_standing_on_the_print_bed(renders):
    for part in PARTS:
        lowest = read_stl(renders[part][1])[..., 2].min()
        assert lowest == pytest.approx(0, abs=MM_TOLERANCE), part


@pytest.mark.slow
@needs_openscad
def test_tilted_assembly_renders_from_seat_base_to_led_holder(renders, tmp_path):
    p = parameters(tmp_path, "seat_bottom_z", "seat_top_z", "tube_length", "cap_thickness")
    vertices = check_render(*renders["assembly"]).reshape(-1, 3)
    assert vertices[:, 2].min() == pytest.approx(p["seat_bottom_z"], abs=MM_TOLERANCE)
    top = p["seat_top_z"] + p["tube_length"] + p["cap_thickness"]
    assert vertices[:, 2].max() == pytest.approx(top, abs=MM_TOLERANCE)


@needs_openscad
def test_assembly_refuses_a_tilt_beyond_the_angle_marks(tmp_path):
    tilt_max = parameters(tmp_path, "tilt_max")["tilt_max"]
    result = openscad(HARDWARE / "assembly.scad", tmp_path / "too_far.stl", f"tilt={tilt_max + 5}")
    assert result.returncode != 0
    assert "tilt must be within" in result.stderr


def test_makefile_renders_every_part():
    sources = {path.stem for path in HARDWARE.glob("*.scad")} - {"parameters", "assembly"}
    listed = re.search(r"^PARTS\s*:?=(.*)$", (HARDWARE / "Makefile").read_text(), re.MULTILINE).group(1).split()
    assert set(PARTS) == sources == set(listed)


def test_bill_of_materials_lists_every_printed_part():
    readme = (HARDWARE / "README.md").read_text()
    for part in PARTS:
        assert f"{part}.scad" in readme, part
