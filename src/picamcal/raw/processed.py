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
everything else with Pillow.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PicamcalError, RawFormatError, closest
from ._files import file_head


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

    Examples
    --------
    >>> linear, encoded = tuning_gamma_curve("imx219.json")  # doctest: +SKIP
    """
    path = Path(path)
    try:
        tuning = json.loads(path.read_text())
        for algorithm in tuning["algorithms"]:
            if "rpi.contrast" in algorithm:
                curve = np.asarray(algorithm["rpi.contrast"]["gamma_curve"], dtype=float)
                break
        else:
            raise RawFormatError("the tuning file has no rpi.contrast gamma_curve", path)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise RawFormatError(f"cannot read a gamma curve from this tuning file ({exc})", path) from exc
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
        width, height, rows, info = png.Reader(file=f).asDirect()
        return np.vstack([np.asarray(row, dtype=np.uint16) for row in rows]).reshape(height, width, info["planes"])


def _png_bit_depth(path: Path) -> int:
    with open(path, "rb") as f:
        head = f.read(26)
    return head[24] if len(head) >= 26 and head[12:16] == b"IHDR" else 8


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
            with tifffile.TiffFile(path) as tif:
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
        How the values were encoded: ``srgb`` (default), ``linear``, ``gamma:G``, ``tuning:FILE``.

    Examples
    --------
    >>> image = read_processed("sample.jpg", encoding="tuning:imx219.json")  # doctest: +SKIP
    >>> image.rgb.dtype, image.rgb.max() <= 1.0  # doctest: +SKIP
    """
    path = Path(path)
    head = file_head(path)
    _refuse_raw(path, head)
    meta: dict[str, Any] = {"path": str(path)}
    try:
        if head[:4] in (b"II*\x00", b"MM\x00*"):
            import tifffile

            data = tifffile.imread(path)
            meta["format"] = "tiff"
        elif head.startswith(b"\x89PNG") and _png_bit_depth(path) == 16:
            data = _read_png16(path)
            meta["format"] = "png"
        else:
            from PIL import Image, UnidentifiedImageError

            try:
                with Image.open(path) as image:
                    meta["format"] = (image.format or "image").lower()
                    meta.update(_exif(image))
                    data = np.asarray(image.convert("RGB"))
            except UnidentifiedImageError:
                raise RawFormatError("not an image file picamcal can read (JPEG, PNG or TIFF)", path) from None
    except RawFormatError:
        raise
    except Exception as exc:
        raise RawFormatError(f"cannot decode the image ({type(exc).__name__}: {exc})", path) from exc
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
    values = data.astype(np.float32) if bits == 32 else data.astype(np.float32) / float((1 << bits) - 1)
    meta["encoding"] = encoding
    return ProcessedImage(linearise(values, encoding), encoding, bits, meta)
