"""Writing corrected images: linear TIFF for measuring, colour-managed sRGB PNG and JPEG for looking at.

One function, :func:`write_corrected`, writes a corrected image (linear RGB in which the calibration's
white reference is 1.0) in one of :data:`OUTPUT_FORMATS`, atomically, with its provenance:

``float32-tiff``
    The values as they are (white reference 1.0); ``ImageDescription`` JSON ``{"picamcal": {...}}``.
``uint16-tiff``
    Linear, ``code = round(value * UINT16_WHITE)``: the white reference at 32768, so that values up to
    twice the white keep their headroom (clipped at 0 and 65535). An ImageJ hyperstack (channels R, G, B,
    composite display, each channel's display range 0-32768) with ImageJ's calibration function set to
    ``value = code / 32768`` (unit "white"), so that Fiji opens it as three channels and measures in units
    of the white reference; the provenance JSON is the ImageJ ``Info`` property.
``srgb-png``, ``srgb-png16``, ``srgb-jpeg``
    Colour-managed (:func:`encode_srgb`): the corrected RGB to linear sRGB through a 3x3 colour matrix
    (:func:`camera_to_srgb`), the white reference at linear :data:`SRGB_WHITE_LEVEL` (0.8: code 231 of
    255, 59396 of 65535), values outside 0-1 clipped, the sRGB transfer function (IEC 61966-2-1), and an
    sRGB ICC profile embedded. Provenance in a PNG ``iTXt`` chunk ``picamcal`` (JSON) and ``tEXt Software``;
    in the JPEG's EXIF ``ImageDescription`` (JSON) and ``Software``. JPEG at quality 95 without chroma
    subsampling (4:4:4).

docs/outputs.md says what opens each format.
"""

from __future__ import annotations

import io
import json
import os
import warnings
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from ._atomic import atomic_path
from ._version import __version__
from .errors import PicamcalError, PicamcalWarning

#: What ``picamcal correct --output-format`` writes: linear float32 or uint16 TIFF, or colour-managed sRGB images.
OUTPUT_FORMATS = ("float32-tiff", "uint16-tiff", "srgb-png", "srgb-png16", "srgb-jpeg")
#: The colour-managed formats: they need a colour matrix (:func:`camera_to_srgb`).
SRGB_FORMATS = ("srgb-png", "srgb-png16", "srgb-jpeg")
#: The formats that take ``compression="zstd"``.
TIFF_FORMATS = ("float32-tiff", "uint16-tiff")
#: File name suffix of each format.
OUTPUT_SUFFIXES = {
    "float32-tiff": ".tiff",
    "uint16-tiff": ".tiff",
    "srgb-png": ".png",
    "srgb-png16": ".png",
    "srgb-jpeg": ".jpg",
}
#: ``uint16-tiff`` code of the white reference (value 1.0): a power of two, so code / 32768 is exact.
UINT16_WHITE = 32768
#: Linear sRGB level of the white reference in the sRGB formats: 25 % headroom above it before clipping.
SRGB_WHITE_LEVEL = 0.8
#: JPEG quality of ``srgb-jpeg`` (Pillow's scale, 1-95).
JPEG_QUALITY = 95

#: Linear sRGB (D65) to CIE XYZ, IEC 61966-2-1:1999 section 5.2 (the standard's 4-digit matrix).
SRGB_TO_XYZ_D65 = np.array(
    [
        [0.4124, 0.3576, 0.1805],
        [0.2126, 0.7152, 0.0722],
        [0.0193, 0.1192, 0.9505],
    ]
)
#: CIE XYZ relative to D50 to linear sRGB (D65), Bradford chromatic adaptation: Bruce Lindbloom, "RGB/XYZ
#: Matrices" (http://www.brucelindbloom.com/Eqn_RGB_XYZ_Matrix.html, sRGB with reference white D50).
#: tests/test_output.py checks it against colour-science.
XYZ_D50_TO_SRGB = np.array(
    [
        [3.1338561, -1.6168667, -0.4906146],
        [-0.9787684, 1.9161415, 0.0334540],
        [0.0719453, -0.2289914, 1.4052427],
    ]
)
#: What an identity colour matrix means when nothing better is known.
NO_MATRIX = "none known: the camera's primaries are taken as sRGB's (identity)"

