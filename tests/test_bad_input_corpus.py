"""A corpus of bad inputs and faults, tried across every command and every format as a careless or unlucky user
would (issue 11).

Each case is refused with exit status 2 -- 1 for a batch with bad files, whose good files are still done -- and
exactly one stderr line ``picamcal: error: ...`` (``picamcal: failed: ...`` for a batch's bad file) that names the
file or the option; no traceback; nothing written under the output's name (the case's folder is unchanged, byte for
byte, but for a batch's good outputs); every input unchanged, byte for byte.

The bad files are made here, by code, from one small real run (a simulated 96 x 64 IMX219 without noise, its
calibration and tuning file). Every case is a process of its own, as a command typed at a shell; they all run in one
module fixture, two at a time (the machine has two cores), and the parametrised tests only check what each gave.
Each case's process is forked from one that has imported the command line and the libraries the commands use
(``PRELOAD``, tests/forked_python.py), so that the corpus does not spend most of its time starting Python and
importing numpy 250 times.
"""

from __future__ import annotations

import hashlib
import io
import itertools
import json
import os
import queue
import shutil
import stat
import struct
import time
import zipfile
import zlib
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import tifffile
from PIL import Image

from forked_python import forkers

#: A case that runs longer than this is taken to hang: every case reads files of a few kilobytes and ends in a few
#: seconds, so this is a guard against waiting for ever (a FIFO read), not a measure of speed.
TIMEOUT_S = 120
#: Each case runs as ``python3 -c CLI ARGV...`` (in a child of a forking process that has imported ``PRELOAD``: the
#: command line and what most commands load).
CLI = "from picamcal.cli import main; main()"
PRELOAD = ("picamcal.cli", "numpy", "picamcal.raw", "picamcal.calibration", "picamcal.correct", "tifffile", "rawpy")
# Over 200 commands of a second or two each, and the small run they share: the fast loop leaves the corpus out.
pytestmark = pytest.mark.slow


# ------------------------------------------------------------------------------------------------- the cases
Argv = Callable[[Path, Path], list]


@dataclass(frozen=True)
class Case:
    """One bad input: ``argv(folder, shared)`` makes the case's files in ``folder`` and gives the command line.

    ``names`` must all be in the error line (``"a|b"``: either). A batch (``status`` 1) may write under ``written``
    (paths relative to the case's folder) but never ``absent``. ``survey``: ``inspect`` of a folder, which lists
    every file (the reason under the table on stdout) and exits 1. ``described``: a readable file with odd
    metadata, which ``inspect`` may describe (exit 0, nothing on stderr) or refuse in one line (exit 2);
    ``warned``: when described, with a line under the table saying what is wrong with it.
    """

    argv: Argv
    status: int = 2
    names: tuple[str, ...] = ()
    written: tuple[str, ...] = ()
    absent: tuple[str, ...] = ()
    env: dict[str, str] = field(default_factory=dict)
    survey: bool = False
    described: bool = False
    warned: bool = False


CASES: list = []


def case(id: str, argv: Argv, *names: str, **options) -> None:
    CASES.append(pytest.param(Case(argv, names=names, **options), id=id))


def write(path: Path, data: bytes | str) -> Path:
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


# -- commands, each given the bad file; a batch also gets a good file, whose output it must still write --------
def inspect_one(make: Callable[[Path, Path], Path]) -> Argv:
    return lambda d, b: ["inspect", make(d, b)]


def calibrate_white(make: Callable[[Path, Path], Path], *extra: str) -> Argv:
    return lambda d, b: ["calibrate", "--white", make(d, b), *extra, "--out", d / "cal.npz"]


def calibrate_full(role: str, make: Callable[[Path, Path], Path]) -> Argv:
    """A full calibration from the shared run with one reference replaced."""

    def argv(d: Path, b: Path) -> list:
        refs = [f"--{r}={b / 'sim' / f'{r}.dng'}" for r in ("white", "red", "green", "blue", "black") if r != role]
        return ["calibrate", *refs, f"--{role}={make(d, b)}", "--out", d / "cal.npz"]

    return argv


def correct_batch(make: Callable[[Path, Path], Path], *extra: str) -> Argv:
    return lambda d, b: ["correct", b / "cal.npz", make(d, b), b / "sim" / "target.dng", *extra,
                         "--out", d / "out", "--workers", "0"]  # fmt: skip


def correct_zarr_batch(make: Callable[[Path, Path], Path]) -> Argv:
    return lambda d, b: ["correct", b / "cal.npz", make(d, b), b / "sim" / "target.dng",
                         "--zarr", d / "stack.zarr", "--workers", "0"]  # fmt: skip


def processed_batch(make: Callable[[Path, Path], Path]) -> Argv:
    return lambda d, b: ["correct", b / "cal.npz", make(d, b), b / "good.png", "--processed",
                         "--out", d / "out", "--workers", "0"]  # fmt: skip


def batch(name: str = "out", stem: str = "bad", suffix: str = ".tiff") -> dict:
    """A batch with one bad file ``stem``: it may write the good file's output under ``name``, never the bad's."""
    return {"status": 1, "written": (name,), "absent": (f"{name}/{stem}{suffix}",)}


def survey(make: Callable[[Path, Path], Path]) -> Argv:
    """``inspect`` of a folder holding the bad file and a good one."""

    def argv(d: Path, b: Path) -> list:
        folder = d / "folder"
        folder.mkdir()
        shutil.copy(b / "sim" / "white.dng", folder / "good.dng")
        make(folder, b)
        return ["inspect", folder]

    return argv


# -- byte surgery ------------------------------------------------------------------------------------------------
def shared(name: str) -> Callable[[Path, Path], bytes]:
    return lambda d, b: (b / name).read_bytes()


def tiff_entry(data: bytes, tag: int) -> int:
    """Offset of ``tag``'s entry in IFD 0 or the EXIF IFD of a little-endian TIFF."""
    ifds = [struct.unpack_from("<I", data, 4)[0]]
    for ifd in ifds:
        for i in range(struct.unpack_from("<H", data, ifd)[0]):
            position = ifd + 2 + 12 * i
            code, _, _, value = struct.unpack_from("<HHII", data, position)
            if code == tag:
                return position
            if code == 34665:
                ifds.append(value)
    raise KeyError(tag)


def retag(data: bytes, tag: int, *, kind: int | None = None, count: int | None = None, value=None) -> bytes:
    """``data`` with ``tag``'s entry given another field type, count or value (int, or bytes: appended if long)."""
    out = bytearray(data)
    position = tiff_entry(data, tag)
    _, old_kind, old_count = struct.unpack_from("<HHI", out, position)
    field_bytes = bytes(out[position + 8 : position + 12])
    if isinstance(value, int):
        field_bytes = struct.pack("<I", value) if (kind or old_kind) == 4 else struct.pack("<HH", value, 0)
    elif isinstance(value, bytes):
        if len(value) <= 4:
            field_bytes = value.ljust(4, b"\0")
        else:
            out += b"\0" * (len(out) % 2)
            field_bytes = struct.pack("<I", len(out))
            out += value
    struct.pack_into("<HHI4s", out, position, tag, kind or old_kind, old_count if count is None else count,
                     field_bytes)  # fmt: skip
    return bytes(out)


def dng(change: Callable[[bytes], bytes], name: str = "bad.dng") -> Callable[[Path, Path], Path]:
    return lambda d, b: write(d / name, change((b / "sim" / "white.dng").read_bytes()))


def rational(numerator: int, denominator: int) -> bytes:
    return struct.pack("<II", numerator, denominator)


def npy(header: str, data: bytes = b"", version: tuple[int, int] = (1, 0)) -> bytes:
    """A .npy file with this header dictionary, whatever it says, and these data bytes."""
    text = header.encode("latin1")
    preamble = 10 if version[0] == 1 else 12
    text += b" " * (63 - (preamble + len(text)) % 64) + b"\n"
    length = struct.pack("<H" if version[0] == 1 else "<I", len(text))
    return b"\x93NUMPY" + bytes(version) + length + text + data


def npy_of(array: np.ndarray) -> bytes:
    f = io.BytesIO()
    np.save(f, array, allow_pickle=True)
    return f.getvalue()


def zipped(members: dict[str, bytes], compress: bool = False) -> bytes:
    f = io.BytesIO()
    with zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return f.getvalue()


def members(data: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        return {name: z.read(name) for name in z.namelist()}


def npz_with(source: str, *, meta=None, arrays: dict | None = None, drop: tuple[str, ...] = (),
             raw: dict[str, bytes] | None = None) -> Callable[[Path, Path], bytes]:  # fmt: skip
    """A shared .npz (a calibration or a raw npz) with its JSON record changed (``meta``: a dict merged in, or a
    function of the record), arrays replaced, members dropped, or members replaced by raw bytes."""

    def make(d: Path, b: Path) -> bytes:
        parts = members((b / source).read_bytes())
        if meta is not None:
            record = json.loads(str(np.load(io.BytesIO(parts["metadata.npy"]))))
            record = meta(record) if callable(meta) else {**record, **meta}
            parts["metadata.npy"] = npy_of(np.array(json.dumps(record)))
        for name, array in (arrays or {}).items():
            parts[f"{name}.npy"] = npy_of(np.asarray(array))
        for name in drop:
            parts.pop(f"{name}.npy")
        for name, data in (raw or {}).items():
            parts[f"{name}.npy"] = data
        return zipped(parts)

    return make


def cal_array(name: str, change: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path, Path], bytes]:
    def make(d: Path, b: Path) -> bytes:
        array = np.load(io.BytesIO(members((b / "cal.npz").read_bytes())[f"{name}.npy"]))
        return npz_with("cal.npz", arrays={name: change(array)})(d, b)

    return make


