"""The raw image model shared by every format reader and writer, and the checks they share."""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import PicamcalError, RawFormatError
from ..geometry import (
    GEOMETRY_SOURCES,
    SensorMode,
    full_field_binning,
    mode_from_crop,
    named_mode,
    registry_mode,
)
from ..sensors import SENSORS, black_level_at, get_sensor, or_list

PATTERNS = ("RGGB", "GBRG", "BGGR", "GRBG")
CHANNELS = "RGB"


def _finite(value: Any) -> bool:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond any float
        return False


def _positive(value: Any) -> bool:
    return _finite(value) and value > 0


def _whole_number(value: Any) -> bool:
    return _finite(value) and isinstance(value, numbers.Integral)


def _numbers_of(length: int, each: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda value: isinstance(value, (list, tuple)) and len(value) == length and all(each(v) for v in value)


#: What picamcal's readers put under each ``RawImage.metadata`` key that code downstream uses, as (what it is,
#: test): the DNG reader checks picamcal's recorded JSON against it, the DNG writer the values it writes as tags.
METADATA_KINDS: dict[str, tuple[str, Callable[[Any], bool]]] = {
    "sensor": ("a sensor name", lambda v: isinstance(v, str)),
    **{key: ("text", lambda v: isinstance(v, str)) for key in ("make", "model", "timestamp")},
    **{
        key: ("a positive number", _positive)
        for key in ("exposure_time_s", "analogue_gain", "digital_gain", "colour_temperature")
    },
    "lux": ("a number of at least 0", lambda v: _finite(v) and v >= 0),
    "iso": ("a positive whole number", lambda v: _positive(v) and _whole_number(v)),
    "sensor_timestamp_ns": ("a whole number", _whole_number),
    "colour_gains": ("2 positive numbers", _numbers_of(2, _positive)),
    "colour_correction_matrix": ("9 finite numbers", _numbers_of(9, _finite)),
    "sensor_size": ("2 positive whole numbers", _numbers_of(2, lambda v: _positive(v) and _whole_number(v))),
    **{
        key: ("4 whole numbers (x, y, width, height)", _numbers_of(4, lambda v: _whole_number(v) and v >= 0))
        for key in ("sensor_crop", "scaler_crop")
    },
    "sensor_flips": (
        "2 booleans (hflip, vflip)",
        lambda v: isinstance(v, list) and len(v) == 2 and all(isinstance(b, bool) for b in v),
    ),
    "geometry_source": ("a geometry source", lambda v: v in GEOMETRY_SOURCES),
}


def site_channels(pattern: str) -> np.ndarray:
    """Channel index (0 R, 1 G, 2 B) of each site of the 2x2 Bayer block, row-major.

    Examples
    --------
    >>> site_channels("BGGR").tolist()
    [2, 1, 1, 0]
    """
    if not isinstance(pattern, str) or pattern not in PATTERNS:
        raise RawFormatError(f"unknown Bayer pattern {pattern!r:.40} (expected one of {', '.join(PATTERNS)})")
    return np.array([CHANNELS.index(c) for c in pattern], dtype=np.intp)


def require_black_level(raw: RawImage, dark_frame: str | None = None) -> None:
    """Raise if ``raw``'s black level is unknown (NaN): the file records none and its sensor is not known.

    Never take 0 silently: a wrong black level skews every ratio the calibration measures. The message says what
    can give it, in options every command that reads raw files has: a sensor outside the registry (``--sensor
    imx298``) has no known level, so only ``--black-level``; a frame whose size several registry sensors share names
    them. ``dark_frame`` is how the caller takes a dark frame, where it takes one (calibrate: ``"--black FILE"``);
    it is named too.

    Examples
    --------
    >>> require_black_level(RawImage(np.zeros((2, 2), np.uint16), "RGGB", 64, 1023, 10))
    >>> require_black_level(RawImage(np.zeros((2, 2), np.uint16), "RGGB", float("nan"), 1023, 10, "imx298"))
    Traceback (most recent call last):
    ...
    picamcal.errors.RawFormatError: <array>: no black level: ... a sensor outside its registry; give --black-level N
    """
    if np.all(np.isfinite(raw.black_level)):
        return
    candidates = raw.metadata.get("sensor_candidates")
    dark = [f"a dark frame ({dark_frame})"] if dark_frame else []
    if raw.sensor is not None and raw.sensor not in SENSORS:
        problem = (
            f"no black level: the file records none, and picamcal does not know the black level of the {raw.sensor}, "
            f"a sensor outside its registry; give {or_list(['--black-level N', *dark])}"
        )
    elif raw.sensor is None and candidates:
        problem = (
            f"no black level: the file records none, and a {raw.width}x{raw.height} frame could be from the "
            f"{or_list(candidates)}; give {or_list(['--sensor NAME (one of them)', '--black-level N', *dark])}"
        )
    else:
        problem = (
            "no black level: the file records none and its sensor is not in picamcal's registry; give "
            f"{or_list(['--black-level N', '--sensor NAME', *dark])}"
        )
    raise RawFormatError(problem, raw.source)


@dataclass
class RawImage:
    """A raw Bayer mosaic with what is needed to interpret it.

    Attributes
    ----------
    bayer : ndarray of uint16, shape (H, W)
        The mosaic at native bit depth (not scaled to 16 bits).
    pattern : str
        Colours of the top-left 2x2 block read row-wise: ``"RGGB"``, ``"GBRG"``, ``"BGGR"`` or ``"GRBG"``.
    black_level : tuple of 4 float
        Black level in DN of each site of the 2x2 block, row-major; NaN where unknown (a headless dump of a
        sensor picamcal does not know, with no level given): see :func:`require_black_level`.
    white_level : int
        Saturation value in DN.
    bit_depth : int
        Bits per pixel of the sensor's output.
    sensor : str or None
        Sensor name from the registry, when the file says, or the one registry sensor of the frame's size
        (``metadata["sensor_source"]`` is then ``"size"``; a size several share puts them in
        ``metadata["sensor_candidates"]``); a sensor the user names that the registry does not hold, as given.
    metadata : dict
        Exposure, gains and whatever else the file records; ``metadata["format"]`` names the format read.
    """

    bayer: np.ndarray
    pattern: str
    black_level: tuple[float, float, float, float]
    white_level: int
    bit_depth: int
    sensor: str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        try:
            bayer = np.asarray(self.bayer)
        except (TypeError, ValueError) as exc:
            raise RawFormatError(f"a Bayer mosaic must be a 2-D uint16 array ({exc})") from None
        if bayer.ndim != 2 or bayer.shape[0] < 2 or bayer.shape[1] < 2:
            raise RawFormatError(f"a Bayer mosaic must be a 2-D array, got shape {bayer.shape}")
        if bayer.shape[0] % 2 or bayer.shape[1] % 2:
            raise RawFormatError(f"a Bayer mosaic needs even width and height, got {bayer.shape[1]}x{bayer.shape[0]}")
        if bayer.dtype != np.uint16:
            raise RawFormatError(f"a Bayer mosaic must be uint16, got {bayer.dtype}")
        site_channels(self.pattern)
        bit_depth = _whole(self.bit_depth, "bit_depth", 1, 16)
        white = _whole(self.white_level, "white_level", 1, (1 << bit_depth) - 1)
        black = _black_levels(self.black_level, "black_level")
        if not (all(math.isfinite(b) for b in black) or all(math.isnan(b) for b in black)):
            raise RawFormatError(f"black_level {_text(black)} is part unknown (NaN): give all four or none")
        if max(black) >= white:  # False for an unknown (NaN) level
            raise RawFormatError(f"black_level {_text(black)} is not below the white level {white}")
        if self.sensor is not None and not isinstance(self.sensor, str):
            raise RawFormatError(f"sensor must be a name or None, not {self.sensor!r:.60}")
        if not isinstance(self.metadata, dict):
            raise RawFormatError(f"metadata must be a dict, not {type(self.metadata).__name__}")
        self.bayer = bayer
        self.black_level = black
        self.white_level = white
        self.bit_depth = bit_depth

    @property
    def height(self) -> int:
        """Mosaic height in pixels."""
        return int(self.bayer.shape[0])

    @property
    def width(self) -> int:
        """Mosaic width in pixels."""
        return int(self.bayer.shape[1])

    @property
    def source(self) -> str:
        """Where the image came from (its path, or a description), for messages."""
        return str(self.metadata.get("path", "<array>"))

    def black_subtracted(self) -> np.ndarray:
        """The mosaic as float32 with each site's black level subtracted (may go negative with noise)."""
        out = self.bayer.astype(np.float32)
        for k, level in enumerate(self.black_level):
            out[k // 2 :: 2, k % 2 :: 2] -= np.float32(level)
        return out


def sensor_black_level(sensor: str | None, bit_depth: int) -> tuple[tuple[float, float, float, float], str]:
    """The black level of each 2x2 site for a file that records none, and where it came from.

    A registry sensor's level at ``bit_depth`` bits (``"registry"``), else unknown: NaN (``"none"``), never 0;
    the error comes where a black level is needed (:func:`require_black_level`).

    Examples
    --------
    >>> sensor_black_level("imx477", 10)
    ((64.0, 64.0, 64.0, 64.0), 'registry')
    >>> sensor_black_level(None, 10)
    ((nan, nan, nan, nan), 'none')
    """
    if sensor is None:
        return (math.nan,) * 4, "none"
    return (black_level_at(get_sensor(sensor), bit_depth),) * 4, "registry"


def require_colour_sensor(name: str | None, source: str | os.PathLike[str]) -> None:
    """Raise if the registry knows ``name`` as a monochrome sensor: there is no colour to calibrate.

    Examples
    --------
    >>> require_colour_sensor("imx219", "white.raw")
    >>> require_colour_sensor("ov9281", "dark.raw")
    Traceback (most recent call last):
    ...
    picamcal.errors.RawFormatError: dark.raw: the OV9281 is a monochrome sensor: picamcal calibrates colour ...
    """
    if name is not None and get_sensor(name).monochrome:
        raise RawFormatError(
            f"the {name.upper()} is a monochrome sensor: picamcal calibrates colour Bayer sensors, and a monochrome "
            "sensor has no colour crosstalk to unmix",
            source,
        )


def given_black_level(value: Any, source: str | os.PathLike[str] | None = None) -> tuple[float, float, float, float]:
    """A black level the user gave (``--black-level``, ``black_level=``), checked: 1 or 4 finite numbers >= 0.

    An unknown level is NaN inside a :class:`RawImage`, but a NaN the user passes is a mistake: it would turn
    every corrected pixel into NaN.

    Examples
    --------
    >>> given_black_level(64)
    (64.0, 64.0, 64.0, 64.0)
    >>> given_black_level(float("nan"), "white.dng")
    Traceback (most recent call last):
    ...
    picamcal.errors.RawFormatError: white.dng: --black-level nan: a black level is 1 or 4 finite numbers >= 0 (DN)
    """
    try:
        black = _black_levels(value, "--black-level")
    except RawFormatError as exc:
        raise RawFormatError(exc.problem, source) from None
    if not all(math.isfinite(b) for b in black):
        raise RawFormatError(f"--black-level {_text(value)}: a black level is 1 or 4 finite numbers >= 0 (DN)", source)
    return black


def _black_levels(value: Any, what: str) -> tuple[float, float, float, float]:
    """1 or 4 numbers as 4 floats, each >= 0 or NaN (unknown); anything else raises."""
    if isinstance(value, (str, bytes)) or value is None:
        raise RawFormatError(f"{what} {_text(value)}: a black level is 1 or 4 finite numbers >= 0 (DN)")
    try:
        levels = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise RawFormatError(f"{what} {_text(value)}: a black level is 1 or 4 finite numbers >= 0 (DN)") from None
    if levels.size == 1:
        levels = np.repeat(levels, 4)
    if levels.size != 4 or np.isinf(levels).any() or (levels < 0).any():
        raise RawFormatError(f"{what} {_text(value)}: a black level is 1 or 4 finite numbers >= 0 (DN)")
    return float(levels[0]), float(levels[1]), float(levels[2]), float(levels[3])


def _whole(value: Any, what: str, low: int, high: int) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
        raise RawFormatError(f"{what} must be a whole number from {low} to {high}, not {_text(value)}")
    return int(value)


def _text(value: Any) -> str:
    """A value for a message: numbers as the user would write them, at most 60 characters."""
    if isinstance(value, (tuple, list)) and all(isinstance(v, (int, float)) for v in value):
        text = " ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    elif isinstance(value, float):
        text = f"{value:g}"
    else:
        text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def raw_geometry(
    raw: RawImage, *, sensor_crop: tuple[int, int, int, int] | None = None, sensor_mode: str | None = None
) -> SensorMode:
    """Where a raw frame lies on its sensor, from what says it, in this order:

    1. ``sensor_crop`` (x, y, width, height in full-sensor pixels) or ``sensor_mode`` (``"WxH[:BITS]"``, a mode of
       the registry's sensor), the user's word (``--sensor-crop``, ``--sensor-mode``);
    2. the file or the camera (``metadata["sensor_crop"]``, ``["sensor_size"]``, ``["sensor_flips"]``: picamera2
       captures and the DNGs picamcal writes of them, the simulator's frames);
    3. the registry's mode of the sensor of this size (rpicam-still and picamera2 DNGs, headless dumps: they record
       no crop), :func:`picamcal.geometry.registry_mode`;
    4. the whole sensor, binned to the frame's size; else (an unknown sensor, or a size no mode of it gives) a
       sensor of the frame's own size (``source`` ``"assumed"``: whatever uses it across modes asks for
       ``--sensor-crop``).

    Raises
    ------
    RawFormatError
        A crop outside the sensor or that cannot give the frame's size, or a mode the sensor does not have (the
        message lists its modes) or of another size than the frame.

    Examples
    --------
    >>> raw = RawImage(np.zeros((1080, 1920), np.uint16), "BGGR", (64,) * 4, 1023, 10, "imx219")
    >>> print(raw_geometry(raw).describe())
    1920x1080: the 1920x1080 area at (680, 692) of the 3280x2464 sensor, 10 bits (registry)
    >>> raw_geometry(raw, sensor_crop=(0, 0, 3840, 2160))
    Traceback (most recent call last):
    ...
    picamcal.errors.RawFormatError: <array>: --sensor-crop 0,0,3840,2160 lies outside the 3280x2464 sensor
    """
    size = (raw.width, raw.height)
    recorded = raw.metadata.get("sensor_size")
    entry = SENSORS.get(raw.sensor or "")
    sensor_size = (int(recorded[0]), int(recorded[1])) if recorded else (entry.size if entry else None)
    try:
        if sensor_crop is not None:
            if sensor_size is None:
                raise PicamcalError(
                    "--sensor-crop needs the sensor's full size, which this frame's unknown sensor does not give: "
                    "name it with --sensor"
                )
            return replace(mode_from_crop(sensor_size, size, sensor_crop), bit_depth=raw.bit_depth)
        if sensor_mode is not None:
            mode = named_mode(raw.sensor, sensor_mode)
            if (mode.width, mode.height) != size:
                raise PicamcalError(
                    f"--sensor-mode {sensor_mode}: the frame is {size[0]}x{size[1]}, "
                    f"the mode {mode.width}x{mode.height}"
                )
            return mode
    except PicamcalError as exc:
        raise RawFormatError(exc.problem, raw.source) from None
    crop = raw.metadata.get("sensor_crop")
    if crop and sensor_size:
        hflip, vflip = raw.metadata.get("sensor_flips") or (False, False)
        source = raw.metadata.get("geometry_source", "file")
        try:
            mode = mode_from_crop(sensor_size, size, tuple(crop), what="the recorded sensor crop")
        except PicamcalError as exc:
            raise RawFormatError(exc.problem, raw.source) from None
        return replace(mode, hflip=bool(hflip), vflip=bool(vflip), bit_depth=raw.bit_depth, source=source)
    registered = None if recorded else registry_mode(raw.sensor, *size, raw.bit_depth)
    if registered is not None:
        return registered
    binning = full_field_binning(sensor_size, size) if sensor_size else None
    if sensor_size is None or binning is None:  # a frame no known mode gives: a sensor of its own size
        return SensorMode.full(*size, bit_depth=raw.bit_depth)
    return SensorMode.full(*sensor_size, binning=binning, bit_depth=raw.bit_depth, output=size)
