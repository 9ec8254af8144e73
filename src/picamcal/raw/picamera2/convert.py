"""Between picamera2's raw buffer, stream configuration and request metadata and a :class:`RawImage`, both ways."""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from ...errors import PicamcalWarning, RawFormatError
from ...sensors import get_sensor, sensor_modes, sensors_of_size, size_note
from ..model import RawImage
from ..packing import pack
from .buffer import Layout, check_layout, decode
from .formats import UNICAM_ALIGN, RawFormat
from .metadata import (
    SENSOR_BLACK_LEVEL_SITES,
    active_area_size,
    black_levels,
    exposure_metadata,
    geometry_metadata,
    resolve_sensor,
    sensor_black_levels,
    site_names,
)


def from_picamera2(
    array: np.ndarray | bytes,
    config: Mapping[str, Any],
    metadata: Mapping[str, Any] | None = None,
    *,
    sensor: str | None = None,
    source: str | os.PathLike[str] = "<picamera2>",
    by_size: bool = True,
) -> RawImage:
    """Make a RawImage from a picamera2 raw buffer, its stream configuration and its request metadata.

    Parameters
    ----------
    array : ndarray of uint8, shape (height, stride)
        What ``Picamera2.capture_array("raw")`` returns; a uint16 ``(height, stride / 2)`` view of it and the flat
        buffer of ``capture_buffer("raw")`` are accepted too. It is never modified nor shared with the result.
    config : mapping
        The raw stream configuration, ``picam2.camera_configuration()["raw"]``
        (``{"format": "SBGGR10_CSI2P", "size": (width, height), "stride": ..., "framesize": ...}``), or the whole
        camera configuration with ``"raw"`` and ``"sensor"`` (``{"bit_depth": 10, ...}``) keys. A ``"model"`` key
        (picamera2's ``camera_properties["Model"]``, e.g. ``"imx708_wide"``) names the sensor; ``"crop_limits"``
        and ``"pixel_array_size"`` place the mode on the sensor (``geometry_metadata``).
    metadata : mapping, optional
        The request metadata (``request.get_metadata()``). ``SensorBlackLevels`` (R, Gr, Gb, B on a 16-bit
        scale, 4096 = 64 at 10 bits) gives the black level of each 2x2 site; ``ExposureTime`` (µs),
        ``AnalogueGain``, ``DigitalGain``, ``ColourGains``, ``ColourCorrectionMatrix``, ``ColourTemperature``,
        ``Lux`` and ``SensorTimestamp`` are kept as ``exposure_time_s``, ``analogue_gain``, ... in
        ``RawImage.metadata``.
    sensor : str, optional
        Sensor name; by default found in ``config["model"]``, else, with ``by_size``, the registry's one sensor of
        the frame's size (with a ``PicamcalWarning``, as :func:`picamcal.read_raw` takes a file's). The sensor's bit
        depth (``config["sensor"]["bit_depth"]``, else that of the registry sensor's mode of this size) is that of
        the data in a 16-bit buffer.
    source : str or path-like
        What to call the data in messages and ``metadata["path"]``.
    by_size : bool
        Whether a buffer that names no sensor is taken as the one registry sensor of its size (the headless reader,
        which says what its dump is itself, decodes without).

    Returns
    -------
    RawImage
        The mosaic at the sensor's bit depth, its pattern (from the format string, flips included), per-site black
        levels (``SensorBlackLevels``, else the sensor registry's, else NaN: unknown, an error where a black level
        is needed) and white level.

    Raises
    ------
    RawFormatError
        One line naming ``source`` for an unknown format, a stride too short for the width, an array smaller than
        the configuration says, inconsistent sizes, or malformed metadata.

    Notes
    -----
    ``<order>_PISP_COMP1``, the Pi 5's default raw format, is lossy (errors up to 256 on the 16-bit scale, 4 DN
    at 10 bits) and not for calibration: configure an unpacked raw format (``raw={"format": "SBGGR16"}`` on a Pi 5)
    instead. It is decoded anyway, with a :class:`PicamcalWarning` (:mod:`picamcal.raw.picamera2.pisp` describes
    the decoding). The decoded values are on a 16-bit
    scale; with ``config["sensor"]["bit_depth"]`` = b they are returned at b bits as
    ``min(2**b - 1, (v + 2**(15 - b)) >> (16 - b))`` (rounded to the nearest DN), else as 16-bit values.

    Examples
    --------
    >>> import numpy as np
    >>> buffer = np.zeros((2, 32), np.uint8)  # 2 rows of 4 RAW10 pixels, stride padded to 32 bytes
    >>> buffer[:, :5] = [0xFF, 0x00, 0x80, 0x01, 0b11_10_01_00]
    >>> config = {"format": "SBGGR10_CSI2P", "size": (4, 2), "stride": 32, "framesize": 64}
    >>> raw = from_picamera2(buffer, config, {"SensorBlackLevels": (4096, 4096, 4096, 4096)})
    >>> raw.bayer[0].tolist(), raw.pattern, raw.black_level, raw.white_level
    ([1020, 1, 514, 7], 'BGGR', (64.0, 64.0, 64.0, 64.0), 1023)
    """
    source = str(source)
    layout = check_layout(array, config, source)
    if metadata is None:
        metadata = {}
    if not isinstance(metadata, Mapping):
        raise RawFormatError(f"request metadata must be a dict, not {type(metadata).__name__}", source)
    name, model = resolve_sensor(sensor, config, metadata, source)
    meta: dict[str, Any] = {"format": "picamera2", "path": source, "raw_format": layout.name, "stride": layout.stride}
    if model is not None:
        meta["model"] = model
    if name is None and model is None and by_size:  # nothing names it: the registry's one sensor of this size
        name = _sensor_by_size(layout, meta)
    if name is not None and layout.sensor_bits is None and layout.bits == 16:
        layout = dataclasses.replace(layout, sensor_bits=_mode_bits(name, layout.width, layout.height))
    if layout.sensor_bits is not None:
        meta["sensor_bit_depth"] = layout.sensor_bits
    if layout.packing == "pisp":
        meta["lossy_compression"] = "PISP_COMP1"
    meta.update(exposure_metadata(metadata, source))
    meta.update(geometry_metadata(config, metadata, source))
    levels = sensor_black_levels(metadata, source)
    bayer, bit_depth, white = decode(layout, source)
    black, meta["black_level_source"] = black_levels(levels, layout.pattern, bit_depth, name)
    try:
        return RawImage(bayer, layout.pattern, black, white, bit_depth, name, meta)
    except RawFormatError as exc:
        raise RawFormatError(exc.problem, source) from None


