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
import os
import re
import struct
import warnings
from collections.abc import Iterator, Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .._atomic import atomic_path
from ..errors import PicamcalWarning, RawFormatError, one_line, short
from ..limits import check_size, require_regular_file
from ..sensors import SENSORS, LegacyMode, Sensor, black_level_at, find_sensor_name
from .model import PATTERNS, RawImage, site_channels
from .packing import pack, packed_row_bytes, unpack

HEADER_SIZE = 32768
#: What every block starts with (the HQ camera's firmware writes ``BRCMo``: :attr:`Sensor.legacy_ident`).
_IDENT = b"BRCM"
_FIELDS = struct.Struct("<32s4H6I2H2B")
_FIELDS_OFFSET = 0xB0
_FORMAT_BAYER = 33  # VC_IMAGE_BAYER (raspberrypi/userland vc_image_types.h, as LibRaw cites it)
_BAYER_FORMAT_BITS = {2: 8, 3: 10, 4: 12, 5: 14, 6: 16}  # VC_IMAGE_BAYER_RAW8 ... RAW16
_BAYER_FORMAT_CODE = {bits: code for code, bits in _BAYER_FORMAT_BITS.items()}
_STRIDE_ALIGN = 32
_BAYER_ORDERS = ("RGGB", "GBRG", "BGGR", "GRBG")  # header bayer_order code -> pattern
#: How far from the end to look for a ``BRCM`` block of unknown size when diagnosing a file, and in what chunks.
_DIAGNOSE_WINDOW = 64 << 20
_DIAGNOSE_CHUNK = 1 << 20
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


def is_brcm(head: bytes) -> bool:
    """True if the first bytes of a file may be a legacy raw file: a JPEG (its raw block is at its end) or a block.

    Examples
    --------
    >>> is_brcm(b"\\xff\\xd8\\xff\\xe1"), is_brcm(b"BRCMo"), is_brcm(b"II*\\x00")
    (True, True, False)
    """
    return is_jpeg(head) or head.startswith(_IDENT)


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
    """The registry sensor an EXIF ``Model`` (or a raw header's name) means, early firmware's aliases included."""
    name = find_sensor_name(model)
    if name is None and model:
        lowered = model.lower()
        name = next((s.name for s in SENSORS.values() for alias in s.legacy_aliases if alias in lowered), None)
    return name


def _rational(value: Any) -> float | None:
    """One positive finite number (Pillow gives an EXIF RATIONAL as an ``IFDRational``), else None."""
    if isinstance(value, (bool, tuple, list, bytes, str)):
        return None
    try:
        result = float(value)
    except (TypeError, ValueError, ZeroDivisionError, OverflowError):
        return None
    return result if math.isfinite(result) and result > 0 else None


def _maker_note(value: Any, problems: list[str]) -> dict[str, Any]:
    """The firmware's MakerNote: ``ev=-1 mlux=-1 exp=62998 ag=556 ... gain_r=1.128 gain_b=2.546 ...``.

    ``ag`` (analogue gain, Q8) and ``gain_r``/``gain_b`` must be positive finite numbers; others are noted in
    ``problems`` and left out. A gain of ``ag=-1`` or ``ag=0`` is the firmware's "not known" and left out quietly.
    """
    text = value.decode("latin-1") if isinstance(value, bytes) else str(value)
    text = one_line(text)
    meta: dict[str, Any] = {"maker_note": text}
    fields = dict(re.findall(r"(?<![\w.])([a-z_]+)=(-?[0-9.]{1,32})(?![0-9.])", text))
    gain = _rational(_float(fields.get("ag")))
    if gain is not None:
        meta["analogue_gain"] = gain / 256.0  # Q8: ag=556 goes with ISO 220 in real files
    if "gain_r" in fields and "gain_b" in fields:
        gains = [_rational(_float(fields["gain_r"])), _rational(_float(fields["gain_b"]))]
        if None in gains:
            problems.append(f"MakerNote colour gains gain_r={fields['gain_r']} gain_b={fields['gain_b']}")
        else:
            meta["colour_gains"] = gains
    return meta


