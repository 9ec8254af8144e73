"""Legacy firmware raw files: a JPEG with a BRCM raw block appended (picamera ``bayer=True``, raspistill ``--raw``).

Layout (FORMATS.md section 2; picamera ``picamera/array.py``; LibRaw ``parse_raspberrypi`` in ``identify.cpp``):

- The file is an ordinary JPEG (with EXIF ``Make`` ``RaspberryPi`` and ``Model`` such as ``RP_imx219``)
  followed by the raw block: the last N bytes of the file, N fixed by sensor and mode (the registry's
  :attr:`~picamcal.sensors.LegacyMode.block_size`). The block starts with ``BRCM`` (``BRCMo`` on the HQ camera).
- The block is a 32768-byte header, then ``rows`` rows of ``stride`` bytes. At offset 0xB0 of the header,
  little-endian: name char[32], width u16, height u16, padding_right u16, padding_down u16, 6 x u32 unused,
  transform u16, format u16 (33 = Bayer), bayer_order u8 (0 RGGB, 1 GBRG, 2 BGGR, 3 GRBG),
  bayer_format u8 (3 = RAW10, 4 = RAW12).
- ``stride`` is ``((width + padding_right) * 5 + 3) // 4`` (10-bit) or ``((width + padding_right + 1) // 2) * 3``
  (12-bit) rounded up to a multiple of 32; ``rows = (N - 32768) / stride`` may exceed ``height``. Only the first
  ``height`` rows and the first ``width * bits / 8`` bytes of each are pixels, MIPI CSI-2 packed
  (:mod:`picamcal.raw.packing`).

OV5647 and IMX219 share two block sizes; the EXIF ``Model`` and the header's width and height tell them apart.
LibRaw (built with ``6BY9RPI``) finds the block the same way: it takes the EXIF ``Model`` from the JPEG's APP1
segment (``RP_imx219``, ``RP_ov5647``/``ov5647``, ``RP_imx477``/``imx477``; not ``RP_testc``), tries that
sensor's block sizes from the end of the file, and loads the block only when the header says format 33 with
bayer_format 3 (RAW10) or 4 (RAW12); its row width comes from the header's width and padding_right. A block
that stands alone (a file starting with ``BRCM``) is read by both LibRaw and :func:`read_brcm`.
"""

from __future__ import annotations

import io
import math
import mmap
import os
import re
import struct
import warnings
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .._atomic import atomic_path
from ..errors import RawFormatError
from ..sensors import SENSORS, LegacyMode, Sensor, black_level_at, find_sensor_name
from .model import PATTERNS, RawImage, site_channels
from .packing import pack, packed_row_bytes, unpack

HEADER_SIZE = 32768
_IDENT = b"BRCM"
#: The HQ camera's firmware writes ``BRCMo``; the others plain ``BRCM``.
_IDENT_BY_SENSOR = {"imx477": b"BRCMo"}
_FIELDS = struct.Struct("<32s4H6I2H2B")
_FIELDS_OFFSET = 0xB0
_FORMAT_BAYER = 33  # VC_IMAGE_BAYER (raspberrypi/userland vc_image_types.h, as LibRaw cites it)
_BAYER_FORMAT_BITS = {2: 8, 3: 10, 4: 12, 5: 14, 6: 16}  # VC_IMAGE_BAYER_RAW8 ... RAW16
_BAYER_FORMAT_CODE = {bits: code for code, bits in _BAYER_FORMAT_BITS.items()}
_STRIDE_ALIGN = 32
_BAYER_ORDERS = ("RGGB", "GBRG", "BGGR", "GRBG")  # header bayer_order code -> pattern
#: EXIF models of early firmware that do not name the sensor.
_MODEL_ALIASES = {"testc": "ov5647"}
#: How far from the end to look for a ``BRCM`` block of unknown size when diagnosing a file.
_DIAGNOSE_WINDOW = 64 << 20
_PREVIEW_MAX_SIDE = 320
_EXPOSURE_TIME, _ISO, _DATETIME_ORIGINAL, _MAKER_NOTE, _EXIF_IFD = 33434, 34855, 36867, 37500, 0x8769
_MAKE, _MODEL, _SOFTWARE, _DATETIME = 271, 272, 305, 306


