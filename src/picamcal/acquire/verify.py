"""Which lens shading table is in force: the camera's own processed white, measured in every sensor mode.

``picamcal verify`` is the check a user runs on the Pi. The white light (the illuminator set as
:func:`~picamcal.acquire.acquisition.acquire` sets it for the white reference) is captured through the camera's own
pipeline in each sensor mode picamera2 reports, with the tuning the camera loads (picamera2's stock file for the
sensor) or the one given, in which only the tone curve and the colour matrix are made identity
(:func:`measurement_tuning`), so that the processed image is the white after black level, lens shading, colour
gains and digital gain alone. Each mode's corners are then compared with its centre, per channel, and the centre's
colour with grey (:func:`shading_figures`).

The colour gains are the ones the tuning file records for that mode (``picamcal export-tuning`` writes
``colour_gains_by_mode`` and ``colour_gains`` into its ``"picamcal"`` entry, which libcamera ignores), else the auto
white balance's. The exposure is fixed for each mode so that the processed white's 99.9th percentile sits at
:data:`TARGET_LEVEL` of full scale: nothing clips and nothing adapts.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from ..errors import PicamcalError
from ..export.tuning import RECORD_KEY, check_tuning, load_tuning, sensor_of_tuning_file
from ..sensors import find_sensor_name
from .base import CameraError, Illuminator
from .illuminators import REFERENCE_LIGHTS, open_illuminator
from .pi_camera import (
    Picamera2Camera,
    camera_model,
    check_tuning_target,
    import_picamera2,
    mode_name,
    picamera2_target,
    stock_tuning_file,
)

__all__ = [
    "CORNERS",
    "FLATNESS_TOLERANCE",
    "NEUTRALITY_TOLERANCE",
    "ModeCheck",
    "Verification",
    "measurement_tuning",
    "shading_figures",
    "verify_modes",
]

#: Default tolerance of flatness: every corner within 2 % of the centre, per channel (issue 30's criterion for a
#: mode inside a calibration's crop).
FLATNESS_TOLERANCE = 0.02
#: Default tolerance of neutrality: the centre's R/G and B/G within 3 % of 1.
NEUTRALITY_TOLERANCE = 0.03
#: The corners, in the order of :attr:`ModeCheck.corners`.
CORNERS = ("top left", "top right", "bottom left", "bottom right")
#: Each corner's box and the centre's half-size, as fractions of the image's width and height.
CORNER_FRACTION = 0.1
#: Where the processed white's 99.9th percentile is put, as a fraction of full scale (255).
TARGET_LEVEL = 0.7
#: The widest processed stream measured: a mode's image is scaled down by a whole factor to at most this width.
MAX_WIDTH = 640
_MAX_EXPOSURE_STEPS = 10
_LEVEL_TOLERANCE = 0.1
_START_EXPOSURE_US = 10_000.0
_AWB_SETTLED = 0.002
_MAX_AWB_FRAMES = 30
_MAX_EXPOSURE_US = 1_000_000.0
#: The linear tone curve (libcamera's ``rpi.contrast`` ``gamma_curve``, input and output pairs on 0..65535).
_LINEAR_CURVE = [0, 0, 65535, 65535]
_IDENTITY = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]


def measurement_tuning(tuning: dict[str, Any]) -> dict[str, Any]:
    """A copy of a libcamera tuning whose processed image is linear camera RGB: lens shading alone is measured.

    ``rpi.contrast`` gets the linear ``gamma_curve`` (0, 0, 65535, 65535) and ``ce_enable`` 0 (libcamera
    ``src/ipa/rpi/controller/rpi/contrast.cpp``: no adaptive contrast stretch, and the curve is the one the ISP's
    gamma block applies), and ``rpi.ccm`` one identity matrix (``ccm.cpp``: one entry holds at every colour
    temperature); a tuning without them gets them, after ``rpi.alsc``. Everything else, lens shading included, is
    kept as it is.

    Parameters
    ----------
    tuning : dict
        A tuning libcamera would load (:func:`picamcal.export.tuning.load_tuning`); never modified.

    Raises
    ------
    TuningError
        ``tuning`` is not one libcamera would load.

    Examples
    --------
    >>> from picamcal.export.tuning import load_tuning, stock_tuning_path
    >>> measured = measurement_tuning(load_tuning(stock_tuning_path("imx219", "pisp")))
    >>> sections = {name: params for algorithm in measured["algorithms"] for name, params in algorithm.items()}
    >>> sections["rpi.contrast"]["gamma_curve"], sections["rpi.contrast"]["ce_enable"]
    ([0, 0, 65535, 65535], 0)
    >>> sections["rpi.ccm"]["ccms"]
    [{'ct': 5000, 'ccm': [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]}]
    """
    check_tuning(tuning, "the tuning")
    measured = copy.deepcopy(tuning)
    algorithms: list[dict[str, Any]] = measured["algorithms"]
    contrast = _section(algorithms, "rpi.contrast", after="rpi.alsc")
    contrast.update(ce_enable=0, gamma_curve=list(_LINEAR_CURVE))
    ccm = _section(algorithms, "rpi.ccm", after="rpi.contrast")
    ccm["ccms"] = [{"ct": 5000, "ccm": list(_IDENTITY)}]
    return measured


def _section(algorithms: list[dict[str, Any]], name: str, after: str) -> dict[str, Any]:
    """An algorithm's parameters, added after ``after`` (or at the end) when the tuning has none."""
    for algorithm in algorithms:
        if name in algorithm:
            return algorithm[name]
    names = [next(iter(a), None) for a in algorithms]
    position = names.index(after) + 1 if after in names else len(algorithms)
    algorithms.insert(position, {name: {}})
    return algorithms[position][name]