_TEMPERATURE_K = 4500.0  # CCM colour temperature when neither the image nor the tuning file says
_STRIP_PIXELS = 1 << 20  # rows are encoded in strips of about this many pixels: bounded temporaries
_SOFTWARE = f"picamcal {__version__}"
# zlib level 1: a 12 MP frame compresses about four times faster than at the default 6, for files about 15 %
# larger (measured on a smooth scene with 1 % noise: 19.7 against 16.7 MB).
_PNG_ZLIB_LEVEL = 1
_ICC_DATE = bytes.fromhex("07e8 0001 0001 0000 0000 0000")  # 2024-01-01 00:00:00, see _srgb_profile


# ------------------------------------------------------------------------------------------------ colour
@dataclass(frozen=True, eq=False)
class ColourMatrix:
    """A 3x3 matrix from a corrected image's RGB to linear sRGB, and where it came from.

    The matrix is normalised on construction so that white (1, 1, 1) maps to white (each row divided by its
    sum): the calibration's white reference stays neutral, at the stated level.

    Attributes
    ----------
    matrix : ndarray (3, 3)
        ``srgb = matrix @ rgb``, rows summing to 1.
    source : str
        Where it came from, in words (recorded in the outputs' metadata).

    Examples
    --------
    >>> ColourMatrix([[2.0, -0.5, -0.5], [-0.25, 1.5, -0.25], [0.0, -0.5, 1.5]], "my chart fit").matrix[0]
    array([ 2. , -0.5, -0.5])
    """

    matrix: np.ndarray
    source: str

    def __post_init__(self) -> None:
        matrix = np.asarray(self.matrix, dtype=float)
        if matrix.shape != (3, 3) or not np.isfinite(matrix).all():
            raise ValueError(f"a colour matrix is 3x3 and finite, not {matrix.tolist()}")
        white = matrix.sum(axis=1)
        if (white <= 1e-6).any():
            raise ValueError(f"this colour matrix takes white to {white.round(4).tolist()}: it cannot be normalised")
        object.__setattr__(self, "matrix", matrix / white[:, None])


def forward_matrix_to_srgb(forward_matrix: Any) -> np.ndarray:
    """White-balanced camera RGB to linear sRGB from a DNG ForwardMatrix (camera to XYZ D50), not normalised.

    The DNG specification (1.4, chapter 6, "Camera to XYZ (D50) transform") defines ForwardMatrix as mapping
    white-balanced camera colours to XYZ relative to D50; :data:`XYZ_D50_TO_SRGB` takes those to sRGB.

    Examples
    --------
    >>> np.allclose(forward_matrix_to_srgb(np.linalg.inv(XYZ_D50_TO_SRGB)), np.eye(3))  # sRGB primaries
    True
    """
    return XYZ_D50_TO_SRGB @ np.asarray(forward_matrix, dtype=float).reshape(3, 3)


def color_matrix_to_srgb(color_matrix: Any) -> np.ndarray:
    """White-balanced camera RGB to linear sRGB from a DNG ColorMatrix (XYZ to camera), white to white.

    As dcraw does it: ``camera_from_srgb = ColorMatrix @ SRGB_TO_XYZ_D65``, each row scaled so that sRGB
    white gives camera (1, 1, 1) (the white balance: the scene's white is taken as D65), then inverted.

    Raises
    ------
    ValueError
        The matrix is singular.

    Examples
    --------
    >>> np.allclose(color_matrix_to_srgb(np.linalg.inv(SRGB_TO_XYZ_D65)), np.eye(3))  # sRGB primaries
    True
    """
    camera_from_srgb = np.asarray(color_matrix, dtype=float).reshape(3, 3) @ SRGB_TO_XYZ_D65
    white = camera_from_srgb.sum(axis=1)
    if np.linalg.cond(camera_from_srgb) > 1e8 or (np.abs(white) < 1e-9).any():
        raise ValueError("the ColorMatrix is singular")
    return np.linalg.inv(camera_from_srgb / white[:, None])