def to(name: str, make: Callable[[Path, Path], bytes | str]) -> Callable[[Path, Path], Path]:
    """The bytes ``make`` gives, written to ``name`` in the case's folder."""
    return lambda d, b: write(d / name, make(d, b))


def const(data: bytes | str) -> Callable[[Path, Path], bytes | str]:
    return lambda d, b: data


def nested(depth: int = 100_000) -> str:
    return "[" * depth + "]" * depth


def json_with(source: str, change: Callable[[dict], object]) -> Callable[[Path, Path], str]:
    def make(d: Path, b: Path) -> str:
        record = json.loads((b / source).read_text())
        changed = change(record)
        return json.dumps(record if changed is None else changed)

    return make


def fifo(name: str) -> Callable[[Path, Path], Path]:
    def make(d: Path, b: Path) -> Path:
        os.mkfifo(d / name)
        return d / name

    return make


def folder(name: str) -> Callable[[Path, Path], Path]:
    def make(d: Path, b: Path) -> Path:
        (d / name).mkdir()
        return d / name

    return make


def loop(name: str) -> Callable[[Path, Path], Path]:
    def make(d: Path, b: Path) -> Path:
        os.symlink(name, d / name)
        return d / name

    return make


def link(name: str, target: str) -> Callable[[Path, Path], Path]:
    def make(d: Path, b: Path) -> Path:
        os.symlink(target, d / name)
        return d / name

    return make


def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def forged_png(width: int, height: int, bits: int = 16) -> bytes:
    """A PNG that declares ``width`` x ``height`` and holds a few kilobytes of zeros."""
    header = struct.pack(">IIBBBBB", width, height, bits, 2, 0, 0, 0)
    pixels = zlib.compress(bytes(1 << 16), 9)
    return b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", header) + png_chunk(b"IDAT", pixels) + png_chunk(b"IEND", b"")


def forged_jpeg(width: int, height: int) -> bytes:
    sof = struct.pack(">BHHB", 8, height, width, 3) + b"\x01\x11\x00\x02\x11\x00\x03\x11\x00"
    return b"\xff\xd8" + b"\xff\xc0" + struct.pack(">H", len(sof) + 2) + sof + bytes(64) + b"\xff\xd9"


def forged_tiff(width: int, height: int) -> bytes:
    """A greyscale TIFF that declares ``width`` x ``height`` and one strip of 64 bytes."""
    entries = [(256, 4, 1, width), (257, 4, 1, height), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 1),
               (273, 4, 1, 8 + 2 + 12 * 7 + 4), (279, 4, 1, 64)]  # fmt: skip
    ifd = struct.pack("<H", len(entries)) + b"".join(struct.pack("<HHII", *e) for e in entries) + bytes(4)
    return b"II*\x00" + struct.pack("<I", 8) + ifd + bytes(64)


def brcm(change: Callable[[bytearray, int], None]) -> Callable[[Path, Path], Path]:
    """The shared JPEG+raw file with its BRCM block changed in place (``change(data, start_of_block)``)."""

    def make(d: Path, b: Path) -> Path:
        data = bytearray((b / "brcm.jpg").read_bytes())
        change(data, data.rfind(b"BRCM"))
        return write(d / "bad.jpg", bytes(data))

    return make


def poke(offset: int, fmt: str, value) -> Callable[[bytearray, int], None]:
    return lambda data, start: struct.pack_into(fmt, data, start + offset, value)


def npy_pair(npy_bytes=None, sidecar=None, name: str = "bad") -> Callable[[Path, Path], Path]:
    """The shared picamera2 buffer (.npy and its JSON sidecar), either part replaced (``None``: kept; ``False``:
    left out); each is bytes, text, or a function of the shared one."""

    def make(d: Path, b: Path) -> Path:
        for part, replacement in (("npy", npy_bytes), ("json", sidecar)):
            original = (b / "npy" / f"white.{part}").read_bytes()
            if replacement is False:
                continue
            data = replacement(original) if callable(replacement) else original if replacement is None else replacement
            write(d / f"{name}.{part}", data)
        return d / f"{name}.npy"

    return make


def sidecar_with(change: Callable[[dict], object]) -> Callable[[bytes], str]:
    def make(original: bytes) -> str:
        record = json.loads(original)
        changed = change(record)
        return json.dumps(record if changed is None else changed)

    return make


def headless(data: Callable[[Path, Path], bytes], *options: str) -> Argv:
    def argv(d: Path, b: Path) -> list:
        return ["calibrate", "--white", write(d / "bad.raw", data(d, b)), "--raw-format", *options,
                "--out", d / "cal.npz"]  # fmt: skip

    return argv


def copies(*names: str) -> Callable[[Path, Path], None]:
    """Copy shared files into the case's folder (for cases whose output could destroy them)."""

    def make(d: Path, b: Path) -> None:
        for name in names:
            source = b / name
            (shutil.copytree if source.is_dir() else shutil.copy)(source, d / Path(name).name)

    return make


def then(prepare: Callable[[Path, Path], object], make: Callable[[Path, Path], object]) -> Callable:
    """``prepare`` the case's folder, then ``make`` what it gives (a path, or a command line)."""

    def both(d: Path, b: Path):
        prepare(d, b)
        return make(d, b)

    return both


# ======================================================================================== numeric and other options
def sim_refs(b: Path) -> list:
    return [f"--{r}={b / 'sim' / f'{r}.dng'}" for r in ("white", "red", "green", "blue", "black")]


def calibrate_with(*options: str) -> Argv:
    return lambda d, b: ["calibrate", *sim_refs(b), *options, "--out", d / "cal.npz"]


def correct_with(*options: str) -> Argv:
    return lambda d, b: ["correct", b / "cal.npz", b / "sim" / "target.dng", *options, "--out", d / "out"]


def processed_with(*options: str) -> Argv:
    return lambda d, b: ["correct", b / "cal.npz", b / "good.png", "--processed", *options, "--out", d / "out"]


def export_tuning_with(*options: str) -> Argv:
    return lambda d, b: ["export-tuning", b / "cal.npz", "--target", "vc4", *options, "--out", d / "tuning.json"]


def apply_tuning_with(*options: str) -> Argv:
    return lambda d, b: ["apply-tuning", b / "tuning.json", b / "sim" / "white.dng", *options, "--out", d / "a.tiff"]


def report_with(*options: str) -> Argv:
    return lambda d, b: ["report", b / "cal.npz", *options, "--out", d / "report"]


def simulate_with(*options: str) -> Argv:
    return lambda d, b: ["simulate", "--no-noise", *options, "--out", d / "sim"]


def target_with(*options: str, out: str = "target.png") -> Argv:
    return lambda d, b: ["target", *options, "--out", d / out]


def demo_with(*options: str) -> Argv:
    return lambda d, b: ["demo", *options, "--out", d / "demo"]


def acquire_with(*options: str) -> Argv:
    return lambda d, b: ["acquire", "--camera", "sim", "--illuminator", "sim", "--size", "96x64", *options,
                         "--out", d / "run"]  # fmt: skip


def headless_with(*options: str) -> Argv:
    def argv(d: Path, b: Path) -> list:
        return ["calibrate", "--white", b / "white.raw", "--raw-format", "SBGGR10_CSI2P", *options,
                "--out", d / "cal.npz"]  # fmt: skip

    return argv


# calibrate: smoothing, bin size, levels, pattern, headless-dump options
case("calibrate --smoothing 1e6", calibrate_with("--smoothing", "1e6"), "smoothing", "1e+06")
case("calibrate --smoothing 1e5", calibrate_with("--smoothing", "1e5"), "smoothing", "100000")
case("calibrate --smoothing nan", calibrate_with("--smoothing", "nan"), "--smoothing", "nan")
case("calibrate --bin-size 0", calibrate_with("--bin-size", "0"), "bin size", "0")
case("calibrate --bin-size 100000", calibrate_with("--bin-size", "100000"), "bin size", "white.dng")
case("calibrate --black-level nan", calibrate_with("--black-level", "nan"), "--black-level", "nan")
case("calibrate --black-level -5", calibrate_with("--black-level", "-5"), "--black-level", "-5")
case("calibrate --black-level above white", calibrate_with("--black-level", "5000"), "white.dng")
case("calibrate --pattern XGGB", calibrate_with("--pattern", "XGGB"), "--pattern", "XGGB")
case("calibrate --stride 0", headless_with("--size", "96x64", "--stride", "0"), "--stride", "0")
case("calibrate --frame -1", headless_with("--size", "96x64", "--frame", "-1"), "--frame", "-1")
case("calibrate --size 95x64", headless_with("--size", "95x64"), "--size", "95x64")
case("calibrate --size 60000x60000", headless_with("--size", "60000x60000"), "white.raw", "60000x60000")
# calibrate and correct: the sensor mode (issue 30)
case("calibrate --sensor-crop outside the sensor", calibrate_with("--sensor-crop", "0,0,200,64"), "white.dng",
     "--sensor-crop 0,0,200,64 lies outside the 96x64 sensor")  # fmt: skip