def shading_figures(rgb: np.ndarray) -> tuple[np.ndarray, tuple[float, float]]:
    """Each corner over the centre per channel, and the centre's colour, of an image of a white.

    The corners are boxes of :data:`CORNER_FRACTION` of the width and height; the centre is the box of twice that
    around the middle. Channel means, not pixels, are compared.

    Parameters
    ----------
    rgb : ndarray, shape (height, width, 3)
        Linear R, G, B (a processed stream through :func:`measurement_tuning`).

    Returns
    -------
    corners : ndarray, shape (4, 3)
        Corner mean / centre mean, rows in :data:`CORNERS` order, columns R, G, B.
    centre : (float, float)
        The centre's R/G and B/G.

    Raises
    ------
    PicamcalError
        The image is too small (under 10 pixels a side) or its centre is black in a channel.

    Examples
    --------
    >>> y, x = np.mgrid[0:100, 0:200]
    >>> falloff = 1 - 0.2 * (((x - 99.5) / 100) ** 2 + ((y - 49.5) / 50) ** 2)
    >>> corners, centre = shading_figures(np.stack([200 * falloff, 100 * falloff, 100 * falloff], axis=-1))
    >>> np.round(corners[0], 3).tolist(), np.round(centre, 3).tolist()
    ([0.678, 0.678, 0.678], [2.0, 1.0])
    """
    image = np.asarray(rgb, dtype=np.float64)
    if image.ndim != 3 or image.shape[2] != 3 or min(image.shape[:2]) < 10:
        raise PicamcalError(f"an RGB image of at least 10 x 10 pixels is needed, not one of shape {image.shape}")
    height, width = image.shape[:2]
    a, b = max(1, round(CORNER_FRACTION * height)), max(1, round(CORNER_FRACTION * width))
    centre = image[height // 2 - a : height // 2 + a, width // 2 - b : width // 2 + b].mean(axis=(0, 1))
    if not np.all(centre > 0):
        raise PicamcalError("the centre of the image is black in a channel: is the light on?")
    boxes = (image[:a, :b], image[:a, -b:], image[-a:, :b], image[-a:, -b:])
    corners = np.stack([box.mean(axis=(0, 1)) / centre for box in boxes])
    return corners, (float(centre[0] / centre[1]), float(centre[2] / centre[1]))


@dataclasses.dataclass(frozen=True)
class ModeCheck:
    """The white through the camera's pipeline in one sensor mode.

    Attributes
    ----------
    mode : str
        ``WIDTHxHEIGHT:BITS``.
    crop : (x, y, width, height)
        The mode's area of the sensor (picamera2's ``crop_limits``), full-sensor pixels.
    scaler_crop : (x, y, width, height) or None
        The ``ScalerCrop`` the measured frame reports: the part of the mode the processed stream shows.
    size : (int, int)
        The processed stream measured (the mode's image scaled down by a whole factor).
    corners : ndarray, shape (4, 3)
        Each corner (:data:`CORNERS`) over the centre, per channel (R, G, B).
    centre : (float, float)
        The centre's R/G and B/G.
    colour_gains : (float, float)
        The red and blue gains the frame was processed with (the frame's ``ColourGains``).
    gains_source : str
        ``colour_gains_by_mode`` or ``colour_gains`` (recorded in the tuning), or ``auto white balance``.
    exposure_time_us : int
    analogue_gain : float
    """

    mode: str
    crop: tuple[int, int, int, int]
    scaler_crop: tuple[int, int, int, int] | None
    size: tuple[int, int]
    corners: np.ndarray
    centre: tuple[float, float]
    colour_gains: tuple[float, float]
    gains_source: str
    exposure_time_us: int
    analogue_gain: float

    @property
    def worst(self) -> np.ndarray:
        """Per channel (R, G, B), the corner's ratio furthest from 1."""
        index = np.argmax(np.abs(self.corners - 1), axis=0)
        return self.corners[index, np.arange(3)]

    @property
    def worst_corner(self) -> str:
        """The corner furthest from the centre in any channel."""
        return CORNERS[int(np.argmax(np.abs(self.corners - 1).max(axis=1)))]

    @property
    def flatness(self) -> float:
        """The largest departure of a corner from the centre, any channel (0.05 is 5 %)."""
        return float(np.abs(self.corners - 1).max())

    @property
    def neutrality(self) -> float:
        """The largest departure of the centre's R/G or B/G from 1."""
        return max(abs(self.centre[0] - 1), abs(self.centre[1] - 1))

    def is_flat(self, tolerance: float = FLATNESS_TOLERANCE) -> bool:
        """Every corner within ``tolerance`` of the centre, per channel."""
        return self.flatness <= tolerance

    def is_neutral(self, tolerance: float = NEUTRALITY_TOLERANCE) -> bool:
        """The centre's R/G and B/G within ``tolerance`` of 1."""
        return self.neutrality <= tolerance

    def to_record(self) -> dict[str, Any]:
        """A JSON-serialisable record (``corners`` by name, each R, G, B)."""
        return {
            "mode": self.mode,
            "crop": list(self.crop),
            "scaler_crop": None if self.scaler_crop is None else list(self.scaler_crop),
            "size": list(self.size),
            "corners": {name: _rounded(row) for name, row in zip(CORNERS, self.corners, strict=True)},
            "worst": _rounded(self.worst),
            "worst_corner": self.worst_corner,
            "flatness": round(self.flatness, 5),
            "centre": {"r/g": round(self.centre[0], 5), "b/g": round(self.centre[1], 5)},
            "neutrality": round(self.neutrality, 5),
            "colour_gains": [round(g, 5) for g in self.colour_gains],
            "gains_source": self.gains_source,
            "exposure_time_us": self.exposure_time_us,
            "analogue_gain": round(self.analogue_gain, 5),
        }


def _rounded(values: Sequence[float] | np.ndarray) -> list[float]:
    return [round(float(v), 5) for v in values]


@dataclasses.dataclass(frozen=True)
class Verification:
    """What :func:`verify_modes` measured: every mode, and the tolerances it was judged by.

    Attributes
    ----------
    sensor : str
        The camera's model.
    platform : str
        ``pisp`` (Pi 5) or ``vc4`` (Pi 4 and earlier).
    tuning : str
        The tuning file in force (its path; ``stock`` first for picamera2's stock file).
    flatness_tolerance, neutrality_tolerance : float
    modes : list of ModeCheck
        In the order picamera2 reports the modes.
    """

    sensor: str
    platform: str
    tuning: str
    flatness_tolerance: float
    neutrality_tolerance: float
    modes: list[ModeCheck]

    def passes(self, check: ModeCheck) -> bool:
        """Whether one mode is flat and neutral within the tolerances."""
        return check.is_flat(self.flatness_tolerance) and check.is_neutral(self.neutrality_tolerance)

    @property
    def passed(self) -> bool:
        """Every mode flat and neutral within the tolerances."""
        return all(self.passes(check) for check in self.modes)

    def to_record(self) -> dict[str, Any]:
        """A JSON-serialisable record: the camera, the tuning, the tolerances, the verdict and every mode's."""
        return {
            "sensor": self.sensor,
            "platform": self.platform,
            "tuning": self.tuning,
            "tolerance": {"flatness": self.flatness_tolerance, "neutrality": self.neutrality_tolerance},
            "passed": self.passed,
            "modes": [{**check.to_record(), "passed": self.passes(check)} for check in self.modes],
        }


def mode_colour_gains(tuning: Mapping[str, Any], mode: str) -> tuple[tuple[float, float] | None, str]:
    """The colour gains a tuning file records for a sensor mode, and where they come from.

    ``colour_gains_by_mode[mode]`` of the tuning's ``"picamcal"`` entry when there is one, else its
    ``colour_gains``, else none (``auto white balance``).

    Examples
    --------
    >>> record = {"picamcal": {"colour_gains": [1.5, 1.2], "colour_gains_by_mode": {"1920x1080:10": [1.6, 1.1]}}}
    >>> mode_colour_gains(record, "1920x1080:10"), mode_colour_gains(record, "640x480:10")
    (((1.6, 1.1), 'colour_gains_by_mode'), ((1.5, 1.2), 'colour_gains'))
    >>> mode_colour_gains({}, "640x480:10")
    (None, 'auto white balance')
    """
    record = tuning.get(RECORD_KEY)
    record = record if isinstance(record, Mapping) else {}
    by_mode = record.get("colour_gains_by_mode")
    for source, value in (
        ("colour_gains_by_mode", by_mode.get(mode) if isinstance(by_mode, Mapping) else None),
        ("colour_gains", record.get("colour_gains")),
    ):
        gains = _gains(value)
        if gains is not None:
            return gains, source
    return None, "auto white balance"


def _gains(value: Any) -> tuple[float, float] | None:
    """Recorded red and blue gains as libcamera takes them (``ColourGains``: two numbers in (0, 32]), or None."""
    if isinstance(value, (list, tuple)) and len(value) == 2:
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v <= 32 for v in value):
            return float(value[0]), float(value[1])
    return None