def _float(text: str | None) -> float | None:
    try:
        return None if text is None else float(text)
    except ValueError:  # "1.2.3" matches the MakerNote's number pattern too
        return None


def _exif_metadata(path: Path, problems: list[str]) -> dict[str, Any]:
    """Make, model, exposure, ISO, gains and timestamp from the JPEG's EXIF.

    All informative: EXIF that Pillow cannot parse, or a value of the wrong kind (an ExposureTime of two values,
    a zero denominator, text where a number belongs), is left out and noted in ``problems``.
    """
    from PIL import Image

    meta: dict[str, Any] = {}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as image:
                tags = image.getexif()
                exif, sub = dict(tags), dict(tags.get_ifd(_EXIF_IFD))
    except Exception as exc:  # only Pillow runs here, and it raises many types on a damaged JPEG or EXIF
        problems.append(f"the JPEG's EXIF cannot be read ({type(exc).__name__})")
        return meta
    for tag, key in ((_MAKE, "make"), (_MODEL, "model")):
        text = _exif_text(exif.get(tag), key, problems)
        if text:
            meta[key] = text
    if sub.get(_EXPOSURE_TIME) is not None:
        exposure = _rational(sub[_EXPOSURE_TIME])
        if exposure is None:
            problems.append(f"EXIF ExposureTime {short(sub[_EXPOSURE_TIME])} is not one positive number")
        else:
            meta["exposure_time_s"] = exposure
    iso = sub.get(_ISO)
    iso = iso[0] if isinstance(iso, tuple) and iso else iso
    if iso is not None:
        if isinstance(iso, int) and not isinstance(iso, bool) and iso > 0:
            meta["iso"] = iso
        else:
            problems.append(f"EXIF ISOSpeedRatings {short(iso)} is not a positive whole number")
    stamp = _exif_text(sub.get(_DATETIME_ORIGINAL), "DateTimeOriginal", problems) or _exif_text(
        exif.get(_DATETIME), "DateTime", problems
    )
    if stamp:
        meta["timestamp"] = stamp
    if sub.get(_MAKER_NOTE) is not None:
        if isinstance(sub[_MAKER_NOTE], (bytes, str)):
            meta.update(_maker_note(sub[_MAKER_NOTE], problems))
        else:
            problems.append("EXIF MakerNote is not text")
    return meta


def _exif_text(value: Any, name: str, problems: list[str]) -> str | None:
    """An EXIF ASCII value as one line of text; None if absent, noted in ``problems`` if not text."""
    if value is None:
        return None
    if not isinstance(value, str):
        problems.append(f"EXIF {name} {short(value)} is not text")
        return None
    return one_line(value) or None