case("calibrate --sensor-crop of another size", calibrate_with("--sensor-crop", "0,0,50,64"), "white.dng",
     "cannot come from a 50x64 sensor area")  # fmt: skip
case("calibrate --sensor-crop 1,2,3", calibrate_with("--sensor-crop", "1,2,3"), "--sensor-crop", "X,Y,WIDTH,HEIGHT")
case("calibrate --sensor-mode 9x9", calibrate_with("--sensor-mode", "9x9"), "white.dng", "imx219 has no such mode",
     "3280x2464:10")  # fmt: skip
case("calibrate --sensor-mode 1920x1080 of a 96x64 frame", calibrate_with("--sensor-mode", "1920x1080"), "white.dng",
     "the frame is 96x64, the mode 1920x1080")  # fmt: skip
case("calibrate --sensor-mode text", calibrate_with("--sensor-mode", "full"), "--sensor-mode", "WIDTHxHEIGHT")
case("correct --sensor-mode 1332x990", correct_with("--sensor-mode", "1332x990"), "target.dng", "no such mode")
case("correct --sensor-crop outside the sensor", correct_with("--sensor-crop", "90,0,96,64"), "target.dng",
     "lies outside the 96x64 sensor")  # fmt: skip


def flipped_red(d: Path, b: Path) -> Path:
    """The red reference as a file that says it was read flipped (another sensor mode than the white's)."""
    from picamcal import read_raw
    from picamcal.raw import write_dng

    raw = read_raw(b / "sim" / "red.dng")
    raw.metadata["sensor_flips"] = [True, True]
    return write_dng(d / "red.dng", raw)


case("calibrate references from different modes", calibrate_full("red", flipped_red), "red.dng",
     "different sensor modes")  # fmt: skip
# verify: what is refused before any camera is opened
case("verify --camera sim", lambda d, b: ["verify", "--camera", "sim"], "--camera", "picamera2")
case("verify --tolerance 0,x", lambda d, b: ["verify", "--tolerance", "0,x"], "--tolerance")
case("verify --tuning missing", lambda d, b: ["verify", "--tuning", d / "missing.json"], "missing.json")
case("verify --tuning a calibration", lambda d, b: ["verify", "--tuning", b / "cal.npz"], "cal.npz")
# correct: workers, mosaic, modes, formats, encodings
case("correct --workers 100000", correct_with("--workers", "100000"), "--workers", "100000")
case("correct --mosaic without --zarr", correct_with("--mosaic", "2x2"), "--mosaic", "--zarr")
case("correct --zarr --mosaic 0x2", lambda d, b: ["correct", b / "cal.npz", b / "sim" / "target.dng", "--zarr",
     d / "stack.zarr", "--mosaic", "0x2"], "--mosaic")  # fmt: skip
case("correct --zarr --mosaic too small", lambda d, b: ["correct", b / "cal.npz", b / "sim" / "target.dng",
     b / "sim" / "white.dng", "--zarr", d / "stack.zarr", "--mosaic", "1x1", "--workers", "0"], "mosaic")  # fmt: skip
case("correct --black-level nan", correct_with("--black-level", "nan"), "--black-level", "nan")
case("correct --binned --processed", processed_with("--binned"), "--binned")
case("correct --white without --processed", lambda d, b: ["correct", b / "cal.npz", b / "sim" / "target.dng",
     "--white", b / "good.png", "--out", d / "out"], "--white")  # fmt: skip
case("correct --input-encoding gamma:nan", processed_with("--input-encoding", "gamma:nan"), "gamma:nan")
case("correct --input-encoding tuning:missing", processed_with("--input-encoding", "tuning:missing.json"),
     "missing.json")  # fmt: skip
# export-tuning and apply-tuning
case("export-tuning --ct 0", export_tuning_with("--ct", "0"), "--ct", "0")
case("export-tuning --ct 1000000", export_tuning_with("--ct", "1000000"), "--ct", "1e+06")
case("export-tuning --luminance-strength nan", export_tuning_with("--luminance-strength", "nan"), "luminance")
case("export-tuning --luminance-strength 2", export_tuning_with("--luminance-strength", "2"), "luminance")
case("export-tuning both into one file", lambda d, b: ["export-tuning", b / "cal.npz", "--out", d / "t.json"],
     "--out")  # fmt: skip
case("apply-tuning --colour-gains 0,1", apply_tuning_with("--colour-gains", "0,1"), "--colour-gains")
case("apply-tuning --colour-gains nan,1", apply_tuning_with("--colour-gains", "nan,1"), "--colour-gains")
case("apply-tuning --sensor-crop inf", apply_tuning_with("--sensor-crop", "0,0,inf,64"), "--sensor-crop")
case("apply-tuning --sensor-size 0x0", apply_tuning_with("--sensor-size", "0x0"), "--sensor-size")
case("apply-tuning --ct 0", apply_tuning_with("--ct", "0"), "--ct", "0")
# report
case("report --cra 0", report_with("--cra", "0"), "--cra", "0")
case("report --cra 90", report_with("--cra", "90"), "--cra", "90")
case("report --cra nan", report_with("--cra", "nan"), "--cra", "nan")
# simulate, target, demo, acquire
case("simulate --size 60000x60000", simulate_with("--size", "60000x60000"), "60000x60000")
case("simulate --size 95x64", simulate_with("--size", "95x64"), "--size", "95x64")
case("simulate --seed -1", simulate_with("--size", "96x64", "--seed", "-1"), "seed", "-1")
case("simulate --dust -1", simulate_with("--size", "96x64", "--dust", "-1"), "dust", "-1")
case("simulate --dust 1e8", simulate_with("--size", "96x64", "--dust", "100000000"), "dust", "100000000")
case("simulate --tilt 90", simulate_with("--size", "96x64", "--tilt", "90", "0"), "tilt", "90")
case("simulate --sensor monochrome", simulate_with("--size", "96x64", "--sensor", "ov9281"), "ov9281")
case("simulate --format brcm 96x64", simulate_with("--size", "96x64", "--format", "brcm"), "96x64")
case("target --size 60000x60000", target_with("--size", "60000x60000"), "60000x60000")
case("target --size 32x32", target_with("--size", "32x32"), "32")
case("demo --size 60000x60000", demo_with("--size", "60000x60000"), "60000x60000")
case("demo --seed -5", demo_with("--size", "96x64", "--seed", "-5"), "seed", "-5")
case("demo --tuning-base missing", demo_with("--size", "96x64", "--tuning-base", "missing.json"), "missing.json")
case("acquire --target-fraction 0", acquire_with("--target-fraction", "0"), "--target-fraction", "0")
case("acquire --settle -1", acquire_with("--settle", "-1"), "--settle", "-1")
case("acquire --max-exposure 0", acquire_with("--max-exposure", "0"), "--max-exposure", "0")
case("acquire --camera unknown", lambda d, b: ["acquire", "--camera", "webcam", "--illuminator", "manual", "--out",
     d / "run"], "webcam")  # fmt: skip
case("acquire --size 60000x60000", lambda d, b: ["acquire", "--camera", "sim", "--illuminator", "sim", "--size",
     "60000x60000", "--out", d / "run"], "60000x60000")  # fmt: skip
# extra colour references, the noise bound, the screens (issue 13)
case("calibrate --max-noise-penalty 0.5", calibrate_with("--max-noise-penalty", "0.5"), "--max-noise-penalty", "0.5")
case("calibrate --max-noise-penalty nan", calibrate_with("--max-noise-penalty", "nan"), "--max-noise-penalty")
case("calibrate --colour identical to red", lambda d, b: ["calibrate", *sim_refs(b), "--colour",
     f"same={b / 'sim' / 'red.dng'}", "--out", d / "cal.npz"], "red.dng")  # fmt: skip
case("calibrate --colour named twice", lambda d, b: ["calibrate", *sim_refs(b), "--colour",
     f"a={b / 'sim' / 'target.dng'}", "--colour", f"a={b / 'sim' / 'white.dng'}", "--out", d / "cal.npz"],
     "--colour")  # fmt: skip
case("target --colour without --screens", target_with("--colour", "cyan=0,255,255"), "--colour")
case("target --screens --colour 300", target_with("--screens", "--colour", "cyan=0,300,255", out="screens"),
     "--colour", "300")  # fmt: skip
case("acquire --colour red", acquire_with("--colour", "red=255,0,0"), "--colour", "red")
case("acquire --colour two values", acquire_with("--colour", "cyan=0,255"), "--colour", "NAME=R,G,B")
case("simulate --spectral --colour 256", simulate_with("--size", "96x64", "--spectral", "--colour", "amber=256,0,0"),
     "--colour", "256")  # fmt: skip
