"""What picamera2 reports about a raw frame beside its bytes: the request metadata and the sensor's name."""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from ...errors import PicamcalWarning, RawFormatError, short
from ...sensors import find_sensor_name
from ..model import require_colour_sensor, sensor_black_level
from .buffer import integer

_METADATA_SCALARS = {  # libcamera control -> (RawImage metadata key, scale)
    "ExposureTime": ("exposure_time_s", 1e-6),
    "AnalogueGain": ("analogue_gain", 1.0),
    "DigitalGain": ("digital_gain", 1.0),
    "ColourTemperature": ("colour_temperature", 1.0),
    "Lux": ("lux", 1.0),
}
_METADATA_VECTORS = {"ColourGains": ("colour_gains", 2), "ColourCorrectionMatrix": ("colour_correction_matrix", 9)}
#: The sites of libcamera's ``SensorBlackLevels``, in its order: red, the greens on red's and on blue's rows, blue.
SENSOR_BLACK_LEVEL_SITES = ("R", "Gr", "Gb", "B")


def site_names(pattern: str) -> list[str]:
    """libcamera's name of each site of the 2x2 block, row-major: a green is Gr when it shares its row with red.

    Examples
    --------
    >>> site_names("BGGR"), site_names("GRBG")
    (['B', 'Gb', 'Gr', 'R'], ['Gr', 'R', 'B', 'Gb'])
    """
    return [c if c != "G" else ("Gr" if pattern[site ^ 1] == "R" else "Gb") for site, c in enumerate(pattern)]


def sensor_black_levels(metadata: Mapping[str, Any], source: str) -> list[float] | None:
    """``SensorBlackLevels`` (R, Gr, Gb, B on the 16-bit scale), checked, or None.

    Examples
    --------
    >>> sensor_black_levels({"SensorBlackLevels": (4096, 4096, 4096, 4096)}, "<picamera2>")
    [4096.0, 4096.0, 4096.0, 4096.0]
    """
    levels = metadata.get("SensorBlackLevels")
    if levels is None:
        return None
    if not isinstance(levels, (list, tuple, np.ndarray)) or len(levels) != 4:
        raise RawFormatError(f"SensorBlackLevels must be 4 numbers (R, Gr, Gb, B), not {short(levels)}", source)
    values = [_number(v, "SensorBlackLevels", source) for v in levels]
    if min(values) < 0 or max(values) > 65535:
        raise RawFormatError(f"SensorBlackLevels {short(levels)} are outside the 16-bit range", source)
    return values


def black_levels(
    levels: list[float] | None, pattern: str, bit_depth: int, sensor: str | None
) -> tuple[tuple[float, float, float, float], str]:
    """Per-site black levels at ``bit_depth`` bits, and where they came from: ``SensorBlackLevels`` (on the
    16-bit scale), else the sensor registry's, else unknown (:func:`picamcal.raw.model.sensor_black_level`).

    Examples
    --------
    >>> black_levels([4096.0, 4000.0, 4032.0, 4096.0], "BGGR", 10, None)
    ((64.0, 63.0, 62.5, 64.0), 'SensorBlackLevels')
    >>> black_levels(None, "BGGR", 10, "imx219")
    ((64.0, 64.0, 64.0, 64.0), 'registry')
    """
    if levels is None:
        return sensor_black_level(sensor, bit_depth)
    by_name = dict(zip(SENSOR_BLACK_LEVEL_SITES, levels, strict=True))
    site = [by_name[name] * 2.0 ** (bit_depth - 16) for name in site_names(pattern)]
    return (site[0], site[1], site[2], site[3]), "SensorBlackLevels"