def _header_fields(f: BinaryIO, start: int) -> dict[str, Any] | None:
    f.seek(start + _FIELDS_OFFSET)
    data = f.read(_FIELDS.size)
    if len(data) < _FIELDS.size:
        return None
    name, width, height, pad_right, pad_down, *_unused, transform, fmt, order, bayer_format = _FIELDS.unpack(data)
    return {
        "name": one_line(name.split(b"\x00", 1)[0].decode("latin-1")),
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


def _find_ident(f: BinaryIO, size: int) -> int | None:
    """Offset of the first ``BRCM`` in the last :data:`_DIAGNOSE_WINDOW` bytes, read a chunk at a time."""
    start = max(0, size - _DIAGNOSE_WINDOW)
    for at in range(start, size, _DIAGNOSE_CHUNK):
        f.seek(at)
        chunk = f.read(_DIAGNOSE_CHUNK + len(_IDENT) - 1)  # overlap: an ident across the chunk boundary
        found = chunk.find(_IDENT)
        if found >= 0:
            return at + found
    return None


def _diagnose(f: BinaryIO, size: int, head: bytes, path: Path) -> RawFormatError:
    """The error for a file with no raw block of a known size at its end."""
    found = _find_ident(f, size)
    if found is not None:
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
        from .processed import NOT_RAW  # only here: the readers of processed images are not needed to read raw

        return RawFormatError(f"a JPEG image with no raw (BRCM) block{ending}, {NOT_RAW}", path)
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


def read_brcm(path: str | os.PathLike[str], *, expected_shape: Sequence[int] | None = None) -> RawImage:
    """Read the Bayer mosaic from a legacy JPEG+raw file (raspistill ``--raw``, picamera ``bayer=True``).

    Only the raw block's header and its pixel rows are read (the block is found from the end of the file by
    the registry's block sizes, so no header can make it read more than the largest mode's block); the EXIF of
    the JPEG adds the sensor hint and exposure metadata.

    The header must agree with its block: width and height those of a mode of that block size, ``format`` 33
    (Bayer), ``bayer_format`` that mode's bit depth (3 = RAW10, 4 = RAW12), ``bayer_order`` 0-3 and a
    ``padding_right`` whose row stride divides the block; otherwise it is a ``RawFormatError`` naming the field.
    The size is checked (:func:`picamcal.limits.check_size`, and against ``expected_shape``) before the rows are
    read. The EXIF is informative: values Pillow cannot parse or of the wrong kind are left out with one
    :class:`~picamcal.errors.PicamcalWarning`.

    Parameters
    ----------
    path : path-like
        The JPEG+raw file (or a BRCM block on its own).
    expected_shape : (height, width), optional
        The mosaic size the caller needs (the calibration's): another size is refused before the rows are read.

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
        Not a regular file, empty, truncated or unrecognised, a JPEG without a raw block, or a header inconsistent
        with its block.
    CalibrationFileError
        The mosaic is not ``expected_shape``.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> _ = write_brcm("white.jpg", simulate_references(make_camera("imx219", size=(640, 480)), seed=1)["white"])
    >>> raw = read_brcm("white.jpg")
    >>> raw.sensor, raw.pattern, raw.bayer.shape, raw.black_level[0], raw.metadata["legacy_mode"]["modes"]
    ('imx219', 'BGGR', (480, 640), 64.0, [7])
    """
    path = Path(path)
    require_regular_file(path)
    problems: list[str] = []
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
            meta = _exif_metadata(path, problems) if is_jpeg(head) else {}
            sensor, mode, block, header = _choose(f, size, candidates, _sensor_from_model(meta.get("model")), path)
            check_size(path, header["width"], header["height"], expected_shape)
            bayer = _read_pixels(f, size - block, mode, header, path)
    except FileNotFoundError:
        raise RawFormatError("no such file", path) from None
    except IsADirectoryError:
        raise RawFormatError("is a directory, not a raw image file", path) from None
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from exc
    if problems:
        warnings.warn(f"{path}: malformed EXIF left out: {'; '.join(problems)}", PicamcalWarning, stacklevel=2)
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


def _read_pixels(f: io.BufferedIOBase, start: int, mode: LegacyMode, header: dict[str, Any], path: Path) -> np.ndarray:
    if header["bayer_order"] >= len(_BAYER_ORDERS):
        raise RawFormatError(f"unknown Bayer order code {header['bayer_order']} in the raw header (expected 0-3)", path)
    if header["format"] != _FORMAT_BAYER:
        raise RawFormatError(f"the raw header's format is {header['format']}, not {_FORMAT_BAYER} (Bayer)", path)
    bits = _BAYER_FORMAT_BITS.get(header["bayer_format"])
    if bits is None:
        known = ", ".join(f"{code} = RAW{depth}" for code, depth in _BAYER_FORMAT_BITS.items())
        raise RawFormatError(f"unknown bayer_format code {header['bayer_format']} in the raw header ({known})", path)
    if bits != mode.bit_depth:
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
    if f.readinto(buffer.data) != buffer.size:
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
    ident = sensor.legacy_ident.encode("ascii")
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
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(640, 480)), seed=1)["white"]  # sensor mode 7
    >>> write_brcm("white.jpg", white)
    PosixPath('white.jpg')
    >>> Path("white.jpg").stat().st_size - 445440 > 0  # a JPEG preview, then the mode's 445440-byte raw block
    True
    >>> write_brcm("white.jpg", simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"])
    Traceback (most recent call last):
    ...
    picamcal.errors.RawFormatError: white.jpg: 320x240 10-bit is not a legacy raw mode of the imx219 (modes: ...)
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