def is_jpeg(head: bytes) -> bool:
    """True if the first bytes of a file are a JPEG start-of-image marker.

    Examples
    --------
    >>> is_jpeg(b"\\xff\\xd8\\xff\\xe0\\x00\\x10JFIF"), is_jpeg(b"BRCM")
    (True, False)
    """
    return head[:3] == b"\xff\xd8\xff"


def _legacy_modes() -> Iterator[tuple[Sensor, LegacyMode]]:
    for sensor in SENSORS.values():
        for mode in sensor.legacy_modes:
            yield sensor, mode


def _block_sizes() -> list[int]:
    return sorted({mode.block_size for _, mode in _legacy_modes()})


def _stride(padded_width: int, bit_depth: int) -> int:
    """Row stride in bytes for ``width + padding_right`` pixels, as the firmware and LibRaw compute it."""
    if bit_depth == 10:
        nbytes = (padded_width * 5 + 3) // 4
    else:
        nbytes = ((padded_width + 1) // 2) * 3
    return -(-nbytes // _STRIDE_ALIGN) * _STRIDE_ALIGN


def _mode_layout(mode: LegacyMode) -> tuple[int, int, int]:
    """``(padding_right, stride, rows)`` that reproduce a mode's block size: the smallest stride that fits.

    padding_right is the largest even value giving that stride (IMX219 1920x1080: 24, stride 2432), even so
    that the 12-bit stride formulas of the firmware and LibRaw agree.
    """
    data = mode.block_size - HEADER_SIZE
    smallest = _stride(mode.width, mode.bit_depth)
    for stride in range(smallest, data // mode.height + 1, _STRIDE_ALIGN):
        if data % stride == 0:
            top = stride * 8 // mode.bit_depth + 2 - mode.width
            for padding in range(top - top % 2, -1, -2):
                if _stride(mode.width + padding, mode.bit_depth) == stride:
                    return padding, stride, data // stride
    raise ValueError(f"no row stride reproduces the {mode.block_size}-byte block of a {mode.width}x{mode.height} mode")


def _describe(mode: LegacyMode) -> str:
    return f"{mode.width}x{mode.height} {mode.bit_depth}-bit"


def _sensor_from_model(model: str | None) -> str | None:
    name = find_sensor_name(model)
    if name is None and model:
        name = next((s for alias, s in _MODEL_ALIASES.items() if alias in model.lower()), None)
    return name


def _rational(value: Any) -> float | None:
    try:
        if isinstance(value, tuple) and len(value) == 2:
            result = value[0] / value[1]
        else:
            result = float(value)
    except (TypeError, ValueError, ZeroDivisionError, OverflowError):
        return None
    return result if math.isfinite(result) and result > 0 else None


def _maker_note(value: Any) -> dict[str, Any]:
    """The firmware's MakerNote: ``ev=-1 mlux=-1 exp=62998 ag=556 ... gain_r=1.128 gain_b=2.546 ...``."""
    text = value.decode("latin-1") if isinstance(value, bytes) else str(value)
    text = text.strip("\x00 ")
    meta: dict[str, Any] = {"maker_note": text}
    fields = dict(re.findall(r"(?<![\w.])([a-z_]+)=(-?[0-9.]+)", text))
    try:
        if int(fields.get("ag", 0)) > 0:
            meta["analogue_gain"] = int(fields["ag"]) / 256.0  # Q8: ag=556 goes with ISO 220 in real files
        if "gain_r" in fields and "gain_b" in fields:
            meta["colour_gains"] = [float(fields["gain_r"]), float(fields["gain_b"])]
    except ValueError:
        pass
    return meta


def _exif_metadata(path: Path) -> dict[str, Any]:
    """Make, model, exposure, ISO, gains and timestamp from the JPEG's EXIF; empty if Pillow cannot parse it."""
    from PIL import Image

    meta: dict[str, Any] = {}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as image:
                tags = image.getexif()
                exif, sub = dict(tags), dict(tags.get_ifd(_EXIF_IFD))
    except Exception:  # Pillow raises many types on damaged JPEG/EXIF; the raw block does not need it
        return meta
    for tag, key in ((_MAKE, "make"), (_MODEL, "model")):
        if isinstance(exif.get(tag), str):
            meta[key] = exif[tag].strip("\x00 ")
    exposure = _rational(sub.get(_EXPOSURE_TIME))
    if exposure is not None:
        meta["exposure_time_s"] = exposure
    iso = sub.get(_ISO)
    iso = iso[0] if isinstance(iso, tuple) and iso else iso
    if isinstance(iso, int) and iso > 0:
        meta["iso"] = iso
    stamp = sub.get(_DATETIME_ORIGINAL) or exif.get(_DATETIME)
    if isinstance(stamp, str) and stamp.strip("\x00 "):
        meta["timestamp"] = stamp.strip("\x00 ")
    if isinstance(sub.get(_MAKER_NOTE), (bytes, str)):
        meta.update(_maker_note(sub[_MAKER_NOTE]))
    return meta


def _header_fields(f: BinaryIO, start: int) -> dict[str, Any] | None:
    f.seek(start + _FIELDS_OFFSET)
    data = f.read(_FIELDS.size)
    if len(data) < _FIELDS.size:
        return None
    name, width, height, pad_right, pad_down, *_unused, transform, fmt, order, bayer_format = _FIELDS.unpack(data)
    return {
        "name": name.split(b"\x00", 1)[0].decode("latin-1"),
        "width": width,
        "height": height,
        "padding_right": pad_right,
        "padding_down": pad_down,
        "transform": transform,
        "format": fmt,
        "bayer_order": order,
        "bayer_format": bayer_format,
    }


def _larger_modes(width: int, height: int, size: int) -> list[LegacyMode]:
    return [m for _, m in _legacy_modes() if (m.width, m.height) == (width, height) and m.block_size > size]


def _diagnose(f: BinaryIO, size: int, head: bytes, path: Path) -> RawFormatError:
    """The error for a file with no raw block of a known size at its end."""
    found = None
    start = max(0, size - _DIAGNOSE_WINDOW)
    try:
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            found = mm.find(_IDENT, start)
    except (OSError, ValueError):
        found = None
    if found is not None and found >= 0:
        block = size - found
        if block < HEADER_SIZE:
            return RawFormatError(
                f"truncated file: its raw (BRCM) block has {block} bytes, less than its {HEADER_SIZE}-byte header",
                path,
            )
        header = _header_fields(f, found)
        longer = _larger_modes(header["width"], header["height"], block) if header else []
        if header and longer:
            return RawFormatError(
                f"truncated file: its raw (BRCM) block has {block} bytes, "
                f"but a {_describe(longer[0])} block has {longer[0].block_size}",
                path,
            )
        dims = f" (header {header['width']}x{header['height']})" if header else ""
        known = ", ".join(str(n) for n in _block_sizes())
        return RawFormatError(
            f"a raw (BRCM) block of {block} bytes{dims} matches no known sensor mode (known sizes: {known})", path
        )
    if is_jpeg(head):
        f.seek(max(0, size - 2))
        ending = "" if f.read(2) == b"\xff\xd9" else " (nor does it end with a JPEG end marker: truncated?)"
        return RawFormatError(
            f"a JPEG image with no raw (BRCM) block{ending}: a processed image? correct it with --processed "
            "(or capture raw with --raw / bayer=True)",
            path,
        )
    return RawFormatError("not a legacy raw file: neither a JPEG nor a BRCM raw block", path)


def _choose(
    f: BinaryIO, size: int, candidates: list[int], hint: str | None, path: Path
) -> tuple[Sensor, LegacyMode, int, dict[str, Any]]:
    """Pick the (sensor, mode) of the block among the sizes that start with ``BRCM``, by EXIF model and header."""
    problems = []
    for block in candidates:
        header = _header_fields(f, size - block)
        if header is None:
            continue
        modes = [(s, m) for s, m in _legacy_modes() if m.block_size == block]
        fitting = [(s, m) for s, m in modes if (m.width, m.height) == (header["width"], header["height"])]
        if not fitting:
            expected = " or ".join(sorted({f"{m.width}x{m.height}" for _, m in modes}))
            problems.append(
                f"the raw header says {header['width']}x{header['height']}, "
                f"but a {block}-byte block is a {expected} mode"
            )
            continue
        for guess in (hint, _sensor_from_model(header["name"])):
            if guess and any(s.name == guess for s, _ in fitting):
                fitting = [(s, m) for s, m in fitting if s.name == guess]
                break
        if len({s.name for s, _ in fitting}) > 1:
            names = " from ".join(s.name.upper() for s, _ in fitting)
            problems.append(
                f"cannot tell {names} apart: the {block}-byte block fits both and the file has no EXIF Model naming one"
            )
            continue
        sensor, mode = fitting[0]
        return sensor, mode, block, header
    raise RawFormatError(problems[0] if problems else "the raw (BRCM) header is cut short", path)


def read_brcm(path: str | os.PathLike[str]) -> RawImage:
    """Read the Bayer mosaic from a legacy JPEG+raw file (raspistill ``--raw``, picamera ``bayer=True``).

    Only the raw block's header and its pixel rows are read (the block is found from the end of the file by
    the registry's block sizes); the EXIF of the JPEG adds the sensor hint and exposure metadata.

    Parameters
    ----------
    path : path-like
        The JPEG+raw file (or a BRCM block on its own).

    Returns
    -------
    RawImage
        The ``height x width`` mosaic at native bit depth, the pattern from the header's ``bayer_order``, the
        registry's black level at that depth, white level ``2**bits - 1`` and metadata: ``format`` ``"brcm"``,
        ``path``, ``legacy_mode``, ``header_name``, ``transform`` and the EXIF ``make``, ``model``,
        ``exposure_time_s``, ``iso``, ``analogue_gain``, ``colour_gains``, ``timestamp`` when present.

    Raises
    ------
    RawFormatError
        Empty, truncated or unrecognised file, a JPEG without a raw block, or a header inconsistent with its block.

    Examples
    --------
    >>> raw = read_brcm("white.jpg")  # doctest: +SKIP
    >>> raw.sensor, raw.pattern, raw.bayer.shape, raw.black_level[0]  # doctest: +SKIP
    ('imx219', 'BGGR', (2464, 3280), 64.0)
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size == 0:
                raise RawFormatError("empty file (0 bytes)", path)
            head = f.read(8)
            candidates = []
            for block in _block_sizes():
                if block <= size:
                    f.seek(size - block)
                    if f.read(len(_IDENT)) == _IDENT:
                        candidates.append(block)
            if not candidates:
                raise _diagnose(f, size, head, path)
            meta = _exif_metadata(path) if is_jpeg(head) else {}
            sensor, mode, block, header = _choose(f, size, candidates, _sensor_from_model(meta.get("model")), path)
            bayer = _read_pixels(f, size - block, mode, header, path)
    except FileNotFoundError:
        raise RawFormatError("no such file", path) from None
    except IsADirectoryError:
        raise RawFormatError("is a directory, not a raw image file", path) from None
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from exc
    meta.update(
        {
            "format": "brcm",
            "path": str(path),
            "legacy_mode": {
                "modes": list(mode.modes),
                "width": mode.width,
                "height": mode.height,
                "bit_depth": mode.bit_depth,
                "block_size": mode.block_size,
            },
            "header_name": header["name"],
            "transform": header["transform"],
        }
    )
    black = black_level_at(sensor, mode.bit_depth)
    pattern = _BAYER_ORDERS[header["bayer_order"]]
    return RawImage(bayer, pattern, (black,) * 4, (1 << mode.bit_depth) - 1, mode.bit_depth, sensor.name, meta)


def _read_pixels(f: BinaryIO, start: int, mode: LegacyMode, header: dict[str, Any], path: Path) -> np.ndarray:
    if header["bayer_order"] >= len(_BAYER_ORDERS):
        raise RawFormatError(f"unknown Bayer order code {header['bayer_order']} in the raw header (expected 0-3)", path)
    if header["format"] == _FORMAT_BAYER:
        bits = _BAYER_FORMAT_BITS.get(header["bayer_format"])
        if bits is not None and bits != mode.bit_depth:
            raise RawFormatError(
                f"the raw header says {bits}-bit samples, but its block is the {_describe(mode)} mode", path
            )
    stride = _stride(mode.width + header["padding_right"], mode.bit_depth)
    data = mode.block_size - HEADER_SIZE
    if data % stride or data // stride < mode.height or stride < packed_row_bytes(mode.width, mode.bit_depth):
        raise RawFormatError(
            f"inconsistent raw layout: padding_right {header['padding_right']} gives {stride}-byte rows, "
            f"which do not divide the {data} pixel bytes into at least {mode.height} rows",
            path,
        )
    buffer = np.empty(mode.height * stride, dtype=np.uint8)
    f.seek(start + HEADER_SIZE)
    if f.readinto(memoryview(buffer)) != buffer.size:
        raise RawFormatError("truncated file: the raw rows end early", path)
    return unpack(buffer.reshape(mode.height, stride), mode.width, mode.bit_depth)


def _find_mode(raw: RawImage, path: Path) -> tuple[Sensor, LegacyMode]:
    if raw.sensor is None or raw.sensor.lower() not in SENSORS:
        raise RawFormatError(f"a legacy raw file needs a known sensor to choose its mode, got {raw.sensor!r}", path)
    sensor = SENSORS[raw.sensor.lower()]
    if not sensor.legacy_modes or sensor.legacy_model is None:
        raise RawFormatError(f"the {sensor.name} ({sensor.camera}) has no legacy firmware raw format", path)
    for mode in sensor.legacy_modes:
        if (mode.width, mode.height, mode.bit_depth) == (raw.width, raw.height, raw.bit_depth):
            return sensor, mode
    known = ", ".join(_describe(m) for m in sensor.legacy_modes)
    raise RawFormatError(
        f"{raw.width}x{raw.height} {raw.bit_depth}-bit is not a legacy raw mode of the {sensor.name} (modes: {known})",
        path,
    )


def _header(sensor: Sensor, mode: LegacyMode, raw: RawImage, padding_right: int) -> bytes:
    header = bytearray(HEADER_SIZE)
    ident = _IDENT_BY_SENSOR.get(sensor.name, _IDENT)
    header[: len(ident)] = ident
    name = raw.metadata.get("header_name")
    name = name if isinstance(name, str) and name else sensor.name
    transform = raw.metadata.get("transform", 0)
    transform = transform if isinstance(transform, int) and 0 <= transform <= 0xFFFF else 0
    _FIELDS.pack_into(
        header,
        _FIELDS_OFFSET,
        name.encode("ascii", "replace")[:31],
        mode.width,
        mode.height,
        padding_right,
        0,
        *([0] * 6),
        transform,
        _FORMAT_BAYER,
        _BAYER_ORDERS.index(raw.pattern),
        _BAYER_FORMAT_CODE[mode.bit_depth],
    )
    return bytes(header)


def _preview(raw: RawImage) -> np.ndarray:
    """A small 8-bit RGB preview: one pixel per 2x2 Bayer block (greens averaged), subsampled, square-root tone."""
    h2, w2 = raw.height // 2, raw.width // 2
    step = max(1, -(-max(h2, w2) // _PREVIEW_MAX_SIDE))
    rgb = np.zeros((-(-h2 // step), -(-w2 // step), 3), dtype=np.float32)
    for site, channel in enumerate(site_channels(raw.pattern)):
        plane = raw.bayer[site // 2 :: 2 * step, site % 2 :: 2 * step][: rgb.shape[0], : rgb.shape[1]]
        rgb[..., channel] += plane / np.float32(2.0 if channel == 1 else 1.0)
    return (np.sqrt(np.clip(rgb / np.float32(raw.white_level), 0, 1)) * 255 + 0.5).astype(np.uint8)


def _jpeg(raw: RawImage, sensor: Sensor) -> bytes:
    from PIL import Image, TiffImagePlugin

    exif = Image.Exif()
    exif[_MAKE] = "RaspberryPi"
    exif[_MODEL] = sensor.legacy_model
    exif[_SOFTWARE] = "picamcal"
    sub = exif.get_ifd(_EXIF_IFD)
    meta = raw.metadata
    notes = []
    exposure = _rational(meta.get("exposure_time_s"))
    if exposure is not None:
        fraction = Fraction(exposure).limit_denominator(1_000_000)
        sub[_EXPOSURE_TIME] = TiffImagePlugin.IFDRational(fraction.numerator, fraction.denominator)
        notes.append(f"exp={round(exposure * 1e6)}")
    gain = _rational(meta.get("analogue_gain"))
    if gain is not None:
        sub[_ISO] = min(round(100 * gain), 0xFFFF)
        notes.append(f"ag={round(gain * 256)}")
    if isinstance(meta.get("timestamp"), str):
        sub[_DATETIME_ORIGINAL] = meta["timestamp"]
    if notes:
        sub[_MAKER_NOTE] = " ".join(notes).encode("ascii")
    out = io.BytesIO()
    Image.fromarray(_preview(raw), "RGB").save(out, "JPEG", quality=85, exif=exif)
    return out.getvalue()


def write_brcm(path: str | os.PathLike[str], raw: RawImage, *, overwrite: bool = True) -> Path:
    """Write a RawImage as a legacy JPEG+raw file that :func:`read_brcm` and LibRaw read back bit-exactly.

    The JPEG is a small preview of the mosaic with EXIF ``Make`` ``RaspberryPi``, ``Model`` the sensor's
    legacy model (``RP_imx219``), ``ExposureTime`` and ``ISO`` (100 x analogue gain) from the metadata; the raw
    block that follows has exactly the registry's size for the sensor and mode, a header with format 33 (Bayer),
    the RAW10/RAW12 code and the Bayer order, and CSI-2 packed rows. Written to a temporary name, then renamed.

    Parameters
    ----------
    path : path-like
        Output file (conventionally ``.jpg``).
    raw : RawImage
        Mosaic of a legacy mode of its sensor (``raw.sensor``, size and bit depth must match one).
    overwrite : bool
        Replace an existing file (default); if False an existing file raises :class:`~picamcal.errors.OutputError`.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    RawFormatError
        The sensor has no legacy raw format (IMX708), or the size and bit depth are not one of its modes.

    Examples
    --------
    >>> from picamcal.simulate import simulate_references  # doctest: +SKIP
    >>> write_brcm("white.jpg", simulate_references("imx219")["white"])  # doctest: +SKIP
    PosixPath('white.jpg')
    """
    path = Path(path)
    sensor, mode = _find_mode(raw, path)
    if raw.pattern not in PATTERNS:
        raise RawFormatError(f"unknown Bayer pattern {raw.pattern!r}", path)
    if int(raw.bayer.max()) >= 1 << mode.bit_depth:
        raise RawFormatError(f"values above {(1 << mode.bit_depth) - 1} do not fit {mode.bit_depth}-bit samples", path)
    padding_right, stride, rows = _mode_layout(mode)
    jpeg = _jpeg(raw, sensor)
    header = _header(sensor, mode, raw, padding_right)
    pixels = pack(raw.bayer, mode.bit_depth, stride)
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        f.write(jpeg)
        f.write(header)
        f.write(pixels.data)
        f.write(bytes((rows - mode.height) * stride))
    return path