def _number(value: Any, key: str, source: str) -> float:
    """A number of the request metadata, finite; anything else is an error naming the control."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise RawFormatError(f"metadata {key} must be numeric, not {short(value)}", source)
    try:
        number = float(value)
    except OverflowError:  # an integer beyond any float
        number = math.inf
    if not math.isfinite(number):
        raise RawFormatError(f"metadata {key} is {short(value)}, not a finite number", source)
    return number


def exposure_metadata(metadata: Mapping[str, Any], source: str) -> dict[str, Any]:
    """The request metadata picamcal keeps, under its own names and units.

    Examples
    --------
    >>> exposure_metadata({"ExposureTime": 20000, "AnalogueGain": 2.0, "FocusFoM": 7}, "<picamera2>")
    {'exposure_time_s': 0.02, 'analogue_gain': 2.0}
    """
    meta: dict[str, Any] = {}
    for control, (key, scale) in _METADATA_SCALARS.items():
        if metadata.get(control) is not None:
            value = _number(metadata[control], control, source)
            if value < 0:
                raise RawFormatError(f"metadata {control} is negative ({value})", source)
            meta[key] = value * scale
    for control, (key, length) in _METADATA_VECTORS.items():
        values = metadata.get(control)
        if values is not None:
            if not isinstance(values, (list, tuple, np.ndarray)) or len(values) != length:
                raise RawFormatError(f"metadata {control} must be {length} numbers, not {short(values)}", source)
            meta[key] = [_number(v, control, source) for v in values]
    if metadata.get("SensorTimestamp") is not None:
        meta["sensor_timestamp_ns"] = integer(metadata["SensorTimestamp"], "metadata SensorTimestamp", source)
    return meta


def resolve_sensor(
    sensor: Any, config: Mapping[str, Any], metadata: Mapping[str, Any], source: str, warn: bool = True
) -> tuple[str | None, str | None]:
    """The registry name of the sensor and the model text it was found in: ``sensor`` if given, else the
    configuration's or the metadata's ``model``; a monochrome sensor is refused.

    Examples
    --------
    >>> resolve_sensor(None, {"model": "imx708_wide"}, {}, "<picamera2>")
    ('imx708', 'imx708_wide')
    """
    if sensor is not None:
        if not isinstance(sensor, str):
            raise RawFormatError(f"sensor must be a name such as 'imx219', not {short(sensor)}", source)
        name = find_sensor_name(sensor)
        require_colour_sensor(name, source)
        if name is None and warn:
            warnings.warn(
                f"{source}: sensor {sensor!r} is not in picamcal's registry; its constants are unknown",
                PicamcalWarning,
                stacklevel=3,
            )
        return name, sensor
    for holder in (config, metadata):
        for key in ("model", "Model"):
            text = holder.get(key)
            if isinstance(text, str) and text:
                name = find_sensor_name(text)
                require_colour_sensor(name, source)
                return name, text
    return None, None


def active_area_size(properties: Mapping[str, Any]) -> Any:
    """The sensor's active area (width, height) from picamera2's ``camera_properties``: what a mode's crop and
    ``ScalerCrop`` are measured in (libcamera's ``CameraSensorRaw::sensorInfo`` subtracts its offset;
    ``control_ids_core.yaml``), ``PixelArrayActiveAreas[0]``, else ``PixelArraySize``; None when neither is given.

    Examples
    --------
    >>> active_area_size({"PixelArraySize": (3296, 2480), "PixelArrayActiveAreas": [(8, 8, 3280, 2464)]})
    (3280, 2464)
    """
    areas = properties.get("PixelArrayActiveAreas")
    return tuple(areas[0][2:]) if areas else properties.get("PixelArraySize")


def _box(value: Any, what: str, source: str) -> list[int]:
    """A libcamera ``Rectangle`` as picamera2 gives it, ``(x, y, width, height)``, checked."""
    if hasattr(value, "width") and hasattr(value, "x"):  # a libcamera Rectangle itself
        value = (value.x, value.y, value.width, value.height)
    if not isinstance(value, (list, tuple)) or len(value) != 4:
        raise RawFormatError(f"{what} must be (x, y, width, height), not {short(value)}", source)
    x, y, w, h = (integer(v, what, source, 0, 1 << 16) for v in value)
    if min(w, h) < 1:
        raise RawFormatError(f"{what} {short(value)} has no area", source)
    return [x, y, w, h]


def geometry_metadata(config: Mapping[str, Any], metadata: Mapping[str, Any], source: str) -> dict[str, Any]:
    """Where the frame lies on the sensor, as the camera says it, for ``RawImage.metadata``.

    From what :func:`picamcal.raw.picamera2.capture_raw` adds to the configuration beside picamera2's own keys:
    ``pixel_array_size`` (the active area, :func:`active_area_size`) and ``crop_limits`` (the mode's area of the
    sensor, the largest ``ScalerCrop``, as picamera2's ``sensor_modes`` give it), and the configuration's
    ``transform`` (its ``hflip`` and ``vflip``); the request's ``ScalerCrop`` (the area the processed streams show)
    is kept as ``scaler_crop``. Nothing when the configuration has no crop.

    Examples
    --------
    >>> geometry_metadata({"pixel_array_size": (3280, 2464), "crop_limits": (680, 692, 1920, 1080)}, {}, "<x>")
    {'sensor_size': [3280, 2464], 'sensor_crop': [680, 692, 1920, 1080], 'sensor_flips': [False, False], \
'geometry_source': 'camera'}
    """
    meta: dict[str, Any] = {}
    limits, array = config.get("crop_limits"), config.get("pixel_array_size")
    if limits is not None and array is not None:
        if hasattr(array, "width"):  # a libcamera Size
            array = (array.width, array.height)
        if not isinstance(array, (list, tuple)) or len(array) != 2:
            raise RawFormatError(f"the pixel array's size must be (width, height), not {short(array)}", source)
        meta["sensor_size"] = [integer(v, "the pixel array's size", source, 1, 1 << 16) for v in array]
        meta["sensor_crop"] = _box(limits, "the mode's crop limits", source)
        transform = config.get("transform")
        meta["sensor_flips"] = [bool(getattr(transform, "hflip", False)), bool(getattr(transform, "vflip", False))]
        meta["geometry_source"] = "camera"
    if metadata.get("ScalerCrop") is not None:
        meta["scaler_crop"] = _box(metadata["ScalerCrop"], "ScalerCrop", source)
    return meta