case("simulate --spectral --dust 3", simulate_with("--size", "96x64", "--spectral", "--dust", "3"), "--dust")
# the pixel limit's own variable
case("PICAMCAL_MAX_PIXELS=many", lambda d, b: ["inspect", b / "sim" / "white.dng"], "PICAMCAL_MAX_PIXELS",
     env={"PICAMCAL_MAX_PIXELS": "many"})  # fmt: skip
case("PICAMCAL_MAX_PIXELS=1000", lambda d, b: ["calibrate", "--white", b / "sim" / "white.dng", "--out",
     d / "cal.npz"], "white.dng", "PICAMCAL_MAX_PIXELS", env={"PICAMCAL_MAX_PIXELS": "1000"})  # fmt: skip


# ================================================================================================= DNG files
def header_ifd(offset: int) -> Callable[[bytes], bytes]:
    return lambda data: data[:4] + struct.pack("<I", offset) + data[8:]


def next_ifd(offset: int) -> Callable[[bytes], bytes]:
    def change(data: bytes) -> bytes:
        entries = struct.unpack_from("<H", data, 8)[0]
        at = 8 + 2 + 12 * entries
        return data[:at] + struct.pack("<I", offset) + data[at + 4 :]

    return change


def description(record: object) -> Callable[[bytes], bytes]:
    text = (record if isinstance(record, str) else json.dumps(record)).encode() + b"\0"
    return lambda data: retag(data, 270, count=len(text), value=text)


def sparse_dng(width: int, height: int) -> Callable[[Path, Path], Path]:
    """A DNG that declares ``width`` x ``height`` 16-bit pixels, with a sparse file that long behind it."""

    def make(d: Path, b: Path) -> Path:
        data = (b / "sim" / "white.dng").read_bytes()
        for tag, value in ((256, width), (257, height), (278, height), (279, width * height * 2)):
            data = retag(data, tag, value=value)
        path = write(d / "bad.dng", data)
        with open(path, "r+b") as f:
            f.truncate(struct.unpack_from("<I", data, tiff_entry(data, 273) + 8)[0] + width * height * 2)
        return path

    return make


def cut(length: int) -> Callable[[bytes], bytes]:
    return lambda data: data[:length]


def copy_shared(name: str, as_name: str) -> Callable[[Path, Path], Path]:
    def make(d: Path, b: Path) -> Path:
        shutil.copy(b / name, d / as_name)
        return d / as_name

    return make


case("dng empty file", calibrate_white(to("bad.dng", const(b""))), "bad.dng")
case("dng cut inside the strip", correct_batch(dng(cut(9000))), "bad.dng", **batch())
case("dng wrong magic", calibrate_white(dng(lambda data: b"XX*\x00" + data[4:])), "bad.dng")
case("dng IFD beyond the end", inspect_one(dng(header_ifd(10**9))), "bad.dng")
case("dng IFD chain loops", inspect_one(dng(next_ifd(8))), "bad.dng", described=True)
case("dng EXIF IFD is IFD 0", inspect_one(dng(lambda data: retag(data, 34665, value=8))), "bad.dng", described=True)
case("dng forged 16000x16000 sparse", calibrate_white(sparse_dng(16000, 16000)), "bad.dng", "16000x16000")
case("dng cut inside the strip, into a stack", correct_zarr_batch(dng(cut(9000))), "bad.dng", status=1,
     written=("stack.zarr",))  # fmt: skip
case("dng forged 16000x16000 into a stack", correct_zarr_batch(sparse_dng(16000, 16000)), "bad.dng", status=1,
     written=("stack.zarr",))  # fmt: skip
case("dng forged 16000x16000 in a batch", correct_batch(sparse_dng(16000, 16000)), "bad.dng", **batch())
case("dng strip beyond the end", calibrate_white(dng(lambda data: retag(data, 273, value=10**8))), "bad.dng")
case("dng 32 bits per sample", calibrate_white(dng(lambda data: retag(data, 258, value=32))), "bad.dng")
case("dng SamplesPerPixel count 2", calibrate_white(dng(lambda data: retag(data, 277, count=2))), "bad.dng")
case("dng JPEG compression", calibrate_white(dng(lambda data: retag(data, 259, value=7))), "bad.dng")
case("dng RGB photometric", calibrate_white(dng(lambda data: retag(data, 262, value=2))), "bad.dng")
case("dng CFAPattern of unknown colours", calibrate_white(dng(lambda data: retag(data, 33422, value=b"\5\5\5\5"))),
     "bad.dng")  # fmt: skip
case("dng BlackLevel 0/0", calibrate_white(dng(lambda data: retag(data, 50714, count=1, value=rational(0, 0)))),
     "bad.dng")  # fmt: skip
case("dng BlackLevel above WhiteLevel", calibrate_white(dng(lambda data: retag(data, 50714, count=1,
     value=rational(2000, 1)))), "bad.dng")  # fmt: skip
case("dng WhiteLevel 0", calibrate_white(dng(lambda data: retag(data, 50717, value=0))), "bad.dng")
case("dng AsShotNeutral 1/0", inspect_one(dng(lambda data: retag(data, 50728, value=rational(1, 0) * 3))),
     "bad.dng", described=True, warned=True)  # fmt: skip
case("dng ExposureTime two values", inspect_one(dng(lambda data: retag(data, 33434, count=2,
     value=rational(1, 100) * 2))), "bad.dng", described=True, warned=True)  # fmt: skip
case("dng ExposureTime as text", inspect_one(dng(lambda data: retag(data, 33434, kind=2, count=8,
     value=b"1/100 s\0"))), "bad.dng", described=True, warned=True)  # fmt: skip
case("dng ImageDescription count 2**30", inspect_one(dng(lambda data: retag(data, 270, count=2**30))), "bad.dng",
     described=True)  # fmt: skip
case("dng odd metadata: sensor 5", inspect_one(dng(description({"picamcal": {"sensor": 5}}))), "bad.dng",
     described=True)  # fmt: skip
case("dng odd metadata: deep JSON", inspect_one(dng(description("[" * 50_000 + "]" * 50_000))), "bad.dng",
     described=True)  # fmt: skip
case("dng odd metadata: brackets", inspect_one(dng(description({"picamcal": {"model": "[/bold]x[red"}}))),
     "bad.dng", described=True)  # fmt: skip
case("dng colour gains text", inspect_one(dng(description({"picamcal": {"colour_gains": "abc"}}))), "bad.dng",
     described=True)  # fmt: skip
case("dng a folder", calibrate_white(folder("bad.dng")), "bad.dng")
case("dng a FIFO to calibrate", calibrate_white(fifo("bad.dng")), "bad.dng")
case("dng a FIFO in a batch", correct_batch(fifo("bad.dng")), "bad.dng", **batch())
case("dng a symlink loop to calibrate", calibrate_white(loop("bad.dng")), "bad.dng")
case("dng a symlink loop in a batch", correct_batch(loop("bad.dng")), "bad.dng", **batch())
case("dng a link to /dev/zero", inspect_one(link("bad.dng", "/dev/zero")), "bad.dng")
case("dng missing", calibrate_white(lambda d, b: d / "bad.dng"), "bad.dng")
case("dng missing in a batch", correct_batch(lambda d, b: d / "bad.dng"), "bad.dng", **batch())
case("dng a PNG by another name", calibrate_white(to("bad.dng", shared("good.png"))), "bad.dng")
case("dng another size in a batch", correct_batch(copy_shared("small.dng", "bad.dng")), "bad.dng", **batch())
case("dng another Bayer order as green", calibrate_full("green", copy_shared("rggb.dng", "bad.dng")), "bad.dng")
case("dng saturated white", calibrate_white(copy_shared("saturated.dng", "bad.dng")), "bad.dng")
case("dng warned, then refused", calibrate_white(copy_shared("gbrg.dng", "bad.dng"), "--bin-size", "100000"),
     "bad.dng: bin size", "(after 1 warning(s): ", "GBRG")  # fmt: skip
case("dng survey of a folder", survey(dng(cut(9000))), "bad.dng", status=1, survey=True)


# ============================================================================== legacy JPEG+raw (BRCM) files
# Offsets in the block's header (FORMATS.md section 2): width, height, padding right, format, Bayer order.
case("brcm a JPEG without a raw block", calibrate_white(copy_shared("good.jpg", "bad.jpg")), "bad.jpg")
case("brcm block cut short", calibrate_white(to("bad.jpg", lambda d, b: (b / "brcm.jpg").read_bytes()[:-10_000])),
     "bad.jpg")  # fmt: skip
case("brcm block cut to its header", calibrate_white(to("bad.jpg", lambda d, b: (lambda data: data[
     : data.rfind(b"BRCM") + 32768])((b / "brcm.jpg").read_bytes()))), "bad.jpg")  # fmt: skip
case("brcm width 65535", calibrate_white(brcm(poke(0xD0, "<H", 65535))), "bad.jpg")
case("brcm height 0", calibrate_white(brcm(poke(0xD2, "<H", 0))), "bad.jpg")
case("brcm padding 60000", calibrate_white(brcm(poke(0xD4, "<H", 60000))), "bad.jpg")
case("brcm Bayer order 7", calibrate_white(brcm(poke(0xF4, "<B", 7))), "bad.jpg")
case("brcm another size in a batch", correct_batch(copy_shared("brcm.jpg", "bad.jpg")), "bad.jpg", **batch())


