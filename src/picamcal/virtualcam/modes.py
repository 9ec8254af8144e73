"""The virtual camera's sensors: their modes, timing, gain codes and mounting, as Raspberry Pi OS drives them.

The size, bit depth and pixel pitch of each sensor come from picamcal's registry (:mod:`picamcal.sensors`); what
the registry does not hold, this module gives per sensor, each value from its source:

- the modes (output size, sensor crop, line length, pixel rate, fastest frame rate) and the unflipped Bayer order
  from the Raspberry Pi kernel's drivers (``drivers/media/i2c/<sensor>.c``: ``supported_modes``, the media bus
  code table "no flip, h flip, v flip, h&v flips");
- the mounting rotation from the Raspberry Pi device tree overlays (``arch/arm/boot/dts/overlays/<sensor>.dtsi``,
  ``rotation = <180>``);
- the analogue gain codes and the lines an exposure keeps from the frame (``frameIntegrationDiff``) from libcamera's
  camera helpers (``src/ipa/rpi/cam_helper/cam_helper_<sensor>.cpp``);
- the frames a control takes to reach the sensor from libcamera's ``src/libcamera/sensor/camera_sensor_properties.cpp``
  (``sensorDelays``).

A registry sensor without such a table gets nominal modes: the full array and its binned modes at 30 frames per
second, unity gain code steps of 1/256, no rotation (said in :attr:`SensorSpec.nominal`).

Examples
--------
>>> spec = sensor_spec("imx477")
>>> [(m.width, m.height, m.bit_depth) for m in spec.modes]
[(1332, 990, 10), (2028, 1080, 12), (2028, 1520, 12), (4056, 3040, 12)]
>>> round(spec.modes[2].max_fps, 2), spec.gain(spec.gain_code(2.0))
(40.01, 2.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from ..errors import PicamcalError
from ..sensors import DRIVER_MODES, SENSORS, DriverMode, get_sensor, scaled_mode


@dataclass(frozen=True)
class ModeSpec(DriverMode):
    """One sensor mode: the registry's (:class:`picamcal.sensors.DriverMode`: size, bit depth, crop on the active
    pixel array, libcamera's ``analogCrop``, what ``ScalerCrop`` is measured in) with its timing.

    Attributes
    ----------
    line_length : int
        Line length in pixel clocks (``line_length_pix``, width + horizontal blanking).
    pixel_rate : float
        Pixel clock in Hz.
    min_frame_lines : int
        Shortest frame in lines (height + the smallest vertical blanking).
    """

    line_length: int
    pixel_rate: float
    min_frame_lines: int

    @property
    def line_time_us(self) -> float:
        """Duration of one line in microseconds."""
        return self.line_length / self.pixel_rate * 1e6

    @property
    def max_fps(self) -> float:
        """The fastest frame rate (shortest frame)."""
        return 1e6 / (self.min_frame_lines * self.line_time_us)

    @property
    def binning(self) -> int:
        """How many sensor pixels make one output pixel along each axis (1 unbinned, 2 for 2x2 binning)."""
        return max(1, round(self.crop[2] / self.width))


@dataclass(frozen=True)
class SensorSpec:
    """A sensor as the virtual camera emulates it.

    Attributes
    ----------
    name : str
        libcamera's model name (the tuning file's stem).
    width, height : int
        The active pixel array.
    bit_depth, black_level : int
        From the registry.
    unit_cell_nm : int
        Pixel pitch in nanometres (the ``UnitCellSize`` property).
    native_order : str
        Bayer order of the unflipped sensor.
    rotation : int
        Mounting rotation in degrees (the ``Rotation`` property).
    supports_flips : bool
        The driver has horizontal and vertical flip controls.
    modes : tuple of ModeSpec
        The modes, as libcamera lists them (by bit depth, then size).
    gain_kind : str
        How gain codes map to gains: ``"sony"`` (``N / (N - code)``), ``"linear"`` (``code / N``).
    gain_base : int
        ``N`` above.
    gain_codes : (int, int)
        The driver's analogue gain control range.
    exposure_min_lines : int
        The driver's smallest exposure in lines.
    integration_diff : int
        Lines between the exposure and the frame length at least (libcamera's ``frameIntegrationDiff``).
    max_frame_lines : int
        Longest frame in lines the driver allows.
    delays : (int, int, int)
        Frames for exposure, gain and vertical blanking to reach the sensor.
    hide_frames_startup, mistrust_frames_startup : int
        The camera helper's frames hidden and not trusted for statistics after a start.
    nominal : bool
        The modes are nominal (no driver table in this module).
    """

    name: str
    width: int
    height: int
    bit_depth: int
    black_level: int
    unit_cell_nm: int
    native_order: str
    rotation: int
    supports_flips: bool
    modes: tuple[ModeSpec, ...]
    gain_kind: str = "sony"
    gain_base: int = 1024
    gain_codes: tuple[int, int] = (0, 978)
    exposure_min_lines: int = 4
    integration_diff: int = 22
    max_frame_lines: int = 0xFFDC
    delays: tuple[int, int, int] = (2, 2, 2)
    hide_frames_startup: int = 0
    mistrust_frames_startup: int = 1
    nominal: bool = False

    def gain(self, code: int) -> float:
        """The analogue gain of a register code (the camera helper's ``gain``)."""
        if self.gain_kind == "linear":
            return code / self.gain_base
        return self.gain_base / (self.gain_base - code)

    def gain_code(self, gain: float) -> int:
        """The register code for a gain, truncated as the camera helper's ``gainCode`` truncates it."""
        if self.gain_kind == "linear":
            return int(gain * self.gain_base)
        return int(self.gain_base - self.gain_base / gain)

    @property
    def gain_range(self) -> tuple[float, float]:
        """The lowest and highest analogue gain."""
        return self.gain(self.gain_codes[0]), self.gain(self.gain_codes[1])


def _mode(mode: DriverMode, line_length: int, rate: float, fps: float) -> ModeSpec:
    """A registry mode with its timing; its shortest frame is the driver's ``timeperframe_min`` (frame length
    rounded down, at least the height, as the drivers' ``get_frame_length`` rounds it)."""
    lines = max(mode.height, math.floor(rate / (fps * line_length)))
    return ModeSpec(mode.width, mode.height, mode.bit_depth, mode.crop, line_length, rate, lines)


def _timed(name: str, timing: dict[tuple[int, int], tuple[int, float, float]]) -> tuple[ModeSpec, ...]:
    """The registry's modes of a sensor (:data:`picamcal.sensors.DRIVER_MODES`: size, bit depth, crop) with the
    timing of each size: line length in pixel clocks, pixel rate, fastest frame rate."""
    return tuple(_mode(m, *timing[(m.width, m.height)]) for m in DRIVER_MODES[name])


def _imx477() -> tuple[ModeSpec, ...]:
    # imx477.c: pixel rate fixed at 840 MHz; line lengths and frame rates of supported_modes_12bit and _10bit.
    rate = 840e6
    return _timed(
        "imx477",
        {(1332, 990): (6664, rate, 120.0), (2028, 1080): (12740, rate, 50.0), (2028, 1520): (12740, rate, 40.0),
         (4056, 3040): (24000, rate, 10.0)},
    )  # fmt: skip


def _imx219() -> tuple[ModeSpec, ...]:
    # imx219.c: 182.4 MHz (2 lanes), line length IMX219_PPL_DEFAULT 3448, IMX219_VBLANK_MIN 32 for every mode.
    return tuple(ModeSpec(m.width, m.height, m.bit_depth, m.crop, 3448, 182.4e6, m.height + 32)
                 for m in DRIVER_MODES["imx219"])  # fmt: skip


def _imx708() -> tuple[ModeSpec, ...]:
    # imx708.c (non-HDR 10-bit modes): 595.2 MHz, line_length_pix 0x3d20, 0x1e90, 0x1460; the frame rates libcamera
    # lists for them.
    rate = 595.2e6
    return _timed(
        "imx708",
        {(1536, 864): (5216, rate, 120.13), (2304, 1296): (7824, rate, 56.03), (4608, 2592): (15648, rate, 14.35)},
    )


def _ov5647() -> tuple[ModeSpec, ...]:
    # ov5647.c ov5647_modes: per-mode pixel rate and HTS, the mode's default frame rates (the fastest the driver
    # allows); 10-bit SBGGR10 (GBRG on the Pi's module, see the registry).
    return _timed(
        "ov5647",
        {(640, 480): (1852, 55e6, 58.92), (1296, 972): (1896, 81.666700e6, 43.25),
         (1920, 1080): (2416, 81.666700e6, 30.62), (2592, 1944): (2844, 87.5e6, 15.63)},
    )  # fmt: skip


# name: (modes, native order, rotation, gain kind/base/codes, min exposure lines, integration diff, max frame lines,
# delays (exposure, gain, vblank), hidden and mistrusted start-up frames)
_TABLES = {
    "imx477": (_imx477, "RGGB", 180, ("sony", 1024, (0, 978)), 4, 22, 0xFFDC << 7, (2, 2, 3), 0, 1),
    "imx219": (_imx219, "RGGB", 180, ("sony", 256, (0, 232)), 4, 4, 0xFFFF, (2, 1, 2), 0, 1),
    "imx708": (_imx708, "RGGB", 180, ("sony", 1024, (112, 960)), 8, 48, 0xFFFF << 7, (2, 2, 3), 0, 1),
    "ov5647": (_ov5647, "GBRG", 0, ("linear", 16, (16, 1023)), 4, 4, 0xFFFF, (2, 2, 2), 2, 2),
}


def _nominal_modes(width: int, height: int, bits: int, binned: tuple[tuple[int, int], ...]) -> tuple[ModeSpec, ...]:
    """Nominal modes of a sensor this module has no driver table for: the full array and its binned modes, each at
    up to 30 frames per second."""
    modes = []
    for w, h in (*sorted(binned), (width, height)):
        line_length = w + 160
        modes.append(ModeSpec(w, h, bits, (0, 0, width, height), line_length, 30.0 * line_length * (h + 32), h + 32))
    return tuple(modes)


def sensor_spec(name: str) -> SensorSpec:
    """The virtual camera's description of a registry sensor.

    Raises
    ------
    PicamcalError
        Not a registry sensor (the message lists them), or a monochrome one (the simulator renders Bayer sensors).

    Examples
    --------
    >>> spec = sensor_spec("imx219")
    >>> spec.rotation, spec.delays, len(spec.modes), sensor_spec("imx296").nominal
    (180, (2, 1, 2), 8, True)
    """
    sensor = get_sensor(name)
    if sensor.monochrome or sensor.default_pattern is None:
        colour = [s.name for s in SENSORS.values() if not s.monochrome]
        raise PicamcalError(
            f"the {sensor.name} is a monochrome sensor: the virtual camera simulates colour sensors "
            f"({', '.join(colour)})"
        )
    common: dict[str, Any] = {
        "name": sensor.name,
        "width": sensor.width,
        "height": sensor.height,
        "bit_depth": sensor.bit_depth,
        "black_level": sensor.black_level,
        "unit_cell_nm": round(sensor.pixel_pitch_um * 1000),
    }
    table = _TABLES.get(sensor.name)
    if table is None:
        return SensorSpec(
            **common,
            native_order=sensor.default_pattern,
            rotation=0,
            supports_flips=True,
            modes=_nominal_modes(sensor.width, sensor.height, sensor.bit_depth, sensor.binned_modes),
            gain_kind="linear",
            gain_base=256,
            gain_codes=(256, 256 * 16),
            integration_diff=4,
            max_frame_lines=0xFFFF,
            nominal=True,
        )
    modes, order, rotation, (kind, base, codes), min_lines, diff, max_lines, delays, hidden, mistrusted = table
    return SensorSpec(
        **common,
        native_order=order,
        rotation=rotation,
        supports_flips=True,
        modes=modes(),
        gain_kind=kind,
        gain_base=base,
        gain_codes=codes,
        exposure_min_lines=min_lines,
        integration_diff=diff,
        max_frame_lines=max_lines,
        delays=delays,
        hide_frames_startup=hidden,
        mistrust_frames_startup=mistrusted,
    )


def scaled_spec(spec: SensorSpec, size: tuple[int, int] | None) -> SensorSpec:
    """The sensor with its pixel array reduced to ``size`` (``--size``): every mode and crop scaled with it, the
    timing (line times, frame rates) kept.

    Raises
    ------
    PicamcalError
        A size larger than the sensor, or not even.

    Examples
    --------
    >>> small = scaled_spec(sensor_spec("imx477"), (640, 480))
    >>> [(m.width, m.height, m.crop) for m in small.modes][:2]
    [(210, 156, (110, 84, 420, 312)), (320, 170, (0, 70, 640, 340))]
    """
    if size is None or tuple(size) == (spec.width, spec.height):
        return spec
    width, height = (int(v) for v in size)
    if width % 2 or height % 2 or width < 16 or height < 16:
        raise PicamcalError(f"the virtual sensor's size must be even and at least 16x16 pixels, not {width}x{height}")
    if width > spec.width or height > spec.height:
        raise PicamcalError(
            f"the virtual {spec.name} is at most {spec.width}x{spec.height} pixels (its full array), "
            f"not {width}x{height}"
        )
    modes = []
    for mode in spec.modes:  # scaled as the registry scales a reduced sensor's modes, timing kept
        w, h, crop = scaled_mode(mode.width, mode.height, mode.crop, (spec.width, spec.height), (width, height))
        modes.append(replace(mode, width=w, height=h, crop=crop))
    # Two modes may meet at one size on a small sensor: libcamera lists each size once per bit depth.
    unique = {(m.bit_depth, m.width, m.height): m for m in modes}
    return replace(spec, width=width, height=height, modes=tuple(unique.values()))
