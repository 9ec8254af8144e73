"""Headless raw dumps: the frames rpicam-raw, libcamera-raw and other libcamera tools write with no header.

``rpicam-raw -t 2000 -o dump.raw`` writes each raw frame's buffer as libcamera filled it, one after another and
nothing else (``--segment 1 -o frame%05d.raw`` writes one file per frame). What the bytes mean is only in the
line the application prints when it starts (``Raw stream: 4056x3040 stride 6112 format SBGGR12_CSI2P``), so the
format and size are given by the user; the decoding is picamera2's, whose buffers these are
(:mod:`picamcal.raw.picamera2`).

The row stride, when not given, is libcamera's, which depends on the Pi:

- Pi 4 and earlier (vc4, Unicam receiver): the row's pixel bytes rounded up to 32. Linux
  ``drivers/media/platform/bcm2835/bcm2835-unicam.c``: ``BPL_ALIGNMENT 32`` ("Stride is a 16 bit register, but
  also has to be a multiple of 32") and ``sizeimage = height * bytesperline``. Unicam writes the CSI-2 packed
  (``*_CSI2P``) and unpacked 8 to 14-bit formats.
- Pi 5 (PiSP, RP1 CFE receiver): rounded up to 64. libcamera ``src/libcamera/pipeline/rpi/pisp/pisp.cpp``
  sets the raw stream's stride with libpisp's ``compute_optimal_stride`` (``PISP_BACK_END_OUTPUT_MAX_ALIGN``, 64
  bytes), which the CFE driver keeps (``rp1_cfe/cfe.c``: ``sizeimage = height * bytesperline``). The Pi 5 writes
  only ``S<order>16`` and ``<order>_PISP_COMP1``: ``platformValidate`` turns other requests into these.

The two alignments differ for some widths (a 1456-pixel IMX296 row of 16-bit pixels: 2912 bytes on a Pi 4, 2944 on
a Pi 5), so the format's own Pi's alignment is tried first, then the other's, then no padding at all (other
tools): the first whose frames divide the file exactly is used, and ``metadata["stride_source"]`` says which.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import RawFormatError
from ..limits import check_size
from ..sensors import SENSORS, find_sensor_name, get_sensor
from .model import RawImage, given_black_level, require_colour_sensor, sensor_black_level
from .npy import file_head
from .picamera2.convert import from_picamera2
from .picamera2.formats import PISP_ALIGN, UNICAM_ALIGN, RawFormat, max_stride, parse_raw_format

__all__ = ["HEADLESS_SUFFIXES", "default_strides", "headless_hint", "read_headless"]

#: The suffixes of headless dumps: read with the sensor, mode and size given (:func:`read_headless`).
HEADLESS_SUFFIXES = (".raw", ".bin")


def default_strides(spec: RawFormat, width: int) -> list[tuple[int, str]]:
    """Row strides to try for a frame ``width`` pixels wide, best first, each with where it comes from.

    Examples
    --------
    >>> default_strides(parse_raw_format("SRGGB16"), 1456)
    [(2944, "libcamera's 64-byte alignment (Pi 5)"), (2912, "libcamera's 32-byte alignment (Pi 4)")]
    """
    row = spec.row_bytes(width)
    pi4 = (UNICAM_ALIGN, f"libcamera's {UNICAM_ALIGN}-byte alignment (Pi 4)")
    pi5 = (PISP_ALIGN, f"libcamera's {PISP_ALIGN}-byte alignment (Pi 5)")
    pi5_format = spec.packing == "pisp" or (spec.packing == "unpacked" and spec.bits == 16)
    strides: list[tuple[int, str]] = []
    for align, what in (*((pi5, pi4) if pi5_format else (pi4, pi5)), (1, "no padding")):
        stride = -(-row // align) * align
        if all(stride != s for s, _ in strides):
            strides.append((stride, what))
    return strides


def read_headless(
    path: str | os.PathLike[str],
    raw_format: str,
    size: Sequence[int] | None,
    *,
    stride: int | None = None,
    frame: int | None = None,
    sensor: str | None = None,
    black_level: float | Sequence[float] | None = None,
    expected_shape: tuple[int, int] | None = None,
) -> RawImage:
    """Read one frame of a headless raw dump (``rpicam-raw -o``), reading only that frame's bytes.

    ``size`` goes through :func:`picamcal.limits.check_size` (and ``expected_shape``) and the stride is bounded by
    :func:`picamcal.raw.picamera2.max_stride` before the file is opened, so a wrong ``--size`` costs nothing.

    Parameters
    ----------
    path : path-like
        The dump: whole frames of ``stride * height`` bytes one after another, nothing else.
    raw_format : str
        libcamera's name of the format (case-insensitive): ``SBGGR10_CSI2P``, ``SRGGB12_CSI2P``, ``SGBRG16``,
        ``BGGR_PISP_COMP1``, ... (:data:`picamcal.raw.picamera2.RAW_FORMATS`). Greyscale formats are refused.
    size : (width, height)
        The frame size in pixels.
    stride : int, optional
        Bytes per row; by default libcamera's (see the module's notes).
    frame : int, optional
        Which frame, from 0 (the default).
    sensor : str, optional
        The sensor. A registry sensor gives the black level (when ``black_level`` is not given) and the bit depth
        of 16-bit and PiSP data (shifted back to it when exact); any other name is kept, with
        ``metadata["sensor_known"]`` false.
    black_level : float or 4 floats, optional
        Black level in DN (one value, or one per 2x2 site row-major; finite, >= 0). Without it and without a
        registry sensor the black level is unknown (NaN): :func:`picamcal.raw.model.require_black_level` raises
        where one is needed.
    expected_shape : (height, width), optional
        The Bayer size the caller needs (a calibration's): another ``size`` raises ``CalibrationFileError``.

    Returns
    -------
    RawImage
        ``metadata["format"]`` is ``"headless"``; ``frames`` the number of frames in the file, ``frame`` the one
        read, ``stride`` and ``stride_source`` the row stride used, ``black_level_source`` ``"given"``,
        ``"registry"`` or ``"none"``.

    Raises
    ------
    RawFormatError
        One line naming the file: no size, a size over the pixel limit, an unknown or greyscale format, a monochrome
        sensor, a stride too short or too long for the width, a file that is not a whole number of frames (the
        frame and file sizes in bytes), a frame past the last, or a black level that is not finite and >= 0.
    CalibrationFileError
        ``size`` is not ``expected_shape``.

    Examples
    --------
    Three simulated frames dumped as a Pi 4 writes them (CSI-2 packed, rows padded to 32 bytes), then the third:

    >>> from picamcal.raw import to_picamera2
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> with open("dump.raw", "wb") as f:
    ...     for role in ("white", "red", "green"):
    ...         _ = f.write(to_picamera2(refs[role])[0].tobytes())
    >>> raw = read_headless("dump.raw", "SBGGR10_CSI2P", (320, 240), frame=2, sensor="imx219")
    >>> raw.metadata["frames"], raw.metadata["stride"], raw.black_level[0]
    (3, 416, 64.0)
    >>> bool(np.array_equal(raw.bayer, refs["green"].bayer))
    True
    """
    path = Path(path)
    spec = parse_raw_format(raw_format, path)
    width, height = _frame_size(size, path)
    check_size(path, width, height, expected_shape)
    if sensor is not None and not isinstance(sensor, str):
        raise RawFormatError(f"the sensor is a name such as 'imx219', not {sensor!r:.40}", path)
    name = find_sensor_name(sensor) if sensor is not None else None
    require_colour_sensor(name, path)
    given_black = None if black_level is None else given_black_level(black_level, path)
    file_head(path)  # no such file, a directory, unreadable or empty: the standard errors
    nbytes = path.stat().st_size
    row_stride, stride_source = _choose_stride(spec, width, height, stride, nbytes, path)
    frame_bytes = row_stride * height
    count = nbytes // frame_bytes
    index = 0 if frame is None else frame
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
        raise RawFormatError(f"the frame must be a whole number from 0, not {index!r:.30}", path)
    if index >= count:
        which = "its only frame is --frame 0" if count == 1 else f"give --frame 0 to {count - 1}"
        raise RawFormatError(f"frame {index} is past the end: the file holds {count} frame(s) ({which})", path)
    with open(path, "rb") as f:
        f.seek(int(index) * frame_bytes)
        data = np.fromfile(f, dtype=np.uint8, count=frame_bytes)
    if data.size != frame_bytes:
        raise RawFormatError(f"truncated while reading: frame {index} ends after {data.size} bytes", path)
    config: dict[str, Any] = {"format": spec.name, "size": (width, height), "stride": row_stride}
    if name is not None:
        config = {"raw": config, "sensor": {"bit_depth": get_sensor(name).bit_depth}}
    decoded = from_picamera2(data, config, {}, source=path, by_size=False)  # read_raw says what its size is
    if given_black is None:
        black, black_source = sensor_black_level(name, decoded.bit_depth)
    else:
        black, black_source = given_black, "given"
    meta: dict[str, Any] = {
        "format": "headless",
        "path": str(path),
        "raw_format": spec.name,
        "stride": row_stride,
        "stride_source": stride_source,
        "frames": count,
        "frame": int(index),
        "black_level_source": black_source,
        "sensor_known": name is not None,
        **{k: decoded.metadata[k] for k in ("sensor_bit_depth", "lossy_compression") if k in decoded.metadata},
    }
    try:
        return RawImage(
            decoded.bayer, decoded.pattern, black, decoded.white_level, decoded.bit_depth, name or sensor or None, meta
        )
    except RawFormatError as exc:
        raise RawFormatError(exc.problem, path) from None


def headless_hint(path: str | os.PathLike[str]) -> str:
    """A hint, for a file whose bytes are no known format, that it may be a headless dump; empty if not likely.

    It is likely when the name ends ``.raw`` or ``.bin``, or when the size is a whole number of full-size frames
    of a registry sensor, packed at its bit depth or 16-bit, at libcamera's alignment.

    Examples
    --------
    >>> _ = Path("frame00001.raw").write_bytes(bytes(1000))
    >>> headless_hint("frame00001.raw")
    '; a headless dump (rpicam-raw)? give --raw-format NAME and --size WIDTHxHEIGHT'
    """
    path = Path(path)
    try:
        nbytes = path.stat().st_size
    except OSError:
        return ""
    for entry in SENSORS.values():
        if entry.monochrome or not nbytes:
            continue
        for packed in (f"S{entry.default_pattern}{entry.bit_depth}_CSI2P", f"S{entry.default_pattern}16"):
            spec = parse_raw_format(packed)
            for row_stride, _ in default_strides(spec, entry.width)[:2]:
                if nbytes % (row_stride * entry.height) == 0:
                    what = f"{entry.bit_depth}-bit packed" if spec.packing == "csi2p" else "16-bit"
                    return (
                        f"; its size fits {entry.name.upper()} {entry.width}x{entry.height} {what} frames: a headless "
                        f"dump? give --raw-format {packed.replace(entry.default_pattern or '', '<order>')} "
                        f"--size {entry.width}x{entry.height}"
                    )
    if path.suffix.lower() in HEADLESS_SUFFIXES:
        return "; a headless dump (rpicam-raw)? give --raw-format NAME and --size WIDTHxHEIGHT"
    return ""


def _frame_size(size: Sequence[int] | None, path: Path) -> tuple[int, int]:
    if size is None:
        raise RawFormatError(
            "a headless dump needs its frame size: give --size WIDTHxHEIGHT (rpicam-raw prints it as "
            "'Raw stream: WIDTHxHEIGHT stride BYTES format NAME')",
            path,
        )
    if isinstance(size, (str, bytes)) or not isinstance(size, Sequence) or len(size) != 2:
        raise RawFormatError(f"the frame size must be (width, height), not {size!r:.40}", path)
    if not all(_whole(v) for v in size):
        raise RawFormatError(f"the frame size must be two whole numbers, not {size!r:.40}", path)
    width, height = (int(v) for v in size)
    if width < 2 or height < 2 or width % 2 or height % 2:
        raise RawFormatError(f"a Bayer frame needs an even width and height of 2 or more, not {width}x{height}", path)
    return width, height


def _whole(value: object) -> bool:
    """A whole number: an integer, or a float with no fraction (``64.0``); never a bool."""
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, (float, np.floating)):
        return math.isfinite(value) and float(value).is_integer()
    return isinstance(value, (int, np.integer))


def _choose_stride(
    spec: RawFormat, width: int, height: int, stride: int | None, nbytes: int, path: Path
) -> tuple[int, str]:
    """The row stride: the given one, checked, or the first default whose frames divide the file exactly."""
    row = spec.row_bytes(width)
    if stride is not None:
        if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or stride < row:
            raise RawFormatError(
                f"a stride of {stride!r:.30} bytes is too short for {width} pixels of {spec.name} ({row} bytes)", path
            )
        if stride > max_stride(row):
            raise RawFormatError(
                f"a stride of {stride} bytes is longer than any camera pads {width} pixels of {spec.name} ({row} "
                f"bytes, at most {max_stride(row)}): check --stride",
                path,
            )
        candidates = [(int(stride), "given")]
    else:
        candidates = default_strides(spec, width)
    for row_stride, source in candidates:
        if nbytes % (row_stride * height) == 0:
            return row_stride, source
    expected, source = candidates[0]
    tried = "" if len(candidates) == 1 else f"; also tried strides {', '.join(str(s) for s, _ in candidates[1:])}"
    raise RawFormatError(
        f"{nbytes} bytes is not a whole number of {width}x{height} {spec.name} frames of {expected * height} bytes "
        f"(stride {expected} bytes, {source}{tried}): check --raw-format, --size and --stride",
        path,
    )