# ================================================================================ picamera2 .npy + JSON sidecar
case("npy sidecar missing", calibrate_white(npy_pair(sidecar=False)), "bad.npy|bad.json")
case("npy sidecar empty", inspect_one(npy_pair(sidecar=b"")), "bad.json|bad.npy")
case("npy sidecar not JSON", calibrate_white(npy_pair(sidecar="{config: raw}")), "bad.json|bad.npy")
case("npy sidecar nested 100000 deep", calibrate_white(npy_pair(sidecar=nested())), "bad.json|bad.npy")
case("npy config a string", calibrate_white(npy_pair(sidecar=sidecar_with(lambda r: r.update(config="raw")))),
     "bad.json|bad.npy")  # fmt: skip
case("npy size forged 60000x60000", calibrate_white(npy_pair(sidecar=sidecar_with(lambda r: r["config"][
     "raw"].update(size=[60000, 60000])))), "bad.json|bad.npy")  # fmt: skip
case("npy format unknown", inspect_one(npy_pair(sidecar=sidecar_with(lambda r: r["config"]["raw"].update(
     format="SBGGR11_CSI2P")))), "bad.json|bad.npy")  # fmt: skip
case("npy black levels infinite", calibrate_white(npy_pair(sidecar=lambda original: original.decode().replace(
     "4096", "1e400"))), "bad.json|bad.npy")  # fmt: skip
case("npy odd metadata: exposure text", inspect_one(npy_pair(sidecar=sidecar_with(lambda r: r["metadata"].update(
     ExposureTime="fast", AnalogueGain=[1, 2])))), "bad.json|bad.npy", described=True)  # fmt: skip
case("npy sidecar a FIFO", calibrate_white(then(fifo("bad.json"), npy_pair(sidecar=False))), "bad.json")
case("npy sidecar a folder", inspect_one(then(folder("bad.json"), npy_pair(sidecar=False))), "bad.json")
case("npy cut inside its header", calibrate_white(npy_pair(npy_bytes=lambda data: data[:30])), "bad.npy")
case("npy object dtype", calibrate_white(npy_pair(npy_bytes=npy_of(np.array([{"a": 1}] * 4, dtype=object)))),
     "bad.npy")  # fmt: skip
case("npy forged 34000x34000", calibrate_white(npy_pair(npy_bytes=npy(
     "{'descr': '|u1', 'fortran_order': False, 'shape': (34000, 34000), }", bytes(8192)))), "bad.npy")  # fmt: skip
case("npy forged 34000x34000 in a batch", correct_batch(npy_pair(npy_bytes=npy(
     "{'descr': '|u1', 'fortran_order': False, 'shape': (34000, 34000), }", bytes(8192)))), "bad.npy",
     **batch())  # fmt: skip
case("npy header of wrong types", calibrate_white(npy_pair(npy_bytes=npy("{'descr': 5, 'fortran_order': 'no', "
     "'shape': 'big', }", bytes(8192)))), "bad.npy")  # fmt: skip


# ================================================================================================ raw .npz
def raw_npz(**changes) -> Callable[[Path, Path], Path]:
    return to("bad.npz", npz_with("npz/white.npz", **changes))


case("npz not a zip", calibrate_white(to("bad.npz", const(b"PK\x03\x04 this is not a zip"))), "bad.npz")
case("npz an empty zip", correct_batch(to("bad.npz", const(zipped({})))), "bad.npz", **batch())
case("npz without the mosaic", calibrate_white(raw_npz(drop=("bayer",))), "bad.npz")
case("npz record not JSON", calibrate_white(raw_npz(arrays={"metadata": np.array("{format: raw")})), "bad.npz")
case("npz record nested 100000 deep", calibrate_white(raw_npz(arrays={"metadata": np.array(nested())})), "bad.npz")
case("npz black level NaN", calibrate_white(raw_npz(meta={"black_level": [float("nan")] * 4})), "bad.npz")
case("npz white level 0 in a batch", correct_batch(raw_npz(meta={"white_level": 0})), "bad.npz", **batch())
case("npz complex mosaic", calibrate_white(raw_npz(arrays={"bayer": np.zeros((64, 96), np.complex64)})), "bad.npz")
case("npz object mosaic", calibrate_white(raw_npz(arrays={"bayer": np.array([[None] * 96] * 64)})), "bad.npz")
case("npz mosaic of three dimensions", correct_batch(raw_npz(arrays={"bayer": np.zeros((64, 96, 3), np.uint16)})),
     "bad.npz", **batch())  # fmt: skip
case("npz mosaic all at 65535", calibrate_white(raw_npz(arrays={"bayer": np.full((64, 96), 65535, np.uint16)})),
     "bad.npz")  # fmt: skip
case("npz mosaic forged 10**6 squared", calibrate_white(raw_npz(raw={"bayer": npy(
     "{'descr': '<u2', 'fortran_order': False, 'shape': (1000000, 1000000), }", bytes(12288))})),
     "bad.npz")  # fmt: skip
case("npz member inflating to 210 MB", calibrate_white(copy_shared("bomb_raw.npz", "bad.npz")), "bad.npz")


# ======================================================================================== headless raw dumps
def dump(length: int | None = None, frames: float = 1.0) -> Callable[[Path, Path], bytes]:
    def make(d: Path, b: Path) -> bytes:
        frame = (b / "white.raw").read_bytes()
        return (frame * 2)[: int(len(frame) * frames)] if length is None else frame[:length]

    return make


case("headless empty file", headless(dump(0), "SBGGR10_CSI2P", "--size", "96x64"), "bad.raw")
case("headless 1000 bytes", headless(dump(1000), "SBGGR10_CSI2P", "--size", "96x64"), "bad.raw")
case("headless one and a half frames", headless(dump(frames=1.5), "SBGGR10_CSI2P", "--size", "96x64"), "bad.raw")
case("headless a folder", lambda d, b: ["calibrate", "--white", folder("bad.raw")(d, b), "--raw-format",
     "SBGGR10_CSI2P", "--size", "96x64", "--out", d / "cal.npz"], "bad.raw")  # fmt: skip
case("headless wrong size, the one file", lambda d, b: ["correct", b / "cal.npz", b / "white.raw", "--raw-format",
     "SBGGR10_CSI2P", "--size", "64x96", "--out", d / "out", "--workers", "0"], "white.raw")  # fmt: skip


# ======================================================================================== the sensor (issue 23)
# A slip of a registry name, on every command that reads raw files with --sensor; a sensor outside the registry, or a
# frame of a size several registry sensors share (1920x1080: a zero SRGGB12_CSI2P frame), with no black level.
case("calibrate --sensor imx2l9", headless_with("--size", "96x64", "--sensor", "imx2l9"), "--sensor",
     "unknown sensor 'imx2l9'; did you mean imx219?")  # fmt: skip
case("correct --sensor imx2l9", correct_with("--sensor", "imx2l9"), "--sensor", "did you mean imx219?")
case("inspect --sensor imx2l9", lambda d, b: ["inspect", b / "sim" / "white.dng", "--sensor", "imx2l9"], "--sensor",
     "did you mean imx219?")  # fmt: skip
case("apply-tuning --sensor imx2l9", apply_tuning_with("--sensor", "imx2l9"), "--sensor", "did you mean imx219?")
case("headless sensor outside the registry", headless_with("--size", "96x64", "--sensor", "imx298"), "white.raw",
     "black level of the imx298", "--black-level N or a dark frame")  # fmt: skip
case("headless size several sensors share", headless(lambda d, b: bytes(2880 * 1080), "SRGGB12_CSI2P", "--size",
     "1920x1080"), "bad.raw", "imx290, imx462, se327m12, imx327 or imx662", "--sensor")  # fmt: skip


# ============================================================================== processed PNG, JPEG and TIFF
def tiff_of(array: np.ndarray) -> Callable[[Path, Path], bytes]:
    def make(d: Path, b: Path) -> bytes:
        f = io.BytesIO()
        tifffile.imwrite(f, array, photometric="rgb" if array.ndim == 3 else "minisblack")
        return f.getvalue()

    return make


case("processed PNG cut short", processed_batch(to("bad.png", lambda d, b: (b / "good.png").read_bytes()[:200])),
     "bad.png", **batch())  # fmt: skip
case("processed PNG forged 20000x20032", processed_batch(to("bad.png", const(forged_png(20000, 20032)))), "bad.png",
     **batch())  # fmt: skip
case("processed JPEG forged 65000x65000", processed_batch(to("bad.jpg", const(forged_jpeg(65000, 65000)))),
     "bad.jpg", **batch())  # fmt: skip
case("processed TIFF cut short", processed_batch(to("bad.tif", lambda d, b: tiff_of(np.zeros((64, 96, 3),
     np.uint16))(d, b)[:100])), "bad.tif", **batch())  # fmt: skip
case("processed TIFF forged 40000x40000", processed_batch(to("bad.tif", const(forged_tiff(40000, 40000)))),
     "bad.tif", **batch())  # fmt: skip
case("processed TIFF complex", processed_batch(to("bad.tif", tiff_of(np.zeros((64, 96, 3), np.complex64)))),
     "bad.tif", **batch())  # fmt: skip
