"""What a running picamera2 camera says about its stream: its sensor mode as libcamera describes it to the IPA, the
ScalerCrop of a request, the metadata once it has settled, and the tuning in force. :mod:`picamcal.live` re-exports
:func:`camera_sensor_mode`.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from typing import Any

from ..errors import PicamcalError
from ..geometry import Box, SensorMode, mode_from_crop
from ..raw.picamera2.metadata import active_area_size

#: Frames :meth:`picamcal.live.LiveUnmixer.for_camera` waits at most for the metadata to settle after ``start``.
_SETTLE_FRAMES = 10


def camera_sensor_mode(picam2: Any) -> SensorMode:
    """The sensor mode a picamera2 camera is configured in, as libcamera describes it to its IPA.

    The mode's size and bit depth are the configuration's ``sensor`` (``output_size``, ``bit_depth``); its crop on
    the sensor is the largest ``ScalerCrop`` (``camera_controls["ScalerCrop"][1]``: libcamera sets its maximum to the
    mode's ``analogCrop``, ``PipelineHandlerBase::configure``); the flips are the configuration's ``transform``; the
    sensor is its active area (``camera_properties["PixelArrayActiveAreas"][0]``, which ``analogCrop`` and
    ``ScalerCrop`` are relative to: ``CameraSensorRaw::sensorInfo`` and ``control_ids_core.yaml``;
    ``PixelArraySize`` where no active area is given).

    Raises
    ------
    PicamcalError
        The camera is not configured, or its crop cannot give the mode's size (one line).

    Examples
    --------
    What picamera2 gives for an IMX219 in its 2 x 2 binned mode, mirrored:

    >>> from types import SimpleNamespace
    >>> picam2 = SimpleNamespace(
    ...     camera_configuration=lambda: {
    ...         "sensor": {"output_size": (1640, 1232), "bit_depth": 10},
    ...         "transform": SimpleNamespace(hflip=True, vflip=False),
    ...     },
    ...     camera_controls={"ScalerCrop": ((0, 0, 128, 128), (0, 0, 3280, 2464), (0, 0, 3280, 2464))},
    ...     camera_properties={"PixelArraySize": (3296, 2480), "PixelArrayActiveAreas": [(8, 8, 3280, 2464)]},
    ... )
    >>> print(camera_sensor_mode(picam2).describe())
    1640x1232: the whole 3280x2464 sensor, 2x2 binned, hflip, 10 bits (camera)
    """
    config = picam2.camera_configuration() or {}
    sensor = config.get("sensor") or {}
    limits = picam2.camera_controls.get("ScalerCrop")
    array = active_area_size(picam2.camera_properties)
    if not sensor.get("output_size") or limits is None or array is None:
        raise PicamcalError(
            "the camera says no sensor mode (its configuration's sensor, the ScalerCrop control, the pixel array): "
            "configure it first"
        )
    transform = config.get("transform")
    size = (int(sensor["output_size"][0]), int(sensor["output_size"][1]))
    x, y, w, h = (int(v) for v in limits[1])
    mode = mode_from_crop((int(array[0]), int(array[1])), size, (x, y, w, h), what="the camera's mode crop")
    bits = sensor.get("bit_depth")
    return dataclasses.replace(
        mode,
        hflip=bool(getattr(transform, "hflip", False)),
        vflip=bool(getattr(transform, "vflip", False)),
        bit_depth=None if bits is None else int(bits),
        source="camera",
    )


def _stream_scaler_crop(metadata: Mapping[str, Any], stream: str) -> Box | None:
    """The ScalerCrop a request's metadata gives for ``stream`` (the Pi 5's ``ScalerCrops`` has one per output,
    main first), or None."""
    crops = metadata.get("ScalerCrops")
    crop = crops[1] if stream == "lores" and crops and len(crops) > 1 else metadata.get("ScalerCrop")
    if crop is None:
        return None
    x, y, w, h = (int(v) for v in crop)
    return x, y, w, h


def _settled_metadata(picam2: Any) -> dict[str, Any]:
    """The metadata of the first frame that agrees with the one before it on the colour gains, the colour temperature
    and the ScalerCrop (at most :data:`_SETTLE_FRAMES` frames): the first frames after ``start`` report the IPA's
    defaults (the colour temperature of 4500 K before its white balance has run), not what is in force."""
    keys = ("ColourGains", "ColourTemperature", "ScalerCrop")
    metadata = picam2.capture_metadata()
    for _ in range(_SETTLE_FRAMES):
        following = picam2.capture_metadata()
        if all(following.get(key) == metadata.get(key) for key in keys):
            return following
        metadata = following
    return metadata


def _tuning_in_force(picam2: Any) -> dict[str, Any]:
    """The tuning the camera runs with: the file ``LIBCAMERA_RPI_TUNING_FILE`` names, else the sensor's stock file
    for this Pi (what libcamera loads when none is named)."""
    from ..export.tuning import load_tuning, stock_tuning_path

    path = os.environ.get("LIBCAMERA_RPI_TUNING_FILE")
    if path:
        if not os.path.isfile(path):
            raise PicamcalError(
                f"the camera's tuning file {path} (LIBCAMERA_RPI_TUNING_FILE) is gone: picamera2 deletes the file of "
                "a tuning it was opened with as a dict; give the tuning to for_camera as tuning="
            )
        return load_tuning(path)
    model = str(picam2.camera_properties.get("Model", ""))
    target = "bcm2835" if "VC4" in str(getattr(type(picam2), "platform", "")).upper() else "pisp"
    return load_tuning(stock_tuning_path(model, target))
