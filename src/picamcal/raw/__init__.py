"""Raw image formats behind one function, :func:`read_raw`.

Each format lives in its own module or package (``dng``, ``brcm``, ``picamera2``, ``headless``, ``npz``), its
signature recognition included; nothing outside it knows its byte layout. ``model`` holds the :class:`RawImage`
they all return and the checks they share, ``packing`` the CSI-2 bit packing, ``npy`` the careful reading of file
heads and ``.npy`` arrays, ``verify`` the checks of what a file declares against its data.
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from collections.abc import Sequence
from pathlib import Path

from ..errors import PicamcalError, PicamcalWarning, RawFormatError
from ..sensors import SENSORS, given_sensor, sensors_of_size, size_note
from .brcm import is_brcm, is_jpeg, read_brcm, write_brcm
from .dng import (
    GainMap,
    flat_field_gain_map,
    is_dng,
    read_dng,
    read_gain_map,
    with_sensor_black_level,
    write_dng,
    write_linear_dng,
)
from .headless import HEADLESS_SUFFIXES, headless_hint, read_headless
from .model import PATTERNS, RawImage, given_black_level, require_colour_sensor, sensor_black_level, site_channels
from .npy import file_head, is_npy
from .npz import is_npz, read_npz, write_npz
from .picamera2 import from_picamera2, read_picamera2_npy, to_picamera2, write_picamera2_npy
from .verify import check_metadata

#: File suffixes of the raw formats a folder is searched for (``read_raw`` tells them apart by content; a ``.raw`` or
#: ``.bin`` headless dump needs its sensor and size given, so folders of raw images do not include them).
RAW_SUFFIXES = (".dng", ".jpg", ".jpeg", ".npy", ".npz")
#: Processed (ISP output) images: :func:`picamcal.raw.processed.read_processed`.
PROCESSED_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")

__all__ = [
    "HEADLESS_SUFFIXES",
    "PATTERNS",
    "PROCESSED_SUFFIXES",
    "RAW_SUFFIXES",
    "GainMap",
    "RawImage",
    "check_metadata",
    "flat_field_gain_map",
    "from_picamera2",
    "is_jpeg",
    "is_npy",
    "override",
    "read_brcm",
    "read_dng",
    "read_gain_map",
    "read_headless",
    "read_npz",
    "read_picamera2_npy",
    "read_raw",
    "site_channels",
    "to_picamera2",
    "write_brcm",
    "write_dng",
    "write_linear_dng",
    "write_npz",
    "write_picamera2_npy",
]

_SIGNATURES = {
    b"\x89PNG": "a PNG image",
    b"GIF8": "a GIF image",
    b"%PDF": "a PDF document",
}


def read_raw(
    path: str | os.PathLike[str],
    *,
    pattern: str | None = None,
    black_level: float | Sequence[float] | None = None,
    raw_format: str | None = None,
    size: tuple[int, int] | None = None,
    stride: int | None = None,
    frame: int | None = None,
    sensor: str | None = None,
    verify: bool = True,
    expected_shape: tuple[int, int] | None = None,
) -> RawImage:
    """Read a raw Bayer image from a file, whatever its format.

    The format is recognised from the file's first bytes, not its name. Supported: DNG (read by
    LibRaw through rawpy), the legacy firmware's JPEG with a BRCM raw block, picamera2 raw buffers
    saved as ``.npy`` with a JSON sidecar, and picamcal's own raw ``.npz`` (docs/formats.md). With
    ``raw_format`` the file is read as a headless dump (``rpicam-raw -o``, :func:`read_headless`)
    whatever its bytes.

    The size a file's header declares (or ``size``, for a headless dump) is checked before anything of that size
    is read: against ``expected_shape`` when given, and against the pixel limit
    (:func:`picamcal.limits.check_size`, ``PICAMCAL_MAX_PIXELS``).

    What the file declares is checked against its data (:func:`picamcal.raw.verify.check_metadata`):
    a Bayer order whose greens sit on the wrong diagonal, or a missing black level, gives a
    ``PicamcalWarning`` saying what to override.

    Parameters
    ----------
    path : path-like
        The raw file.
    pattern : str, optional
        Override the file's Bayer order (``RGGB``, ``GBRG``, ``BGGR``, ``GRBG``).
    black_level : float or 4 floats, optional
        Override the file's black level (DN; one value, or one per 2x2 site row-major; finite, >= 0 and below the
        white level).
    raw_format : str, optional
        Read the file as a headless raw dump (``rpicam-raw``, ``libcamera-raw``) in this libcamera format
        (``SBGGR10_CSI2P``, ``SRGGB12_CSI2P``, ``SGBRG16``, ``BGGR_PISP_COMP1``, ...; case-insensitive); needs
        ``size``. Greyscale formats (``R10_CSI2P``, ...) are refused.
    size : (width, height), optional
        With ``raw_format``: the frame size in pixels.
    stride : int, optional
        With ``raw_format``: bytes per row. By default libcamera's: the row's bytes rounded up to 32 on a Pi 4
        (Unicam), to 64 on a Pi 5 (PiSP); the format's own Pi's first, then the other's, then no padding, the
        first that divides the file into whole frames (:mod:`picamcal.raw.headless` cites the sources).
    frame : int, optional
        With ``raw_format``: which frame of a dump of several frames (default 0, the first);
        ``metadata["frames"]`` gives how many there are.
    sensor : str, optional
        The sensor, for files that do not say (picamera2's DNGs, a headless dump, a picamera2 buffer without a
        model), checked by :func:`picamcal.sensors.given_sensor` (a near miss of a registry name is refused): a
        registry sensor gives the black level when the file has none; another name is kept as given, with
        ``metadata["sensor_known"]`` false. A file that names its sensor keeps its own. Without it, a file that
        does not name its sensor is taken as the one registry sensor of its frame size
        (:func:`picamcal.sensors.sensors_of_size`), with a ``PicamcalWarning`` saying so and
        ``metadata["sensor_source"]`` ``"size"``; a size several sensors share is not guessed: the warning lists
        them, and so does ``metadata["sensor_candidates"]``.
    verify : bool
        Check the declared metadata against the data and warn.
    expected_shape : (height, width), optional
        The Bayer size the caller needs (a calibration's): a file declaring another size raises
        ``CalibrationFileError`` before its pixels are read.

    Returns
    -------
    RawImage
        The mosaic with its pattern, black and white levels, sensor and metadata
        (``metadata["format"]`` names the format). The black level is NaN when nothing gives it (a headless
        dump of an unknown sensor without ``black_level``): :func:`picamcal.raw.model.require_black_level`
        raises where one is needed, naming the three ways to give it.

    Raises
    ------
    RawFormatError
        The file is missing, not a regular file, unreadable, empty, not a raw image, corrupt, or declares a size
        over the pixel limit; an override is malformed (a black level that is NaN, negative or not below the white
        level); for a headless dump, see :func:`read_headless`.
    CalibrationFileError
        The file's size is not ``expected_shape``.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> _ = write_dng("white.dng", white)
    >>> raw = read_raw("white.dng")
    >>> raw.bayer.shape, raw.pattern, raw.metadata["format"]
    ((240, 320), 'BGGR', 'dng')

    The same frame as a headless dump (rpicam-raw's bytes, nothing else) of a sensor it is not told:

    >>> _ = Path("video.raw").write_bytes(to_picamera2(white)[0].tobytes())
    >>> dump = read_raw("video.raw", raw_format="SBGGR10_CSI2P", size=(320, 240))
    >>> dump.metadata["frames"], dump.sensor, dump.black_level[0]
    (1, None, nan)
    """
    path = Path(path)
    if sensor is not None:
        try:
            sensor = given_sensor(sensor, warn=False)  # the command line warned once of a sensor outside the registry
        except PicamcalError as exc:
            raise RawFormatError(exc.problem, path) from None
    if raw_format is not None:
        raw = read_headless(
            path,
            raw_format,
            size,
            stride=stride,
            frame=frame,
            sensor=sensor,
            black_level=black_level,
            expected_shape=expected_shape,
        )
        if pattern is not None:
            raw = override(raw, pattern=pattern)
    else:
        if size is not None or stride is not None or frame is not None:
            raise RawFormatError("a size, stride or frame describes a headless dump: give its raw format too", path)
        try:
            raw = _read_by_signature(path, file_head(path), expected_shape)
        except RawFormatError as exc:
            if exc.path is not None:
                raise
            raise RawFormatError(exc.problem, path) from None  # a check deep in a reader that did not name the file
        if sensor is not None and raw.sensor is None:
            raw = _with_sensor(raw, sensor)
        if pattern is not None or black_level is not None:
            raw = override(raw, pattern=pattern, black_level=black_level)
    if raw.sensor is None:
        raw = _by_size(raw)
    raw = with_sensor_black_level(raw)  # a DNG without a BlackLevel tag, of a known sensor: the sensor's, said
    if verify:
        for problem in check_metadata(raw):
            warnings.warn(f"{path}: {problem}", PicamcalWarning, stacklevel=2)
    return raw


def _with_sensor(raw: RawImage, sensor: str) -> RawImage:
    """``raw`` with the sensor its file does not name, and that sensor's black level if the file has none."""
    name = sensor if sensor in SENSORS else None
    require_colour_sensor(name, raw.source)
    meta = {**raw.metadata, "sensor_known": name is not None}
    black = raw.black_level
    if name is not None and not all(math.isfinite(b) for b in black):
        black, meta["black_level_source"] = sensor_black_level(name, raw.bit_depth)
    return dataclasses.replace(raw, sensor=name or sensor, black_level=black, metadata=meta)


def _by_size(raw: RawImage) -> RawImage:
    """``raw``, which names no sensor, as the one registry sensor of its size (said in a warning); for a size several
    sensors share, with them in ``metadata["sensor_candidates"]`` and the warning asking for ``--sensor``.

    The warning does not name the file: every frame of a folder or a batch gives the same one, shown once.
    """
    names = sensors_of_size(raw.width, raw.height, raw.bit_depth)
    if names:
        warnings.warn(size_note(names, raw.width, raw.height), PicamcalWarning, stacklevel=3)
    if len(names) == 1:
        raw = _with_sensor(raw, names[0])
        raw.metadata["sensor_source"] = "size"
    elif names:
        raw = dataclasses.replace(raw, metadata={**raw.metadata, "sensor_candidates": list(names)})
    return raw


def _read_by_signature(path: Path, head: bytes, expected_shape: tuple[int, int] | None) -> RawImage:
    if is_dng(head):
        return read_dng(path, expected_shape=expected_shape)
    if is_brcm(head):
        return read_brcm(path, expected_shape=expected_shape)
    if is_npz(head):
        return read_npz(path, expected_shape=expected_shape)
    if is_npy(head):
        return read_picamera2_npy(path, expected_shape=expected_shape)
    for signature, what in _SIGNATURES.items():
        if head.startswith(signature):
            from .processed import NOT_RAW  # only here: the readers of processed images are not needed to read raw

            raise RawFormatError(f"{what}, {NOT_RAW}", path)
    raise RawFormatError(
        "not a raw image format picamcal reads (DNG, JPEG+raw, picamera2 .npy or picamcal .npz)" + headless_hint(path),
        path,
    )


def override(
    raw: RawImage, *, pattern: str | None = None, black_level: float | Sequence[float] | None = None
) -> RawImage:
    """A copy of ``raw`` with its Bayer order or black level replaced; the declared values stay in the metadata.

    The black level must be 1 or 4 finite numbers >= 0 below the white level (:func:`given_black_level`): an
    unknown level is NaN inside a RawImage, but a NaN given here would make every corrected pixel NaN.

    Examples
    --------
    >>> raw = RawImage(np.full((4, 4), 100, np.uint16), "GBRG", 0, 1023, 10, "imx219")
    >>> fixed = override(raw, pattern="BGGR", black_level=64)
    >>> fixed.pattern, fixed.black_level, fixed.metadata
    ('BGGR', (64.0, 64.0, 64.0, 64.0), {'declared_pattern': 'GBRG', 'declared_black_level': [0.0, 0.0, 0.0, 0.0]})
    """
    meta = dict(raw.metadata)
    if pattern is not None and pattern != raw.pattern:
        meta["declared_pattern"] = raw.pattern
    if black_level is not None:
        black_level = given_black_level(black_level, raw.source)
        if max(black_level) >= raw.white_level:
            raise RawFormatError(
                f"--black-level {max(black_level):g} is not below the white level {raw.white_level}", raw.source
            )
        meta["declared_black_level"] = list(raw.black_level)
    try:
        return RawImage(
            raw.bayer,
            pattern if pattern is not None else raw.pattern,
            raw.black_level if black_level is None else black_level,
            raw.white_level,
            raw.bit_depth,
            raw.sensor,
            meta,
        )
    except RawFormatError as exc:
        raise RawFormatError(exc.problem, raw.source) from None