def _sensor_by_size(layout: Layout, meta: dict[str, Any]) -> str | None:
    """The registry sensor a buffer of this size and format comes from when only one does, said in the warning
    :func:`picamcal.read_raw` gives of a file (which lists the candidates of a size several sensors share). The bits
    of an unpacked 16-bit or PiSP buffer say nothing of the sensor's."""
    names = sensors_of_size(layout.width, layout.height, layout.sensor_bits or layout.bits)
    if len(names) != 1:
        return None
    warnings.warn(size_note(names, layout.width, layout.height), PicamcalWarning, stacklevel=3)
    meta["sensor_source"] = "size"
    return names[0]


def _mode_bits(name: str, width: int, height: int) -> int:
    """The bit depth of a registry sensor's deepest mode of this size (its deepest mode if none is), that of the
    data in a 16-bit buffer (the Pi 5's ``S<order>16``, PiSP) whose configuration does not give the sensor's."""
    depths = [mode.bit_depth for mode in sensor_modes(name) if (mode.width, mode.height) == (width, height)]
    return max(depths, default=get_sensor(name).bit_depth)


def to_picamera2(raw: RawImage, *, packed: bool = True, align: int = UNICAM_ALIGN) -> tuple[np.ndarray, dict, dict]:
    """The buffer, configuration and metadata picamera2 would give for ``raw``: the inverse of :func:`from_picamera2`.

    Packed ``S<order><bits>_CSI2P`` for 10 and 12 bits (unpacked ``S<order><bits>`` otherwise: one byte per pixel
    at 8 bits, else little-endian uint16), rows padded to ``align`` bytes (32 on a Pi 4, 64 on a Pi 5),
    ``SensorBlackLevels`` on the 16-bit scale (left out when the black level is unknown).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> raw = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> array, config, metadata = to_picamera2(raw)
    >>> array.shape, config["raw"]["format"], metadata["SensorBlackLevels"]
    ((240, 416), 'SBGGR10_CSI2P', [4096, 4096, 4096, 4096])
    >>> bool(np.array_equal(from_picamera2(array, config, metadata).bayer, raw.bayer))
    True
    """
    bits = raw.bit_depth
    packed = packed and bits in (10, 12)
    name = f"S{raw.pattern}{bits}{'_CSI2P' if packed else ''}"
    row_bytes = RawFormat(name, raw.pattern, "csi2p" if packed else "unpacked", bits).row_bytes(raw.width)
    stride = -(-row_bytes // align) * align
    if packed:
        array = pack(raw.bayer, bits, stride)
    else:
        array = np.zeros((raw.height, stride), dtype=np.uint8)
        samples = raw.bayer.astype(np.uint8) if bits == 8 else raw.bayer.astype("<u2").view(np.uint8)
        array[:, :row_bytes] = samples.reshape(raw.height, -1)
    by_name = dict(zip(site_names(raw.pattern), raw.black_level, strict=True))
    scale = 2.0 ** (16 - bits)
    config = {
        "raw": {
            "format": name,
            "size": (raw.width, raw.height),
            "stride": stride,
            "framesize": stride * raw.height,
        },
        "sensor": {"bit_depth": bits, "output_size": (raw.width, raw.height)},
        "model": raw.sensor,
    }
    metadata: dict[str, Any] = {}
    if all(math.isfinite(b) for b in raw.black_level):  # an unknown (NaN) black level stays unknown
        metadata["SensorBlackLevels"] = [round(by_name[site] * scale) for site in SENSOR_BLACK_LEVEL_SITES]
    if raw.metadata.get("exposure_time_s"):
        metadata["ExposureTime"] = round(1e6 * float(raw.metadata["exposure_time_s"]))
    if raw.metadata.get("analogue_gain"):
        metadata["AnalogueGain"] = float(raw.metadata["analogue_gain"])
    return array, config, metadata


def capture_raw(picam2: Any, *, sensor: str | None = None) -> RawImage:
    """Capture one raw frame from a running ``Picamera2`` camera (on the Pi) as a RawImage.

    Parameters
    ----------
    picam2 : picamera2.Picamera2
        A camera configured with a raw stream and started. The sensor's bit depth comes from
        ``camera_configuration()["sensor"]`` and its name from ``camera_properties["Model"]``.
    sensor : str, optional
        Sensor name, if the camera's model is not enough.

    Returns
    -------
    RawImage
        As :func:`from_picamera2` makes it; the request is released whatever happens.

    Examples
    --------
    A script for a Raspberry Pi with its camera; here it runs on picamcal's virtual camera
    (:func:`picamcal.virtualcam.install`, the script's first two lines, in a Python of its own as it changes the
    import path), which the real picamera2 runs on:

    >>> import subprocess, sys
    >>> from pathlib import Path
    >>> _ = Path("capture.py").write_text('''
    ... from picamcal.virtualcam import install
    ... install(sensor="imx219", size=(320, 240))  # not on a Raspberry Pi: the virtual camera
    ...
    ... from picamera2 import Picamera2
    ... from picamcal.raw.picamera2 import capture_raw
    ...
    ... with Picamera2() as picam2:
    ...     picam2.configure(picam2.create_still_configuration(raw={"format": "SBGGR16"}))
    ...     picam2.start()
    ...     raw = capture_raw(picam2)
    ... print(raw.sensor, raw.pattern, raw.bayer.shape, raw.black_level)
    ... ''')
    >>> print(subprocess.run([sys.executable, "capture.py"], capture_output=True, text=True).stdout, end="")
    imx219 BGGR (240, 320) (64.0, 64.0, 64.0, 64.0)
    """
    config = dict(picam2.camera_configuration())
    model = picam2.camera_properties.get("Model")
    if model is not None:
        config["model"] = model
    # Where the mode lies on the sensor: the largest ScalerCrop of the configured mode is its crop (picamera2's
    # sensor_modes call it crop_limits), on the sensor's active area.
    scaler_crop = picam2.camera_controls.get("ScalerCrop")
    active = active_area_size(picam2.camera_properties)
    if scaler_crop is not None and active is not None:
        config["crop_limits"], config["pixel_array_size"] = scaler_crop[1], active
    request = picam2.capture_request()
    try:  # decoded before the buffer goes back to the camera, in case the array shares its memory
        return from_picamera2(
            request.make_array("raw"), config, request.get_metadata(), sensor=sensor, source="<picamera2 capture>"
        )
    finally:
        request.release()