case("processed TIFF of NaN", processed_batch(to("bad.tif", tiff_of(np.full((64, 96, 3), np.nan, np.float32)))),
     "bad.tif", **batch())  # fmt: skip
case("processed a FIFO", processed_batch(fifo("bad.png")), "bad.png", **batch())
case("processed --white cut short", lambda d, b: ["correct", b / "cal.npz", b / "good.png", "--processed",
     "--white", write(d / "bad.png", (b / "good.png").read_bytes()[:200]), "--out", d / "out"],
     "bad.png")  # fmt: skip
case("processed --tuning not JSON", lambda d, b: ["correct", b / "cal.npz", b / "good.png", "--processed",
     "--tuning", write(d / "bad.json", "{rpi.alsc"), "--out", d / "out"], "bad.json")  # fmt: skip
case("analyse a PNG cut short", lambda d, b: ["analyse", write(d / "bad.png", (b / "good.png").read_bytes()[:200]),
     "--out", d / "analysis"], "bad.png")  # fmt: skip
case("analyse a forged PNG", lambda d, b: ["analyse", write(d / "bad.png", forged_png(20000, 20032)), "--out",
     d / "analysis"], "bad.png")  # fmt: skip


# ========================================================================================== calibration files
def cal_file(make: Callable[[Path, Path], bytes | str]) -> Callable[[Path, Path], Path]:
    return to("bad.npz", make)


def correct_cal(make: Callable[[Path, Path], Path]) -> Argv:
    return lambda d, b: ["correct", make(d, b), b / "sim" / "target.dng", "--out", d / "out", "--workers", "0"]


def export_tuning_cal(make: Callable[[Path, Path], Path]) -> Argv:
    return lambda d, b: ["export-tuning", make(d, b), "--target", "vc4", "--out", d / "tuning.json"]


def export_lst_cal(make: Callable[[Path, Path], Path]) -> Argv:
    return lambda d, b: ["export-lst", make(d, b), "--out", d / "table.npy"]


def report_cal(make: Callable[[Path, Path], Path]) -> Argv:
    return lambda d, b: ["report", make(d, b), "--out", d / "report"]


def cal_meta(**changes) -> Callable[[Path, Path], Path]:
    return cal_file(npz_with("cal.npz", meta=changes))


def forged_member(shape: str) -> bytes:
    return npy(f"{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}", bytes(4096))


case("calibration empty", correct_cal(cal_file(const(b""))), "bad.npz")
case("calibration not a zip", export_lst_cal(cal_file(const(b"PK\x03\x04 this is not a zip"))), "bad.npz")
case("calibration without its record", export_tuning_cal(cal_file(npz_with("cal.npz", drop=("metadata",)))),
     "bad.npz")  # fmt: skip
case("calibration record not JSON", correct_cal(cal_file(npz_with("cal.npz", arrays={"metadata": np.array(
     "{schema")}))), "bad.npz")  # fmt: skip
case("calibration record nested 100000 deep", correct_cal(cal_file(npz_with("cal.npz", arrays={"metadata": np.array(
     nested())}))), "bad.npz")  # fmt: skip
case("calibration schema version 99", correct_cal(cal_meta(schema_version=99)), "bad.npz")
case("calibration bin size 0", correct_cal(cal_meta(bin_size=0)), "bad.npz")
case("calibration full without unmixing", correct_cal(cal_file(npz_with("cal.npz", drop=("unmixing",)))),
     "bad.npz")  # fmt: skip
case("calibration white negative", export_tuning_cal(cal_file(cal_array("white", lambda a: -a))), "bad.npz")
case("calibration white zero", correct_cal(cal_file(cal_array("white", np.zeros_like))), "bad.npz")
case("calibration white complex", correct_cal(cal_file(cal_array("white", lambda a: a.astype(np.complex64)))),
     "bad.npz")  # fmt: skip
case("calibration white NaN", export_lst_cal(cal_file(cal_array("white", lambda a: np.full_like(a, np.nan)))),
     "bad.npz")  # fmt: skip
case("calibration white of another shape", correct_cal(cal_file(cal_array("white", lambda a: a[:3, :5]))),
     "bad.npz")  # fmt: skip
case("calibration lens shading infinite", export_tuning_cal(cal_file(cal_array("lens_shading", lambda a:
     np.where(a > 0, np.inf, a)))), "bad.npz")  # fmt: skip
case("calibration unmixing NaN", correct_cal(cal_file(cal_array("unmixing", lambda a: np.full_like(a, np.nan)))),
     "bad.npz")  # fmt: skip
case("calibration member forged 10**12", correct_cal(cal_file(npz_with("cal.npz", raw={
     "site_responses": forged_member("(4, 1000000, 250000, 1)")}))), "bad.npz")  # fmt: skip
case("calibration member inflating to 200 MB", correct_cal(copy_shared("bomb_cal.npz", "bad.npz")), "bad.npz")
case("calibration a FIFO", correct_cal(fifo("bad.npz")), "bad.npz")
case("calibration a folder", export_tuning_cal(folder("bad.npz")), "bad.npz")
case("calibration missing to correct", correct_cal(lambda d, b: d / "bad.npz"), "bad.npz")
case("calibration a raw npz", report_cal(copy_shared("npz/white.npz", "bad.npz")), "bad.npz")
case("calibration bad to --zarr", lambda d, b: ["correct", write(d / "bad.npz", b""), b / "sim" / "target.dng",
     "--zarr", d / "stack.zarr"], "bad.npz")  # fmt: skip
case("calibration flat as --unmixing-from", lambda d, b: ["calibrate", "--white", b / "sim" / "white.dng",
     "--unmixing-from", copy_shared("flat.npz", "bad.npz")(d, b), "--out", d / "cal.npz"], "bad.npz")  # fmt: skip
case("calibration flat with --mode centre", lambda d, b: ["correct", copy_shared("flat.npz", "bad.npz")(d, b),
     b / "sim" / "target.dng", "--mode", "centre", "--out", d / "out"], "bad.npz|--mode")  # fmt: skip


# ============================================================================================ tuning JSON files
def tuning(change: Callable[[dict], object]) -> Callable[[Path, Path], Path]:
    return to("bad.json", json_with("tuning.json", change))


def alsc(record: dict) -> dict:
    return next(a["rpi.alsc"] for a in record["algorithms"] if "rpi.alsc" in a)


def export_base(make: Callable[[Path, Path], Path]) -> Argv:
    return lambda d, b: ["export-tuning", b / "cal.npz", "--base", make(d, b), "--sensor", "imx219", "--out",
                         d / "tuning.json"]  # fmt: skip


def apply(make: Callable[[Path, Path], Path], *options: str) -> Argv:
    return lambda d, b: ["apply-tuning", make(d, b), b / "sim" / "white.dng", *options, "--out", d / "a.tiff"]


def alsc_update(**changes) -> Callable[[dict], None]:
    return lambda r: alsc(r).update(changes)


case("tuning empty", export_base(to("bad.json", const(""))), "bad.json")
case("tuning not JSON", apply(to("bad.json", const("{version: 2"))), "bad.json")
case("tuning nested 100000 deep", apply(to("bad.json", const(nested()))), "bad.json")
case("tuning version 3", export_base(tuning(lambda r: r.update(version=3.0))), "bad.json")
case("tuning target unknown", apply(tuning(lambda r: r.update(target="nope"))), "bad.json")
case("tuning without rpi.alsc", apply(tuning(lambda r: r.update(algorithms=[a for a in r["algorithms"]
     if "rpi.alsc" not in a]))), "bad.json")  # fmt: skip
case("tuning table of text", export_base(tuning(lambda r: alsc(r).update(luminance_lut=["one"] * 192))),
     "bad.json")  # fmt: skip
case("tuning colour temperatures decreasing", apply(tuning(lambda r: alsc(r).update(calibrations_Cr=[
     {"ct": 5000, "table": [1.0] * 192}, {"ct": 3000, "table": [1.0] * 192}]))), "bad.json")  # fmt: skip
case("tuning luminance NaN", apply(tuning(alsc_update(luminance_lut=[float("nan")] * 192))), "bad.json")
case("tuning black level text", apply(tuning(lambda r: r["algorithms"].insert(0, {"rpi.black_level": {
     "black_level": "dark"}}))), "bad.json")  # fmt: skip
case("tuning a FIFO", export_base(fifo("bad.json")), "bad.json")
case("tuning a folder", apply(folder("bad.json")), "bad.json")


# ============================================================================================ target layouts
def analyse_layout(make: Callable[[Path, Path], Path]) -> Argv:
    return lambda d, b: ["analyse", b / "sim" / "target.dng", "--layout", make(d, b), "--out", d / "analysis"]


def layout(change: Callable[[dict], object]) -> Callable[[Path, Path], Path]:
    return to("bad.json", json_with("sim/layout.json", change))