def camera_to_srgb(
    metadata: Mapping[str, Any] | None = None,
    tuning: Mapping[str, Any] | None = None,
    *,
    tuning_path: str | os.PathLike[str] | None = None,
) -> ColourMatrix:
    """The colour matrix for the sRGB outputs of a raw image, from the best source known.

    In this order: the ``tuning`` file's ``rpi.ccm`` (libcamera's CCM maps white-balanced camera RGB to
    linear sRGB), at the image's colour temperature (``metadata["colour_temperature"]``, from picamera2),
    else the tuning file's ``rpi.alsc`` ``default_ct``, else 4500 K; the image's own libcamera CCM
    (``metadata["colour_correction_matrix"]``, picamera2's ``ColourCorrectionMatrix``); a DNG's
    ForwardMatrix1 (:func:`forward_matrix_to_srgb`); a DNG's ColorMatrix1 (:func:`color_matrix_to_srgb`);
    else the identity (:data:`NO_MATRIX`). An identity matrix in a file is a placeholder (picamcal's own
    DNGs carried one), not a measurement, and is passed over. The image's matrices are the camera's
    own: for the corrected image they are right in ``balance``, ``flat`` and ``centre`` modes, whose
    output is white-balanced camera RGB.

    Parameters
    ----------
    metadata : mapping, optional
        The raw image's metadata (:attr:`picamcal.RawImage.metadata`).
    tuning : mapping, optional
        A libcamera tuning file (:func:`picamcal.export.tuning.load_tuning`).
    tuning_path : path-like, optional
        Where ``tuning`` came from: named in the matrix's source and in errors.

    Returns
    -------
    ColourMatrix

    Raises
    ------
    PicamcalError
        The tuning file has no ``rpi.ccm``.

    Examples
    --------
    >>> camera_to_srgb({"colour_correction_matrix": [1.8, -0.6, -0.2, -0.3, 1.6, -0.3, 0.0, -0.7, 1.7]}).source
    "the image's ColourCorrectionMatrix (libcamera's CCM at capture)"
    >>> camera_to_srgb({}).source == NO_MATRIX
    True
    """
    metadata = metadata or {}
    if tuning is not None:
        from .export.isp import alsc_section, tuning_ccm

        ct = metadata.get("colour_temperature")
        if not ct:
            try:
                ct = alsc_section(dict(tuning)).get("default_ct", _TEMPERATURE_K)
            except PicamcalError:
                ct = _TEMPERATURE_K
        ccm = tuning_ccm(dict(tuning), float(ct))
        if ccm is None:
            raise PicamcalError("has no rpi.ccm colour matrix: give the camera's own tuning file", tuning_path)
        name = Path(tuning_path).name if tuning_path is not None else "the tuning file"
        return ColourMatrix(ccm, f"{name} rpi.ccm at {float(ct):.0f} K")
    where = metadata.get("path", "the image")
    candidates = (
        ("colour_correction_matrix", "the image's ColourCorrectionMatrix (libcamera's CCM at capture)", np.asarray),
        ("forward_matrix1", "the DNG's ForwardMatrix1, then XYZ D50 to sRGB (Bradford)", forward_matrix_to_srgb),
        ("color_matrix1", "the DNG's ColorMatrix1, inverted (scene white taken as D65)", color_matrix_to_srgb),
    )
    for key, source, to_srgb in candidates:
        values = metadata.get(key)
        if values is None:
            continue
        matrix = np.asarray(values, dtype=float)
        if matrix.size != 9 or np.allclose(matrix.reshape(3, 3), np.eye(3)):
            continue
        try:
            return ColourMatrix(to_srgb(matrix.reshape(3, 3)), source)
        except ValueError as exc:
            warnings.warn(f"{where}: its {key} is not usable ({exc}); trying the next source", PicamcalWarning, 2)
    return ColourMatrix(np.eye(3), NO_MATRIX)


