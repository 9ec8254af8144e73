"""Processed images (JPEG, PNG, 8/16-bit TIFF) read as linear RGB.

A processed image has been through the camera's ISP: black level, lens shading, colour gains,
demosaicing and a tone curve. picamcal can still unmix its colours, but only after undoing the tone
curve, which the file does not describe: the caller says how it was encoded (``encoding``):

``srgb``
    the sRGB transfer function (most JPEG and PNG files).
``linear``
    no curve (values are proportional to light).
``gamma:G``
    a pure power law, linear = value ** G (e.g. ``gamma:2.2``).
``tuning:FILE``
    the ``rpi.contrast`` ``gamma_curve`` of a libcamera tuning file, as the Raspberry Pi ISP applied it.

16-bit PNG is read with pypng (Pillow reduces 16-bit colour PNG to 8 bits), TIFF with tifffile,
everything else with Pillow. A float TIFF picamcal wrote (``apply-tuning``, ``correct``) is linear RGB whatever the
encoding given, and its record (``metadata["picamcal"]``) says what made it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._json import Fields, parse_json, read_libcamera_yaml
from ..errors import PicamcalError, RawFormatError, closest
from ..limits import check_size
from .npy import file_head

#: What follows the name of a processed image (or any file that is no raw frame) given where a raw frame is needed:
#: the one wording for every command that can meet one, which fits each of them (calibrate has no --processed,
#: correct has).
NOT_RAW = (
    "not a raw image (DNG, JPEG+raw from raspistill --raw or picamera bayer=True, picamera2 .npy, a headless dump): "
    "a calibration cannot be made from processed images; correct takes them with --processed"
)


@dataclass
class ProcessedImage:
    """A processed RGB image, linearised.

    Attributes
    ----------
    rgb : ndarray of float32, shape (H, W, 3)
        Linear RGB scaled so that the file's full scale is 1.0.
    encoding : str
        The encoding that was undone.
    bit_depth : int
        Bits per sample in the file.
    metadata : dict
        ``format`` (``jpeg``, ``png``, ``tiff``), ``path`` and EXIF exposure data where present.
    """

    rgb: np.ndarray
    encoding: str
    bit_depth: int
    metadata: dict[str, Any] = field(default_factory=dict)

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return int(self.rgb.shape[0])

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return int(self.rgb.shape[1])


def _srgb_to_linear(v: np.ndarray) -> np.ndarray:
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def tuning_gamma_curve(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """The ``rpi.contrast`` gamma curve of a libcamera tuning file as (linear, encoded), both scaled to 0..1.

    Raises
    ------
    RawFormatError
        Not a regular file, not what libcamera's YAML parser reads, no ``rpi.contrast`` ``gamma_curve``, or one
        that is not increasing pairs of numbers in 0..65535.

    Examples
    --------
    >>> from picamcal.export.tuning import stock_tuning_path
    >>> linear, encoded = tuning_gamma_curve(stock_tuning_path("imx219", "pisp"))
    >>> float(linear[0]), float(linear[-1]), bool(np.all(np.diff(encoded) >= 0))
    (0.0, 1.0, True)
    """
    path = Path(path)
    tuning = read_libcamera_yaml(path, RawFormatError, "a libcamera tuning file")  # as libcamera parses it
    fields = Fields(path, RawFormatError, "a tuning file with a gamma curve")
    algorithms = fields.items(fields.mapping(tuning, "the file", ("algorithms",))["algorithms"], "'algorithms'")
    sections = [a["rpi.contrast"] for a in algorithms if isinstance(a, dict) and "rpi.contrast" in a]
    if not sections:
        raise RawFormatError("the tuning file has no rpi.contrast gamma_curve", path)
    section = fields.mapping(sections[0], "rpi.contrast", ("gamma_curve",))
    curve = np.asarray(fields.numbers(section["gamma_curve"], "rpi.contrast gamma_curve", minimum=0, maximum=65535))
    if curve.size < 4 or curve.size % 2:
        raise RawFormatError("rpi.contrast gamma_curve must hold (input, output) pairs", path)
    linear, encoded = curve[0::2] / 65535.0, curve[1::2] / 65535.0
    if np.any(np.diff(linear) <= 0) or np.any(np.diff(encoded) < 0):
        raise RawFormatError("rpi.contrast gamma_curve is not increasing, so it cannot be undone", path)
    return linear, encoded


def linearise(values: np.ndarray, encoding: str) -> np.ndarray:
    """Undo a tone curve: map encoded values in 0..1 to linear light in 0..1.

    Parameters
    ----------
    values : ndarray
        Encoded values scaled to 0..1.
    encoding : str
        ``srgb``, ``linear``, ``gamma:G`` or ``tuning:FILE`` (see the module docstring).

    Examples
    --------
    >>> float(linearise(np.array(0.5), "gamma:2.0"))
    0.25
    >>> round(float(linearise(np.array(0.5), "sRGB")), 4)
    0.214
    """
    kind, _, arg = encoding.partition(":")
    kind = kind.strip().lower()  # sRGB, Linear, GAMMA:2.2 are what users type; a tuning file's name keeps its case
    values = np.asarray(values, dtype=np.float32)
    if kind == "srgb" and not arg:
        return _srgb_to_linear(values).astype(np.float32)
    if kind == "linear" and not arg:
        return values
    if kind == "gamma":
        try:
            g = float(arg)
        except ValueError:
            raise PicamcalError(f"input encoding {encoding!r}: the gamma must be a number, e.g. gamma:2.2") from None
        if not 0.1 <= g <= 10:
            raise PicamcalError(f"input encoding {encoding!r}: gamma {g} is outside 0.1..10")
        return np.power(np.clip(values, 0, None), g).astype(np.float32)
    if kind == "tuning" and arg:
        linear, encoded = tuning_gamma_curve(arg)
        return np.interp(values, encoded, linear).astype(np.float32)
    near = closest(kind, ["srgb", "linear", "gamma", "tuning"])
    hint = f" (did you mean {near}{':...' if near in ('gamma', 'tuning') else ''}?)" if near else ""
    raise PicamcalError(f"unknown input encoding {encoding!r}{hint}: use srgb, linear, gamma:G or tuning:FILE")


def _read_png16(path: Path) -> np.ndarray:
    import png

    with open(path, "rb") as f:
        reader = png.Reader(file=f)
        reader.preamble()  # the header alone: the size is checked before a row is decoded
        check_size(path, reader.width, reader.height)
        width, height, rows, info = reader.asDirect()
        return np.vstack([np.asarray(row, dtype=np.uint16) for row in rows]).reshape(height, width, info["planes"])


def _png_bit_depth(path: Path) -> int:
    with open(path, "rb") as f:
        head = f.read(26)
    return head[24] if len(head) >= 26 and head[12:16] == b"IHDR" else 8


def _read_tiff(path: Path, meta: dict[str, Any]) -> np.ndarray:
    import tifffile

    with tifffile.TiffFile(path) as tif:
        series = tif.series[0]
        shape = tuple(series.shape)
        if len(shape) != 3 or shape[-1] not in (3, 4):
            raise RawFormatError(f"expected an RGB image, got an array of shape {shape}", path)
        check_size(path, int(shape[1]), int(shape[0]))
        meta.update(_picamcal_description(tif.pages.first.tags))
        return series.asarray()


def _picamcal_description(tags: Any) -> dict[str, Any]:
    """picamcal's own record in a TIFF it wrote (Software ``picamcal ...``, a JSON ImageDescription), as metadata.

    ``picamcal`` holds the record (``apply-tuning`` writes whether it applied the CCM, ``"ccm"``); its
    ``colour_gains``, if any, become the image's. A damaged or foreign description is simply not picamcal's.
    """
    software, description = tags.get(305), tags.get(270)
    if software is None or not str(software.value).startswith("picamcal") or description is None:
        return {}
    try:
        record = parse_json(str(description.value), RawFormatError, "picamcal's description").get("picamcal")
    except (PicamcalError, AttributeError):
        return {}
    if not isinstance(record, dict):
        return {}
    meta: dict[str, Any] = {"picamcal": record}
    gains = record.get("colour_gains")
    if isinstance(gains, list) and len(gains) == 2 and all(isinstance(g, (int, float)) and g > 0 for g in gains):
        meta["colour_gains"] = [float(g) for g in gains]
    return meta


def _read_with_pillow(path: Path, meta: dict[str, Any]) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    with warnings.catch_warnings():
        # Pillow's own bomb check warns first and refuses at twice its limit; picamcal's limit decides instead
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            image = Image.open(path)
        except UnidentifiedImageError:
            raise RawFormatError("not an image file picamcal can read (JPEG, PNG or TIFF)", path) from None
        except Image.DecompressionBombError as exc:
            # Pillow gives only the pixel count; the header gives the size for the usual message
            with open(path, "rb") as f:
                width, height = _declared_size(f.read(1 << 16))
            if width and height:
                check_size(path, width, height)
            raise RawFormatError(f"declares an image too large to decode ({exc})", path) from None
    with image:
        check_size(path, image.width, image.height)
        meta["format"] = (image.format or "image").lower()
        meta.update(_exif(image))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            return np.asarray(image.convert("RGB"))


def _declared_size(head: bytes) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR or a JPEG's start-of-frame, or (0, 0) if neither is found."""
    if head.startswith(b"\x89PNG") and head[12:16] == b"IHDR":
        return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    at = 2
    while head.startswith(b"\xff\xd8") and at + 9 <= len(head) and head[at] == 0xFF:
        marker, length = head[at + 1], int.from_bytes(head[at + 2 : at + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            return int.from_bytes(head[at + 7 : at + 9], "big"), int.from_bytes(head[at + 5 : at + 7], "big")
        at += 2 + length
    return 0, 0


def _exif(image: Any) -> dict[str, Any]:
    meta: dict[str, Any] = {}
    try:
        exif = image.getexif()
        sub = exif.get_ifd(0x8769)
    except Exception:
        return meta
    for tag, key in ((271, "make"), (272, "model")):
        if tag in exif:
            meta[key] = str(exif[tag]).strip("\x00 ")
    if 33434 in sub:
        meta["exposure_time_s"] = float(sub[33434])
    if 34855 in sub:
        iso = sub[34855]
        meta["iso"] = int(iso[0] if isinstance(iso, tuple) else iso)
    return meta


@contextlib.contextmanager
def _quiet_tifffile() -> Iterator[None]:
    """Keep tifffile's log lines about a damaged file off stderr: the error that follows says it in one line."""
    logger = logging.getLogger("tifffile")
    level = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        logger.setLevel(level)


def _refuse_raw(path: Path, head: bytes) -> None:
    """A raw image given as processed: say so, rather than decode a DNG's preview or a mosaic as colours."""
    what = None
    if head[:6] == b"\x93NUMPY":
        what = "a raw buffer (.npy)"
    elif head.startswith(b"PK"):
        from .npz import is_raw_npz

        what = "a picamcal raw image (.npz)" if is_raw_npz(path) else None
    elif head[:4] in (b"II*\x00", b"MM\x00*"):
        import tifffile

        try:
            with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
                what = "a DNG raw image" if 50706 in tif.pages.first.tags else None  # DNGVersion
        except Exception:  # a broken TIFF is for the decoder below to report
            what = None
    if what is not None:
        raise RawFormatError(f"{what}, not a processed one: leave out --processed", path)


def read_processed(path: str | os.PathLike[str], encoding: str = "srgb") -> ProcessedImage:
    """Read a processed image as linear RGB.

    Parameters
    ----------
    path : path-like
        JPEG, PNG (8 or 16 bit) or TIFF (8 or 16 bit, or float on a 0..1 scale; RGB).
    encoding : str
        How the values were encoded: ``srgb`` (default), ``linear``, ``gamma:G``, ``tuning:FILE``. A float32
        TIFF that picamcal wrote (``apply-tuning``, ``correct``) says it is linear RGB, and is read as such
        whatever the encoding, as is a ``uint16-tiff`` (``code / scale``, its record's scale); its record is kept
        as ``metadata["picamcal"]`` (and its ``colour_gains``, if it has them, as the image's: see
        :func:`picamcal.export.isp.processed_inputs`).

    Examples
    --------
    >>> from PIL import Image
    >>> Image.fromarray(np.full((4, 6, 3), 188, np.uint8)).save("grey.png")  # sRGB 188: linear 0.5
    >>> image = read_processed("grey.png", encoding="srgb")
    >>> image.rgb.shape, image.rgb.dtype, round(float(image.rgb.mean()), 3)
    ((4, 6, 3), dtype('float32'), 0.503)
    """
    path = Path(path)
    head = file_head(path)
    _refuse_raw(path, head)
    meta: dict[str, Any] = {"path": str(path)}
    try:
        with _quiet_tifffile():
            if head[:4] in (b"II*\x00", b"MM\x00*"):
                data = _read_tiff(path, meta)
                meta["format"] = "tiff"
            elif head.startswith(b"\x89PNG") and _png_bit_depth(path) == 16:
                data = _read_png16(path)
                meta["format"] = "png"
            else:
                data = _read_with_pillow(path, meta)
    except PicamcalError:
        raise
    except Exception as exc:  # every decoder's own errors (and MemoryError): the file, not the program, is wrong
        raise RawFormatError(f"cannot decode the image ({type(exc).__name__}: {exc})", path) from None
    if data.ndim == 3 and data.shape[-1] == 4:
        data = data[..., :3]
    if data.ndim != 3 or data.shape[-1] != 3:
        raise RawFormatError(f"expected an RGB image, got an array of shape {data.shape}", path)
    if data.dtype == np.uint8:
        bits = 8
    elif data.dtype == np.uint16:
        bits = 16
    elif data.dtype in (np.float32, np.float64):
        bits = 32  # float TIFF (picamcal's own output, for one): taken as values on a 0..1 scale
    else:
        raise RawFormatError(f"expected 8- or 16-bit or float samples, got {data.dtype}", path)
    if bits == 32 and not np.all(np.isfinite(data)):
        count = int(np.count_nonzero(~np.isfinite(data)))
        raise RawFormatError(f"holds {count} NaN or infinite samples: not an image picamcal can correct", path)
    # picamcal's uint16-tiff: linear, value = code / scale (its record says so), the white reference at the scale.
    scale = meta.get("picamcal", {}).get("scale") if bits == 16 else None
    scale = float(scale) if isinstance(scale, (int, float)) and not isinstance(scale, bool) and scale > 0 else None
    if (bits == 32 and "picamcal" in meta) or scale is not None:
        # picamcal writes float samples only as linear RGB: undoing a tone curve that was never applied would bend
        # every value (corner CIEDE2000 of 5 to 8 for apply-tuning's output read with the tuning's curve).
        encoding = "linear"
    values = data.astype(np.float32) if bits == 32 else data.astype(np.float32) / (scale or float((1 << bits) - 1))
    meta["encoding"] = encoding
    return ProcessedImage(linearise(values, encoding), encoding, bits, meta)