case("layout empty", analyse_layout(to("bad.json", const(""))), "bad.json")
case("layout not JSON", analyse_layout(to("bad.json", const("{wheels"))), "bad.json")
case("layout nested 100000 deep", analyse_layout(to("bad.json", const(nested()))), "bad.json")
case("layout wheels a string", analyse_layout(layout(lambda r: r.update(wheels="five"))), "bad.json")
case("layout wheel x text", analyse_layout(layout(lambda r: r["wheels"][1].update(x="left"))), "bad.json")
case("layout negative radius", analyse_layout(layout(lambda r: r["wheels"][0].update(radius=-5))), "bad.json")
case("layout without segments", analyse_layout(layout(lambda r: r.pop("segments"))), "bad.json")
case("layout a FIFO", analyse_layout(fifo("bad.json")), "bad.json")


# ================================================================================== acquisition manifests
def acquisition(change: Callable[[Path], object]) -> Argv:
    """``calibrate`` on a copy of the shared acquisition with its manifest (or files) changed."""

    def argv(d: Path, b: Path) -> list:
        shutil.copytree(b / "acq", d / "run")
        change(d / "run")
        return ["calibrate", d / "run", "--out", d / "cal.npz"]

    return argv


def manifest(change: Callable[[dict], object]) -> Callable[[Path], object]:
    def edit(run: Path) -> None:
        record = json.loads((run / "manifest.json").read_text())
        changed = change(record)
        (run / "manifest.json").write_text(json.dumps(record if changed is None else changed))

    return edit


case("manifest empty", acquisition(lambda run: write(run / "manifest.json", "")), "manifest.json")
case("manifest not JSON", acquisition(lambda run: write(run / "manifest.json", "{format")), "manifest.json")
case("manifest nested 100000 deep", acquisition(lambda run: write(run / "manifest.json", nested())), "manifest.json")
case("manifest of another format", acquisition(manifest(lambda r: r.update(format="other"))), "manifest.json")
case("manifest version 99", acquisition(manifest(lambda r: r.update(version=99))), "manifest.json")
case("manifest entries a string", acquisition(manifest(lambda r: r.update(entries="all"))), "manifest.json")
case("manifest lists a missing file", acquisition(lambda run: (run / "red.dng").unlink()), "red.dng")


# ================================================================== outputs that are inputs, or not picamcal's
def foreign(name: str, data: bytes | str = b"lab notes\n") -> Callable[[Path, Path], Path]:
    def make(d: Path, b: Path) -> Path:
        if name.endswith("/"):
            (d / name).mkdir()
            (d / name / "lab-book.txt").write_text("day 1\n")
            return d / name
        return write(d / name, data)

    return make


LOCAL = copies("cal.npz", "tuning.json", "sim")


def local(*parts: str) -> Callable[[Path], list]:
    """A command line on the case's own copies of the shared files ({cal}, {tuning}, {sim})."""

    def argv(d: Path) -> list:
        names = {"cal": d / "cal.npz", "tuning": d / "tuning.json", "sim": d / "sim"}
        return [part.format(**names) for part in parts]

    return argv


def own(*parts: str) -> Argv:
    return then(LOCAL, lambda d, b: local(*parts)(d))


case("report --out the calibration", own("report", "{cal}", "--out", "{cal}", "--overwrite"), "cal.npz")
case("report --out the captures", own("report", "{cal}", "--test", "{sim}/target.dng", "--out", "{sim}",
     "--overwrite"), "sim")  # fmt: skip
case("export-lst --out the calibration", own("export-lst", "{cal}", "--out", "{cal}", "--overwrite"), "cal.npz")
case("apply-tuning --out the tuning", own("apply-tuning", "{tuning}", "{sim}/white.dng", "--out", "{tuning}",
     "--overwrite"), "tuning.json")  # fmt: skip
case("calibrate --out a reference", own("calibrate", "{sim}", "--out", "{sim}/white.dng", "--overwrite"), "white.dng")
case("correct --out the captures", own("correct", "{cal}", "{sim}", "--out", "{sim}", "--overwrite"), "sim")
case("correct --out inside an input", own("correct", "{cal}", "{sim}/target.dng", "--out", "{sim}/target.dng/x"),
     "target.dng")  # fmt: skip
case("correct --zarr the calibration", own("correct", "{cal}", "{sim}/target.dng", "--zarr", "{cal}",
     "--overwrite"), "cal.npz")  # fmt: skip
case("export-tuning --out its base", own("export-tuning", "{cal}", "--base", "{tuning}", "--out", "{tuning}",
     "--overwrite"), "tuning.json")  # fmt: skip
case("analyse --out the captures", own("analyse", "{sim}/target.dng", "--out", "{sim}"), "sim")
case("demo --out the folder of its base", then(LOCAL, lambda d, b: ["demo", "--size", "96x64", "--tuning-base",
     d / "tuning.json", "--out", d, "--overwrite"]), "tuning.json|holds")  # fmt: skip
case("calibrate --overwrite a foreign .npz", lambda d, b: ["calibrate", "--white", b / "sim" / "white.dng", "--out",
     foreign("other.npz", zipped({}))(d, b), "--overwrite"], "other.npz")  # fmt: skip
case("export-lst --overwrite a foreign .npy", lambda d, b: ["export-lst", b / "cal.npz", "--out",
     foreign("table.npy", "not a table")(d, b), "--overwrite"], "table.npy")  # fmt: skip
case("report --overwrite a folder of notes", lambda d, b: ["report", b / "cal.npz", "--out", foreign("notes/")(d, b),
     "--overwrite"], "notes")  # fmt: skip
case("export-tuning --overwrite a foreign .json", lambda d, b: ["export-tuning", b / "cal.npz", "--target", "vc4",
     "--out", foreign("mine.json", '{"a": 1}')(d, b), "--overwrite"], "mine.json")  # fmt: skip
case("apply-tuning --overwrite a foreign .tiff", lambda d, b: ["apply-tuning", b / "tuning.json",
     b / "sim" / "white.dng", "--out", write(d / "photo.tiff", tiff_of(np.zeros((8, 8), np.uint8))(d, b)),
     "--overwrite"], "photo.tiff")  # fmt: skip


def folder_with(name: str, make: Callable[[Path, Path], object]) -> Callable[[Path, Path], Path]:
    """A folder ``name`` of the case's, holding what ``make`` puts in it."""

    def build(d: Path, b: Path) -> Path:
        (d / name).mkdir()
        make(d, b)
        return d / name

    return build


case("correct --overwrite a foreign output", lambda d, b: ["correct", b / "cal.npz", b / "sim" / "target.dng",
     "--out", folder_with("out", to("out/target.tiff", const("not an image")))(d, b), "--overwrite", "--workers",
     "0"], "target.tiff")  # fmt: skip
case("target --overwrite a foreign PNG", lambda d, b: ["target", "--size", "320x240", "--out",
     copy_shared("good.png", "photo.png")(d, b), "--overwrite"], "photo.png")  # fmt: skip
case("target --overwrite a foreign layout", then(foreign("wheels.json", '{"mine": true}'), lambda d, b: ["target",
     "--size", "320x240", "--out", d / "wheels.png", "--overwrite"]), "wheels.json")  # fmt: skip
case("simulate --overwrite a folder of captures", lambda d, b: ["simulate", "--size", "96x64", "--out",
     folder_with("captures", copy_shared("sim/white.dng", "captures/white.dng"))(d, b), "--overwrite"],
     "white.dng")  # fmt: skip
case("demo --overwrite a folder with a calibration", lambda d, b: ["demo", "--size", "96x64", "--out",
     folder_with("work", copy_shared("cal.npz", "work/calibration.npz"))(d, b), "--overwrite"],
     "calibration.npz")  # fmt: skip
case("calibrate --out a folder", lambda d, b: ["calibrate", "--white", b / "sim" / "white.dng", "--out",
     foreign("cal.npz/")(d, b), "--overwrite"], "cal.npz")  # fmt: skip
# A missing folder is made (--out newdir/cal.npz); a file in the way of one is refused, and kept.
case("calibrate --out under a file", lambda d, b: ["calibrate", "--white", b / "sim" / "white.dng", "--out",
     write(d / "notes.txt", "focus at 3 mm") / "cal.npz"], "cal.npz", "a file is in the way")  # fmt: skip