def srgb_transfer(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1:1999, the encoding): linear 0-1 to non-linear 0-1.

    Examples
    --------
    >>> float(srgb_transfer(np.array(SRGB_WHITE_LEVEL)) * 255)
    231.11459710273513
    """
    linear = np.asarray(linear, dtype=float)
    return np.where(
        linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(np.maximum(linear, 0.0031308), 1 / 2.4) - 0.055
    )


def encode_srgb(
    rgb: np.ndarray,
    colour_matrix: ColourMatrix | None = None,
    *,
    white_level: float = SRGB_WHITE_LEVEL,
    bits: int = 8,
) -> np.ndarray:
    """Linear RGB (white reference 1.0) to sRGB code values: matrix, white level, clip, transfer function.

    ``code = round((2**bits - 1) * srgb_transfer(clip(white_level * matrix @ rgb, 0, 1)))``; NaN gives 0.

    Parameters
    ----------
    rgb : ndarray (H, W, 3)
        Corrected linear RGB.
    colour_matrix : ColourMatrix, optional
        To linear sRGB (:func:`camera_to_srgb`); default the identity.
    white_level : float
        The linear sRGB level of the white reference (1.0 in ``rgb``).
    bits : {8, 16}

    Returns
    -------
    ndarray of uint8 or uint16, shape (H, W, 3)

    Examples
    --------
    >>> encode_srgb(np.ones((1, 1, 3), np.float32))
    array([[[231, 231, 231]]], dtype=uint8)
    """
    if bits not in (8, 16):
        raise ValueError("bits is 8 or 16")
    rgb = _check_rgb(rgb)
    matrix = np.eye(3) if colour_matrix is None else colour_matrix.matrix
    to_linear = (white_level * matrix).T
    top = 2**bits - 1
    out = np.empty(rgb.shape, dtype=np.uint8 if bits == 8 else np.uint16)
    for rows in _strips(rgb.shape):
        linear = np.nan_to_num(rgb[rows].astype(float) @ to_linear, nan=0.0)
        out[rows] = np.rint(top * srgb_transfer(np.clip(linear, 0.0, 1.0)))
    return out


def encode_uint16(rgb: np.ndarray) -> np.ndarray:
    """Linear RGB to ``uint16-tiff`` codes, planar (3, H, W): ``round(value * UINT16_WHITE)``, clipped; NaN gives 0.

    Examples
    --------
    >>> encode_uint16(np.array([[[1.0, 0.5, 2.5]]], np.float32)).ravel()
    array([32768, 16384, 65535], dtype=uint16)
    """
    rgb = _check_rgb(rgb)
    out = np.empty((3, *rgb.shape[:2]), dtype=np.uint16)
    for rows in _strips(rgb.shape):
        codes = np.clip(np.nan_to_num(rgb[rows].astype(float), nan=0.0) * UINT16_WHITE, 0, 65535)
        out[:, rows] = np.moveaxis(np.rint(codes), -1, 0)
    return out


def output_bytes(output_format: str, shape: tuple[int, ...]) -> int:
    """The size of one output of ``shape`` (H, W, 3) uncompressed, in bytes: what a batch reserves to check for room.

    The headers, metadata and ICC profile (a few kB) are left out; PNG and JPEG are usually much smaller.

    Examples
    --------
    >>> output_bytes("uint16-tiff", (3040, 4056, 3))
    73981440
    """
    per_sample = {"float32-tiff": 4, "uint16-tiff": 2, "srgb-png16": 2}.get(output_format, 1)
    return int(np.prod(shape)) * per_sample


# ------------------------------------------------------------------------------------------------ writing
def write_corrected(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    output_format: str = "float32-tiff",
    metadata: Mapping[str, Any] | None = None,
    *,
    colour_matrix: ColourMatrix | None = None,
    white_level: float = SRGB_WHITE_LEVEL,
    overwrite: bool = False,
    compression: str | None = None,
) -> Path:
    """Write a corrected image in one of :data:`OUTPUT_FORMATS`, atomically, with its provenance.

    The formats, their scales and their metadata are described in this module's docstring and in
    docs/outputs.md.

    Parameters
    ----------
    path : path-like
        The file to write (its suffix is not checked: :data:`OUTPUT_SUFFIXES` has the usual ones).
    rgb : ndarray (H, W, 3)
        Corrected linear RGB, the white reference at 1.0.
    output_format : str
        One of :data:`OUTPUT_FORMATS`.
    metadata : mapping, optional
        Provenance (source, calibration, mode, ...): JSON-serialisable. The sRGB and uint16 formats add
        ``output_format`` and ``picamcal_version`` and their scale; the sRGB ones add the colour matrix and
        its source, ``white_level`` and ``white_code``. float32 TIFFs keep it as given (their scale is
        1.0 by definition) and name the version in the TIFF ``Software`` tag, as every TIFF does.
    colour_matrix : ColourMatrix, optional
        sRGB formats: to linear sRGB (:func:`camera_to_srgb`); default the identity (:data:`NO_MATRIX`).
    white_level : float
        sRGB formats: the linear sRGB level of the white reference.
    overwrite : bool
        Replace an existing file; otherwise that is an :class:`~picamcal.errors.OutputError`.
    compression : {None, "zstd"}
        TIFF formats: lossless zstd with a predictor (needs imagecodecs; ImageJ's own TIFF reader cannot
        decompress it).

    Returns
    -------
    Path

    Raises
    ------
    OutputError
        The file exists (without ``overwrite``) or cannot be written.

    Examples
    --------
    >>> write_corrected("out/sample.png", rgb, "srgb-png", {"source": "sample.dng"},
    ...                 colour_matrix=camera_to_srgb(raw.metadata))  # doctest: +SKIP
    PosixPath('out/sample.png')
    """
    if output_format not in OUTPUT_FORMATS:
        raise ValueError(f"unknown output format {output_format!r}: choose one of {', '.join(OUTPUT_FORMATS)}")
    if compression is not None and (compression != "zstd" or output_format not in TIFF_FORMATS):
        raise ValueError(f"compression {compression!r} is for {' and '.join(TIFF_FORMATS)} only (zstd)")
    rgb = _check_rgb(rgb)
    path = Path(path)
    info = dict(metadata or {})
    if output_format == "float32-tiff":
        with atomic_path(path, overwrite=overwrite) as tmp:
            tifffile.imwrite(
                tmp,
                np.ascontiguousarray(rgb, dtype=np.float32),
                photometric="rgb",
                description=json.dumps({"picamcal": info}),
                software=_SOFTWARE,
                metadata=None,
                **_tiff_compression(compression),
            )
        return path
    info.update(output_format=output_format, picamcal_version=__version__)
    if output_format == "uint16-tiff":
        info.update(encoding=f"linear: value = code / {UINT16_WHITE} (the white reference at {UINT16_WHITE})")
        info.update(scale=UINT16_WHITE)
        codes = encode_uint16(rgb)
        with atomic_path(path, overwrite=overwrite) as tmp:
            tifffile.imwrite(
                tmp,
                codes,
                imagej=True,
                software=_SOFTWARE,
                metadata={
                    "axes": "CYX",
                    "mode": "composite",
                    "Ranges": [0.0, float(UINT16_WHITE)] * 3,
                    "Labels": ["red", "green", "blue"],
                    "cf": 0,  # ImageJ's straight-line calibration: value = c0 + c1 * code
                    "c0": 0.0,
                    "c1": 1.0 / UINT16_WHITE,
                    "vunit": "white",
                    "Info": json.dumps({"picamcal": info}, indent=1),
                },
                **_tiff_compression(compression),
            )
        return path
    bits = 16 if output_format == "srgb-png16" else 8
    colour_matrix = colour_matrix if colour_matrix is not None else ColourMatrix(np.eye(3), NO_MATRIX)
    info.update(
        encoding="sRGB (IEC 61966-2-1), sRGB ICC profile embedded",
        white_level=white_level,
        white_code=int(np.rint((2**bits - 1) * srgb_transfer(np.array(min(white_level, 1.0))))),
        colour_matrix=np.round(colour_matrix.matrix, 6).tolist(),
        colour_matrix_source=colour_matrix.source,
    )
    codes = encode_srgb(rgb, colour_matrix, white_level=white_level, bits=bits)
    description = json.dumps({"picamcal": info})
    with atomic_path(path, overwrite=overwrite) as tmp:
        if output_format == "srgb-jpeg":
            _write_jpeg(tmp, codes, description)
        else:
            _write_png(tmp, codes, description)
    return path


def write_rgb_tiff(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    metadata: dict[str, Any] | None = None,
    overwrite: bool = False,
    compression: str | None = None,
) -> Path:
    """Write a float32 (H, W, 3) linear RGB image as a TIFF, with a JSON description, atomically.

    The same as :func:`write_corrected` with ``"float32-tiff"``. ``compression="zstd"`` compresses
    losslessly with the floating-point predictor (needs imagecodecs).

    Examples
    --------
    >>> write_rgb_tiff("out/sample.tiff", rgb, {"mode": "centre"})  # doctest: +SKIP
    """
    return write_corrected(path, rgb, "float32-tiff", metadata, overwrite=overwrite, compression=compression)


def _check_rgb(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"a corrected image is (H, W, 3), not {rgb.shape}")
    return rgb


def _strips(shape: tuple[int, ...]) -> list[slice]:
    step = max(1, _STRIP_PIXELS // max(1, shape[1]))
    return [slice(y, y + step) for y in range(0, shape[0], step)]


def _tiff_compression(compression: str | None) -> dict[str, Any]:
    return {"compression": compression, "predictor": True} if compression else {}


def _srgb_profile() -> bytes:
    """LittleCMS's built-in sRGB profile (through Pillow), with a fixed creation date.

    LittleCMS stamps the profile with the time it was made; a fixed one keeps the outputs the same bytes in
    every worker and run (the profile has no ID checksum over the header: its ID field is zero).
    """
    from PIL import ImageCms

    profile = bytearray(ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes())
    profile[24:36] = _ICC_DATE
    return bytes(profile)


def _write_jpeg(path: Path, codes: np.ndarray, description: str) -> None:
    from PIL import Image

    exif = Image.Exif()
    exif[0x010E] = description  # ImageDescription (ASCII: json.dumps escapes everything else)
    exif[0x0131] = _SOFTWARE  # Software
    # The tags EXIF 2.32 requires in a JPEG's IFD0 (exiftool -validate): 72 dpi, centred chroma samples.
    exif.update({0x011A: 72.0, 0x011B: 72.0, 0x0128: 2, 0x0213: 1})
    Image.fromarray(codes).save(
        path, "JPEG", quality=JPEG_QUALITY, subsampling=0, icc_profile=_srgb_profile(), exif=exif.tobytes()
    )


def _write_png(path: Path, codes: np.ndarray, description: str) -> None:
    """8-bit PNG through Pillow (adaptive row filters: smaller files); 16-bit through pypng (Pillow cannot).

    Either way the metadata chunks are added here, after IHDR: ``iCCP`` (the sRGB profile; a PNG with an
    iCCP has no sRGB chunk), ``iTXt picamcal`` (the JSON) and ``tEXt Software``.
    """
    import png

    height, width = codes.shape[:2]
    encoded = io.BytesIO()
    if codes.dtype == np.uint8:
        from PIL import Image

        Image.fromarray(codes).save(encoded, "PNG", compress_level=_PNG_ZLIB_LEVEL)
    else:
        writer = png.Writer(width, height, greyscale=False, bitdepth=16, compression=_PNG_ZLIB_LEVEL)
        writer.write(encoded, codes.reshape(height, width * 3))
    chunks = list(png.Reader(bytes=encoded.getvalue()).chunks())
    extra = [
        (b"iCCP", b"sRGB\x00\x00" + zlib.compress(_srgb_profile())),
        (b"iTXt", b"picamcal\x00\x00\x00\x00\x00" + description.encode("utf-8")),
        (b"tEXt", b"Software\x00" + _SOFTWARE.encode("latin-1")),
    ]
    with open(path, "wb") as file:
        png.write_chunks(file, [chunks[0], *extra, *chunks[1:]])


__all__ = [
    "JPEG_QUALITY",
    "NO_MATRIX",
    "OUTPUT_FORMATS",
    "OUTPUT_SUFFIXES",
    "SRGB_FORMATS",
    "SRGB_TO_XYZ_D65",
    "SRGB_WHITE_LEVEL",
    "TIFF_FORMATS",
    "UINT16_WHITE",
    "XYZ_D50_TO_SRGB",
    "ColourMatrix",
    "camera_to_srgb",
    "color_matrix_to_srgb",
    "encode_srgb",
    "encode_uint16",
    "forward_matrix_to_srgb",
    "output_bytes",
    "srgb_transfer",
    "write_corrected",
    "write_rgb_tiff",
]


def is_picamcal_output(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is an image picamcal wrote (its Software field names picamcal): one ``overwrite`` may replace.

    Examples
    --------
    >>> is_picamcal_output("corrected/target.tiff")  # doctest: +SKIP
    True
    """
    path = Path(path)
    with open(path, "rb") as f:
        head = f.read(8)
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        with tifffile.TiffFile(path) as tif:
            tag = tif.pages.first.tags.get(305)  # Software
            return tag is not None and str(tag.value).startswith("picamcal")
    from PIL import Image

    with Image.open(path) as image:
        software = image.info.get("Software") or image.getexif().get(0x0131) or ""
    return str(software).startswith("picamcal")