def _stream_size(width: int, height: int) -> tuple[int, int]:
    """The mode's image scaled down by the smallest whole factor that makes it at most :data:`MAX_WIDTH` wide (even
    sizes, the ISP's)."""
    factor = max(1, math.ceil(width / MAX_WIDTH))
    return (width // factor) & ~1, (height // factor) & ~1


def _expose(
    camera: Picamera2Camera, gains: tuple[float, float] | None, start_us: float
) -> tuple[np.ndarray, dict[str, Any]]:
    """Fix the exposure so that the processed white's 99.9th percentile lands at :data:`TARGET_LEVEL`; the frame
    and its metadata. The exposure time grows first, at the lowest gain; the gain only beyond 1 s."""
    limits = camera.limits()
    (t_min, t_max), (g_min, g_max) = limits.exposure_time_us, limits.analogue_gain
    t_max = min(t_max, _MAX_EXPOSURE_US)
    product = min(max(start_us * g_min, t_min * g_min), t_max * g_max)
    for _ in range(_MAX_EXPOSURE_STEPS):
        exposure = min(max(product / g_min, t_min), t_max)
        gain = min(max(product / exposure, g_min), g_max)
        camera.set_controls(exposure, gain, gains, auto_white_balance=gains is None)
        rgb, metadata = camera.capture_processed()
        level = float(np.percentile(rgb, 99.9)) / 255.0
        if level >= 0.99:  # clipped: how far is unknown
            if exposure <= t_min and gain <= g_min:
                raise CameraError(
                    "the white clips even at the shortest exposure and lowest gain: dim the light or add a diffuser"
                )
            product = max(product / 4, t_min * g_min)
            continue
        if abs(level / TARGET_LEVEL - 1) <= _LEVEL_TOLERANCE:
            return rgb, metadata
        if exposure >= t_max and gain >= g_max:
            if level >= TARGET_LEVEL / 2:
                return rgb, metadata
            raise CameraError(
                f"the white is too dark ({100 * level:.0f} % of full scale at the longest exposure and highest gain): "
                "brighten the light or bring it closer"
            )
        product = min(max(product * TARGET_LEVEL / max(level, 1e-3), t_min * g_min), t_max * g_max)
    raise CameraError(
        f"the processed white did not settle at {100 * TARGET_LEVEL:.0f} % of full scale in {_MAX_EXPOSURE_STEPS} "
        "frames: is the light flickering or still warming up?"
    )


def _awb_settled(
    camera: Picamera2Camera, rgb: np.ndarray, metadata: dict[str, Any]
) -> tuple[np.ndarray, dict[str, Any]]:
    """The first frame whose auto white balance gains moved less than :data:`_AWB_SETTLED` from the frame before
    (libcamera's AWB moves at ``rpi.awb``'s speed once its start-up frames are over), or the last of
    :data:`_MAX_AWB_FRAMES` more."""
    for _ in range(_MAX_AWB_FRAMES):
        before = metadata.get("ColourGains")
        rgb, metadata = camera.capture_processed()
        after = metadata.get("ColourGains")
        if before is None or after is None:
            break
        if all(abs(float(a) / float(b) - 1) < _AWB_SETTLED for a, b in zip(after, before, strict=True)):
            break
    return rgb, metadata


def _measure(camera: Picamera2Camera, mode: Mapping[str, Any], tuning: Mapping[str, Any], start_us: float) -> ModeCheck:
    name = mode_name(mode)
    size = _stream_size(*(int(v) for v in mode["size"]))
    camera.configure_processed(mode, size)
    gains, source = mode_colour_gains(tuning, name)
    rgb, metadata = _expose(camera, gains, start_us)
    if gains is None:
        rgb, metadata = _awb_settled(camera, rgb, metadata)
    corners, centre = shading_figures(rgb)
    geometry = camera.geometry(mode)
    applied = metadata.get("ColourGains") or gains or (1.0, 1.0)
    crop = metadata.get("ScalerCrop")
    return ModeCheck(
        mode=name,
        crop=geometry.crop,
        scaler_crop=None if crop is None else tuple(int(v) for v in crop),  # type: ignore[arg-type]
        size=(int(rgb.shape[1]), int(rgb.shape[0])),
        corners=corners,
        centre=centre,
        colour_gains=(float(applied[0]), float(applied[1])),
        gains_source=source,
        exposure_time_us=int(metadata.get("ExposureTime", 0)),
        analogue_gain=float(metadata.get("AnalogueGain", 0.0)),
    )


def check_tolerances(flatness: float, neutrality: float) -> None:
    """Refuse a tolerance that is not a fraction between 0 and 1 (0.02 is 2 %).

    Examples
    --------
    >>> check_tolerances(0.02, 1.5)
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: the neutrality tolerance must be a fraction above 0 and below 1 (0.03 is 3 %), \
not 1.5
    """
    for what, value in (("flatness", flatness), ("neutrality", neutrality)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and 0 < value < 1):
            raise PicamcalError(
                f"the {what} tolerance must be a fraction above 0 and below 1 (0.03 is 3 %), not {value!r}"
            )


def verify_modes(
    camera_num: int = 0,
    tuning: str | os.PathLike[str] | None = None,
    illuminator: Illuminator | str | None = None,
    *,
    flatness_tolerance: float = FLATNESS_TOLERANCE,
    neutrality_tolerance: float = NEUTRALITY_TOLERANCE,
    settle_s: float = 0.5,
    progress: Callable[[str, int, int], Any] | None = None,
) -> Verification:
    """Measure the white through a Raspberry Pi camera's own pipeline in every sensor mode: flat and neutral?

    The camera is opened with :func:`measurement_tuning` of ``tuning`` (default: the file the camera loads when none
    is given, picamera2's stock file for the sensor), the illuminator set to white (waiting ``settle_s``), and each
    mode picamera2 reports (:func:`~picamcal.acquire.cameras.raw_sensor_modes`) configured in turn with a processed
    RGB stream of the whole mode (scaled down to at most :data:`MAX_WIDTH` pixels wide), its colour gains those the
    tuning records for the mode (:func:`mode_colour_gains`) or the auto white balance's (once its gains move less
    than 0.2 % a frame), its exposure fixed so that
    the white's 99.9th percentile sits at :data:`TARGET_LEVEL` of full scale. Each mode's figures are
    :func:`shading_figures` of one frame.

    Parameters
    ----------
    camera_num : int
        Which camera (``Picamera2.global_camera_info()`` order).
    tuning : path-like, optional
        The libcamera tuning file to check.
    illuminator : Illuminator or str, optional
        The light to set to white: one opened by the caller (left on), or its command-line name
        (:func:`~picamcal.acquire.illuminators.open_illuminator`: ``serial``, ``virtual``, ...), opened once the
        inputs are checked and closed at the end; None when the white is lit otherwise.
    flatness_tolerance : float
        A mode is flat when every corner is within this fraction of its centre, per channel.
    neutrality_tolerance : float
        A mode is neutral when its centre's R/G and B/G are within this fraction of 1.
    settle_s : float
        Seconds to wait after setting the light.
    progress : callable, optional
        ``progress(mode, done, total)`` before each mode and at the end (``"done"``).

    Returns
    -------
    Verification

    Raises
    ------
    PicamcalError
        A tolerance out of range; the tuning file is missing or not a tuning file (``TuningError``), is for the
        other Raspberry Pi or for another sensor (``CameraError``, naming the file); no camera, or it cannot be
        configured or exposed (``CameraError``).

    Examples
    --------
    On a Raspberry Pi with its camera looking at the rig's white (``tests/test_verify_modes.py`` runs it on the
    virtual camera)::

        from picamcal.acquire.illuminators import open_illuminator

        light = open_illuminator("serial")
        result = verify_modes(0, "tuning/imx219_pisp.json", light)
        light.close()
        for check in result.modes:
            print(check.mode, check.worst, check.centre)  # each corner over the centre, R, G, B; R/G, B/G
        print(result.passed)
    """
    check_tolerances(flatness_tolerance, neutrality_tolerance)
    if settle_s < 0:
        raise PicamcalError(f"the settling time must be >= 0 s, got {settle_s}")
    given = None if tuning is None else load_tuning(tuning)  # a bad file is its own error, camera or not
    module = import_picamera2()
    if given is not None:
        check_tuning_target(given, module, str(tuning))
    model = camera_model(camera_num)
    if tuning is None:
        path = stock_tuning_file(model, module)
        chosen, description = load_tuning(path), f"stock: {path}"
    else:
        assert given is not None
        named = sensor_of_tuning_file(tuning)
        if named is not None and named != (find_sensor_name(model) or model):
            raise CameraError(
                f"{tuning} is a tuning file for the {named}, but camera {camera_num} is the {model}: give the "
                f"{model}'s (picamcal export-tuning CALIBRATION writes one)"
            )
        chosen, description = given, str(tuning)
    platform = "vc4" if picamera2_target(module) == "bcm2835" else "pisp"
    report = progress or (lambda message, done, total: None)
    light = open_illuminator(illuminator) if isinstance(illuminator, str) else illuminator
    try:
        checks = _measure_modes(camera_num, chosen, light, settle_s, report)
    finally:
        if isinstance(illuminator, str) and light is not None:
            light.close()
    return Verification(model, platform, description, flatness_tolerance, neutrality_tolerance, checks)


def _measure_modes(
    camera_num: int,
    tuning: dict[str, Any],
    light: Illuminator | None,
    settle_s: float,
    report: Callable[[str, int, int], Any],
) -> list[ModeCheck]:
    """:func:`verify_modes` once its inputs are checked: open the camera, light the white, measure every mode."""
    camera = Picamera2Camera(camera_num, tuning=measurement_tuning(tuning))
    try:
        if light is not None:  # after the camera opened: the virtual camera's light needs it
            light.set_rgb(*REFERENCE_LIGHTS["white"])
            time.sleep(settle_s)
        modes = camera.sensor_modes
        checks: list[ModeCheck] = []
        start_us = _START_EXPOSURE_US
        for done, mode in enumerate(modes):
            report(mode_name(mode), done, len(modes))
            check = _measure(camera, mode, tuning, start_us)
            start_us = check.exposure_time_us * check.analogue_gain
            checks.append(check)
        report("done", len(modes), len(modes))
    finally:
        camera.close()
    return checks