# ================================================================================== the shared run and the runs
def make_shared(root: Path) -> Path:
    """The small real run the bad files are made from, written once (in this process: it is faster)."""
    import copy

    from picamcal import calibrate, load_calibration, read_raw
    from picamcal.acquire.acquisition import acquire, open_rig
    from picamcal.export.tuning import export_tuning, load_tuning, save_tuning, stock_tuning_path
    from picamcal.raw import write_brcm, write_dng
    from picamcal.raw.packing import pack
    from picamcal.simulate import make_camera, render, simulate_run

    paths = simulate_run(root / "sim", size=(96, 64), noise=False)
    simulate_run(root / "npy", size=(96, 64), noise=False, fmt="npy")
    simulate_run(root / "npz", size=(96, 64), noise=False, fmt="npz")
    calibrate(*(paths[role] for role in ("white", "red", "green", "blue", "black"))).save(root / "cal.npz")
    calibrate(paths["white"], black=paths["black"]).save(root / "flat.npz")
    base = load_tuning(stock_tuning_path("imx219", "bcm2835"))
    save_tuning(root / "tuning.json", export_tuning(load_calibration(root / "cal.npz"), base, base_sensor="imx219"))
    white = read_raw(paths["white"])
    for name, change in {
        "small.dng": {"bayer": white.bayer[:48, :64].copy()},
        "rggb.dng": {"pattern": "RGGB"},
        "imx477.dng": {"sensor": "imx477"},
        "saturated.dng": {"bayer": np.minimum(white.bayer * 4, white.white_level).astype(np.uint16)},
        "gbrg.dng": {"pattern": "GBRG"},  # the greens sit on the other diagonal: a warning
    }.items():
        other = copy.deepcopy(white)
        for key, value in change.items():
            setattr(other, key, value)
        write_dng(root / name, other)
    (root / "white.raw").write_bytes(pack(white.bayer, 10, 128).tobytes())
    gradient = np.linspace(40, 220, 96 * 64 * 3).reshape(64, 96, 3).astype(np.uint8)
    Image.fromarray(gradient).save(root / "good.png")
    Image.fromarray(gradient).save(root / "good.jpg", quality=90)
    write_brcm(root / "brcm.jpg", render(make_camera("imx219", size=(640, 480)), "white", noise=False))
    with open_rig("sim", "sim", size=(96, 64)) as rig:
        acquire(rig.camera, rig.illuminator, root / "acq", settle_s=0, prompt=rig.prompt)
    raw_members = members((root / "npz" / "white.npz").read_bytes())
    inflating(root / "bomb_raw.npz", raw_members, "bayer", "<u2", (10240, 10240))
    inflating(root / "bomb_cal.npz", members((root / "cal.npz").read_bytes()), "site_responses", "<f4",
              (4, 1000, 3125, 4))  # fmt: skip
    return root


def inflating(path: Path, parts: dict[str, bytes], name: str, dtype: str, shape: tuple[int, ...]) -> None:
    """An .npz whose member ``name`` declares ``shape`` and holds that many zero bytes, deflated to a few hundred
    kilobytes: what a few hundred kilobytes on disk can cost in memory."""
    header = npy(f"{{'descr': '{dtype}', 'fortran_order': False, 'shape': {shape}, }}")
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize
    chunk = bytes(1 << 24)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        for member, data in parts.items():
            if member != f"{name}.npy":
                z.writestr(member, data)
        with z.open(f"{name}.npy", "w", force_zip64=True) as f:
            f.write(header)
            for start in range(0, size, len(chunk)):
                f.write(chunk[: min(len(chunk), size - start)])


def fingerprint(path: Path) -> tuple:
    """What a directory entry is, without following links or opening anything but a regular file."""
    info = os.lstat(path)
    if stat.S_ISLNK(info.st_mode):
        return ("link", os.readlink(path))
    if stat.S_ISDIR(info.st_mode):
        return ("folder",)
    if not stat.S_ISREG(info.st_mode):
        return ("special", stat.S_IFMT(info.st_mode))
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        if info.st_size > 64 << 20:  # the sparse forged files: their ends, size and time stand for them
            digest.update(f.read(1 << 20))
            f.seek(-(1 << 20), os.SEEK_END)
            digest.update(f"{info.st_size} {info.st_mtime_ns}".encode())
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return ("file", digest.hexdigest())


def snapshot(root: Path) -> dict[str, tuple]:
    """Every entry under ``root`` (links not followed), by its path relative to ``root``."""
    entries = {}
    for folder_name, folders, files in os.walk(root):
        for name in folders + files:
            path = Path(folder_name, name)
            entries[str(path.relative_to(root))] = fingerprint(path)
    return entries


def shared_inputs(argv: list[str], shared: Path) -> dict[str, dict[str, tuple]]:
    """Snapshots of the shared files and folders a command line names."""
    found = {}
    for arg in argv:
        text = arg.split("=", 1)[-1].removeprefix("tuning:")
        path = Path(text)
        if path.is_absolute() and path.is_relative_to(shared) and os.path.lexists(path):
            found[text] = snapshot(path) if path.is_dir() else {"": fingerprint(path)}
    return found


@dataclass
class Outcome:
    argv: list[str]
    status: int | None  # None: it did not end in TIMEOUT_S
    stdout: str
    stderr: str
    seconds: float
    folder_before: dict
    folder_after: dict
    inputs_before: dict
    inputs_after: dict


def run_case(started: queue.Queue, one: Case, folder: Path, argv: list[str], shared: Path, streams: Path) -> Outcome:
    env = {k: v for k, v in os.environ.items() if k != "PICAMCAL_MAX_PIXELS"} | one.env
    folder_before, inputs_before = snapshot(folder), shared_inputs(argv, shared)
    forker = started.get()
    start = time.monotonic()
    try:
        status, stdout, stderr = forker.run(CLI, argv, cwd=folder, env=env, streams=streams, timeout=TIMEOUT_S)
    finally:
        started.put(forker)
    seconds = time.monotonic() - start
    return Outcome(argv, status, stdout, stderr, seconds, folder_before, snapshot(folder), inputs_before,
                   shared_inputs(argv, shared))  # fmt: skip


@pytest.fixture(scope="module")
def corpus(tmp_path_factory, request) -> dict:
    """The outcome of every case selected (``-k``), by id, run two at a time; the shared run's snapshots before
    and after them."""
    selected = {getattr(item, "callspec", None) and item.callspec.id for item in request.session.items}
    params = [param for param in CASES if param.id in selected]
    root = tmp_path_factory.mktemp("corpus")
    shared = make_shared(root / "shared")
    jobs = []
    for number, param in enumerate(params):
        folder = root / "cases" / f"{number:03d}"
        folder.mkdir(parents=True)
        argv = [str(part) for part in param.values[0].argv(folder, shared)]
        jobs.append((param.values[0], folder, argv, shared))
    before = snapshot(shared)
    streams = root / "streams"
    streams.mkdir()
    numbers = itertools.count()
    with forkers(2, PRELOAD) as started, ThreadPoolExecutor(max_workers=2) as pool:
        outcomes = list(pool.map(lambda job: run_case(started, *job, streams / f"{next(numbers):03d}"), jobs))
    return {
        "cases": {param.id: outcome for param, outcome in zip(params, outcomes, strict=True)},
        "shared_before": before,
        "shared_after": snapshot(shared),
    }


def holds(line: str, name: str) -> bool:
    return any(alternative in line for alternative in name.split("|"))


def changes(before: dict, after: dict) -> set[str]:
    return {path for path in before.keys() | after.keys() if before.get(path) != after.get(path)}


@pytest.mark.parametrize("one", CASES)
def test_bad_input_is_refused_in_one_line_and_nothing_is_lost(one: Case, corpus: dict, request) -> None:
    outcome: Outcome = corpus["cases"][request.node.callspec.id]
    shown = f"picamcal {' '.join(outcome.argv)}\nexit {outcome.status}\nstderr: {outcome.stderr}"
    assert outcome.status is not None, f"no answer in {TIMEOUT_S} s (a hang)\n{shown}"
    assert "Traceback" not in outcome.stderr + outcome.stdout, shown
    lines = outcome.stderr.splitlines()  # an empty line is a line too
    if one.described and outcome.status == 0:  # an odd file described as it is
        assert lines == [], shown
        rows = outcome.stdout.splitlines()
        assert all(any(holds(row, name) for row in rows) for name in one.names), shown
        if one.warned:
            assert any(row.startswith(f"{name}: ") for row in rows for name in one.names[0].split("|")), shown
    elif one.survey:  # inspect of a folder: the table, the reason under it, exit 1
        assert outcome.status == 1 and lines == [], shown
        assert any(holds(row, name) and "cannot read" in row for row in outcome.stdout.splitlines()
                   for name in one.names), shown  # fmt: skip
    elif one.status == 1:  # a batch: the bad file reported in one line, the summary, exit 1
        assert outcome.status == 1, shown
        failed = [line for line in lines if line.startswith("picamcal: failed: ")]
        assert len(failed) == 1, shown
        assert all(holds(failed[0], name) for name in one.names), shown
        assert all(line.startswith("wrote ") for line in lines if line not in failed), shown
    else:
        assert outcome.status == one.status, shown
        assert len(lines) == 1 and lines[0].startswith("picamcal: error: "), shown
        assert all(holds(lines[0], name) for name in one.names), shown
    written = changes(outcome.folder_before, outcome.folder_after)
    allowed = {path for path in written if any(path == w or path.startswith(f"{w}/") for w in one.written)}
    assert written == allowed, f"written or changed: {sorted(written - allowed)}\n{shown}"
    assert not [path for path in one.absent if path in outcome.folder_after], shown
    assert outcome.inputs_after == outcome.inputs_before, f"a shared input changed\n{shown}"


def test_the_shared_run_is_unchanged_and_every_command_is_tried(corpus: dict) -> None:
    assert corpus["shared_after"] == corpus["shared_before"]
    if len(corpus["cases"]) < len(CASES):
        pytest.skip("only some cases were selected")
    tried = {outcome.argv[0] for outcome in corpus["cases"].values()}
    commands = {"calibrate", "correct", "inspect", "export-tuning", "export-lst", "apply-tuning", "analyse", "report",
                "simulate", "target", "acquire", "demo"}  # fmt: skip
    assert commands <= tried and len(corpus["cases"]) >= 150
