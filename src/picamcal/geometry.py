"""Where on the sensor an image was taken: the sensor mode as one value, carried from the file to the correction.

A raw frame comes from a sensor mode: an area of the sensor's pixel array (the mode's crop, libcamera's
``analogCrop``), read out whole or binned, maybe mirrored. libcamera describes it with ``IPACameraSensorInfo``
(``include/libcamera/ipa/core.mojom``) and the Raspberry Pi IPA's ``CameraMode`` (``src/ipa/rpi/controller/
camera_mode.h``: crop, scale, transform); its lens shading works from that alone (``resampleCalTable`` in
``src/ipa/rpi/controller/rpi/alsc.cpp``). :class:`SensorMode` is picamcal's value for it, made once where the file
or the camera says it (:func:`raw_geometry`), recorded with the :class:`~picamcal.calibration.Calibration`, and
taken by every resampling between modes (:func:`image_to_image`).

Coordinates are continuous: pixel ``i`` of an image spans ``[i, i + 1)``; a mode's crop is in full-sensor pixels
(as libcamera's ``analogCrop`` and picamera2's ``crop_limits`` and ``ScalerCrop`` are); flips mirror the image
inside its crop, as libcamera's ``CameraMode::transform`` mirrors the lens shading tables.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import PicamcalError
from .sensors import SENSORS, DriverMode, sensor_modes

#: Where a :class:`SensorMode` came from, and what each means.
GEOMETRY_SOURCES: dict[str, str] = {
    "camera": "the camera said (picamera2's sensor mode, crop limits and transform)",
    "file": "the file records it",
    "given": "given by the user (--sensor-crop or --sensor-mode)",
    "registry": "the sensor's mode of this size in picamcal's registry (the file records no crop)",
    "assumed": "nothing says: the whole sensor is assumed",
    "unknown": "geometry unknown (a calibration from before it was recorded): taken as the full sensor",
}

Box = tuple[int, int, int, int]

__all__ = [
    "GEOMETRY_SOURCES",
    "SensorMode",
    "assumed_geometry",
    "check_scaler_crop",
    "default_scaler_crop",
    "driver_geometry",
    "full_field_binning",
    "image_to_image",
    "mode_for_image",
    "mode_from_crop",
    "mode_names",
    "named_mode",
    "parse_sensor_crop",
    "parse_sensor_mode",
    "registry_mode",
    "sensor_area",
    "stream_positions",
]


@dataclass(frozen=True)
class SensorMode:
    """Where a sensor mode's image lies on the full sensor (libcamera's ``CameraMode``).

    Attributes
    ----------
    sensor_width, sensor_height : int
        Full sensor (active pixel array) size in pixels.
    crop : (x, y, width, height)
        The sensor area the mode reads, in full-sensor pixels.
    binning : int
        Binning or scaling factor from that area to the mode's image (1 unbinned, 2 for 2 x 2).
    hflip, vflip : bool
        Mirroring of the mode's image (libcamera's transform of the mode; the lens shading tables follow it).
    bit_depth : int or None
        Bits per pixel of the mode, when known.
    source : str
        Where this value came from, one of :data:`GEOMETRY_SOURCES`.
    output : (width, height) or None
        The mode's image size where it is not the crop divided by the binning (the OV5647's 1920 x 1080 mode reads
        a 1928 pixel wide area); None: ``crop / binning``.

    Examples
    --------
    >>> mode = SensorMode(3280, 2464, (680, 692, 1920, 1080), bit_depth=10, source="registry")
    >>> mode.width, mode.height, mode.is_full
    (1920, 1080, False)
    >>> print(mode.describe())
    1920x1080: the 1920x1080 area at (680, 692) of the 3280x2464 sensor, 10 bits (registry)
    """

    sensor_width: int
    sensor_height: int
    crop: Box
    binning: int = 1
    hflip: bool = False
    vflip: bool = False
    bit_depth: int | None = None
    source: str = "assumed"
    output: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        x, y, w, h = self.crop
        if min(self.sensor_width, self.sensor_height, w, h, self.binning) < 1 or x < 0 or y < 0:
            raise PicamcalError(f"sensor crop {list(self.crop)} is not an area of a sensor")
        if x + w > self.sensor_width or y + h > self.sensor_height:
            raise PicamcalError(
                f"sensor crop {list(self.crop)} lies outside the {self.sensor_width}x{self.sensor_height} sensor"
            )
        if self.source not in GEOMETRY_SOURCES:
            raise PicamcalError(f"unknown geometry source {self.source!r}")
        if self.output is not None and tuple(self.output) == (w // self.binning, h // self.binning):
            object.__setattr__(self, "output", None)  # one value for one mode: the size it implies is not repeated

    @classmethod
    def full(
        cls,
        width: int,
        height: int,
        *,
        binning: int = 1,
        bit_depth: int | None = None,
        source: str = "assumed",
        output: tuple[int, int] | None = None,
    ) -> SensorMode:
        """The whole of a ``width`` x ``height`` sensor, read out at ``binning`` (to ``output`` pixels)."""
        return cls(width, height, (0, 0, width, height), binning, bit_depth=bit_depth, source=source, output=output)

    @property
    def width(self) -> int:
        """Image width of the mode."""
        return self.output[0] if self.output else self.crop[2] // self.binning

    @property
    def height(self) -> int:
        """Image height of the mode."""
        return self.output[1] if self.output else self.crop[3] // self.binning

    @property
    def sensor_size(self) -> tuple[int, int]:
        """(width, height) of the full sensor."""
        return self.sensor_width, self.sensor_height

    @property
    def is_full(self) -> bool:
        """The mode reads the whole sensor (binned or not)."""
        return self.crop == (0, 0, self.sensor_width, self.sensor_height)

    def area(self) -> tuple[int, int, Box, int, bool, bool, int, int]:
        """What places the image on the sensor (everything but the bit depth and the source), for comparisons."""
        return (*self.sensor_size, self.crop, self.binning, self.hflip, self.vflip, self.width, self.height)

    def contains(self, box: Box, tolerance: int = 0) -> bool:
        """Whether the sensor area ``box`` (x, y, width, height, full-sensor pixels) lies inside this mode's crop,
        give or take ``tolerance`` pixels."""
        x, y, w, h = self.crop
        bx, by, bw, bh = box
        t = tolerance
        return bx >= x - t and by >= y - t and bx + bw <= x + w + t and by + bh <= y + h + t

    def describe(self) -> str:
        """One line: the image size, where it lies on the sensor, and where that came from."""
        x, y, w, h = self.crop
        where = f"the {w}x{h} area at ({x}, {y}) of the" if not self.is_full else "the whole"
        binning = f", {self.binning}x{self.binning} binned" if self.binning > 1 else ""
        flips = [name for name, on in (("h", self.hflip), ("v", self.vflip)) if on]
        flipped = f", {'+'.join(flips)}flip" if flips else ""
        bits = f", {self.bit_depth} bits" if self.bit_depth else ""
        return (
            f"{self.width}x{self.height}: {where} {self.sensor_width}x{self.sensor_height} sensor"
            f"{binning}{flipped}{bits} ({self.source})"
        )

    def to_record(self) -> dict[str, Any]:
        """The JSON record of a calibration's ``geometry``.

        Examples
        --------
        >>> SensorMode.full(640, 480).to_record()["crop"]
        [0, 0, 640, 480]
        """
        return {
            "sensor_size": [self.sensor_width, self.sensor_height],
            "crop": list(self.crop),
            "binning": self.binning,
            "hflip": self.hflip,
            "vflip": self.vflip,
            "bit_depth": self.bit_depth,
            "source": self.source,
            "size": [self.width, self.height],
        }

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> SensorMode:
        """The value of a record :meth:`to_record` wrote (its types checked by the calibration's schema)."""
        width, height = (int(v) for v in record["sensor_size"])
        x, y, w, h = (int(v) for v in record["crop"])
        bits, size = record.get("bit_depth"), record.get("size")
        return cls(
            width,
            height,
            (x, y, w, h),
            int(record.get("binning", 1)),
            bool(record.get("hflip", False)),
            bool(record.get("vflip", False)),
            None if bits is None else int(bits),
            str(record.get("source", "file")),
            None if size is None else (int(size[0]), int(size[1])),
        )


def driver_geometry(sensor_size: tuple[int, int], mode: DriverMode, source: str = "registry") -> SensorMode:
    """A driver's mode (:class:`picamcal.sensors.DriverMode`) on a sensor of ``sensor_size`` as a :class:`SensorMode`.

    Examples
    --------
    >>> from picamcal.sensors import sensor_modes
    >>> driver_geometry((3280, 2464), sensor_modes("imx219")[1]).binning
    2
    """
    binning = max(1, round(mode.crop[2] / mode.width))
    output = (mode.width, mode.height)
    return SensorMode(*sensor_size, mode.crop, binning, bit_depth=mode.bit_depth, source=source, output=output)


def _modes_of_size(sensor: str, width: int, height: int, bits: int | None) -> list[DriverMode]:
    """The registry sensor's modes of that size, those of ``bits`` first, then the deepest."""
    matches = [m for m in sensor_modes(sensor) if (m.width, m.height) == (width, height)]
    return sorted(matches, key=lambda m: (m.bit_depth != bits, -m.bit_depth))


def registry_mode(
    sensor: str | None, width: int, height: int, bit_depth: int | None = None, *, source: str = "registry"
) -> SensorMode | None:
    """The registry's mode of ``sensor`` that gives a ``width`` x ``height`` image, or None.

    Examples
    --------
    >>> registry_mode("imx219", 1920, 1080).crop
    (680, 692, 1920, 1080)
    >>> registry_mode("imx219", 1640, 1232).binning, registry_mode("imx219", 1000, 1000)
    (2, None)
    """
    entry = SENSORS.get(sensor or "")
    matches = _modes_of_size(entry.name, width, height, bit_depth) if entry else []
    return driver_geometry(entry.size, matches[0], source) if entry and matches else None


def mode_names(sensor: str) -> str:
    """The sizes of a registry sensor's modes, for messages.

    Examples
    --------
    >>> mode_names("imx219")
    '640x480, 1640x1232, 1920x1080, 3280x2464'
    """
    sizes = sorted({(m.width, m.height) for m in sensor_modes(sensor)})
    return ", ".join(f"{w}x{h}" for w, h in sizes)


def mode_from_crop(
    sensor_size: tuple[int, int], image_size: tuple[int, int], crop: Box, *, what: str = "--sensor-crop"
) -> SensorMode:
    """The mode of an image of ``image_size`` read from the sensor area ``crop`` (binning from their ratio).

    Raises
    ------
    PicamcalError
        The crop lies outside the sensor, or the image cannot come from it (its size is not the crop's divided by a
        whole binning); the message names ``what``.

    Examples
    --------
    >>> mode_from_crop((3280, 2464), (640, 480), (1000, 752, 1280, 960)).binning
    2
    """
    (sw, sh), (w, h) = sensor_size, image_size
    x, y, cw, ch = (int(v) for v in crop)
    if min(x, y) < 0 or min(cw, ch) < 1 or x + cw > sw or y + ch > sh:
        raise PicamcalError(f"{what} {x},{y},{cw},{ch} lies outside the {sw}x{sh} sensor")
    binning = max(1, round(cw / w))
    # A driver may read a little more than it sends (the OV5647's 1920 x 1080 mode reads 1928 columns).
    if abs(cw / binning - w) > max(1, w / 100) or abs(ch / binning - h) > max(1, h / 100):
        raise PicamcalError(
            f"{what} {x},{y},{cw},{ch}: a {w}x{h} image cannot come from a {cw}x{ch} sensor area (not a whole "
            "binning of it)"
        )
    return SensorMode(sw, sh, (x, y, cw, ch), binning, source="given", output=(w, h))


def mode_for_image(sensor_size: tuple[int, int], image_size: tuple[int, int], crop: Box | None = None) -> SensorMode:
    """The sensor mode an image of ``image_size`` comes from: full size, a binned full field, or an explicit crop.

    Raises
    ------
    PicamcalError
        The image is neither the full sensor nor an integer binning of it, and no crop is given.

    Examples
    --------
    >>> mode_for_image((3280, 2464), (1640, 1232)).binning
    2
    """
    if crop is not None:
        return mode_from_crop(sensor_size, image_size, crop)
    binning = full_field_binning(sensor_size, image_size)
    if binning is None:
        (sw, sh), (w, h) = sensor_size, image_size
        raise PicamcalError(
            f"a {w}x{h} image is not the full {sw}x{sh} sensor or a binned copy of it: give the sensor crop of its "
            "mode (--sensor-crop X,Y,WIDTH,HEIGHT in full-sensor pixels)"
        )
    return SensorMode.full(*sensor_size, binning=binning, output=image_size)


def full_field_binning(sensor_size: tuple[int, int], image_size: tuple[int, int]) -> int | None:
    """The binning (1 to 4) that makes the whole sensor an image of ``image_size``, or None.

    Examples
    --------
    >>> full_field_binning((2592, 1944), (1296, 972)), full_field_binning((2592, 1944), (1920, 1080))
    (2, None)
    """
    (sw, sh), (w, h) = sensor_size, image_size
    for binning in (1, 2, 3, 4):
        if (sw // binning, sh // binning) == (w, h) or (-(-sw // binning), -(-sh // binning)) == (w, h):
            return binning
    return None


def assumed_geometry(
    sensor: str | None, width: int, height: int, bit_depth: int | None = None, *, source: str = "assumed"
) -> SensorMode:
    """The geometry taken when nothing says it: the whole sensor (the registry's, binned to this size if it is a
    binned copy of it; else a sensor of this very size).

    Examples
    --------
    >>> assumed_geometry("imx219", 1640, 1232).binning, assumed_geometry("imx219", 1920, 1080).sensor_size
    (2, (1920, 1080))
    """
    entry = SENSORS.get(sensor or "")
    binning = full_field_binning(entry.size, (width, height)) if entry else None
    if entry is None or binning is None:
        return SensorMode.full(width, height, bit_depth=bit_depth, source=source)
    return SensorMode.full(*entry.size, binning=binning, bit_depth=bit_depth, source=source, output=(width, height))


def image_to_image(
    source: SensorMode, target: SensorMode, size: tuple[int, int] | None = None
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The affine map from an image of ``source`` to one of ``target``, per axis: ``u_t = a u_s + b``.

    Coordinates are continuous (pixel ``i`` spans ``[i, i + 1)``); ``size`` is the source image's size when it is
    not the mode's own (a processed stream the ISP scaled from the mode). Both modes must be of one sensor.

    Examples
    --------
    >>> full = SensorMode.full(3280, 2464)
    >>> binned = SensorMode.full(3280, 2464, binning=2)
    >>> image_to_image(binned, full)  # x and y double
    ((2.0, 0.0), (2.0, 0.0))
    >>> image_to_image(SensorMode(3280, 2464, (680, 692, 1920, 1080)), full)[0]  # the crop starts at x = 680
    (1.0, 680.0)
    """
    width, height = size or (source.width, source.height)
    axes = []
    for axis in (0, 1):
        n_source = (width, height)[axis]
        s0, s_len = source.crop[axis], source.crop[axis + 2]
        t0, t_len = target.crop[axis], target.crop[axis + 2]
        t_n = (target.width, target.height)[axis]
        s_flip = (source.hflip, source.vflip)[axis]
        t_flip = (target.hflip, target.vflip)[axis]
        # sensor = s0 + (n - u if flipped else u) * s_len / n; target u = (sensor - t0) * t_n / t_len, mirrored
        a = s_len / n_source * (-1 if s_flip else 1)
        b = s0 + (s_len if s_flip else 0.0)
        scale = t_n / t_len
        a, b = a * scale, (b - t0) * scale
        if t_flip:
            a, b = -a, t_n - b
        axes.append((float(a), float(b)))
    return axes[0], axes[1]


def sensor_area(mode: SensorMode, box: tuple[float, float, float, float]) -> Box:
    """The sensor area (full-sensor pixels, rounded outwards) of a box (x, y, width, height) of the mode's image.

    Examples
    --------
    >>> sensor_area(SensorMode.full(3280, 2464, binning=2), (0, 0, 1640, 1232))
    (0, 0, 3280, 2464)
    """
    full = SensorMode.full(mode.sensor_width, mode.sensor_height)
    (ax, bx), (ay, by) = image_to_image(mode, full)
    x, y, w, h = box
    xs = sorted((ax * x + bx, ax * (x + w) + bx))
    ys = sorted((ay * y + by, ay * (y + h) + by))
    x0, y0 = math.floor(xs[0] + 1e-6), math.floor(ys[0] + 1e-6)
    return x0, y0, math.ceil(xs[1] - 1e-6) - x0, math.ceil(ys[1] - 1e-6) - y0


def parse_sensor_crop(text: str | None, what: str = "--sensor-crop") -> Box | None:
    """``"X,Y,WIDTH,HEIGHT"`` as four whole numbers (X, Y at least 0, WIDTH, HEIGHT above 0), or None.

    Raises
    ------
    PicamcalError
        Not four such numbers; the message names ``what``.

    Examples
    --------
    >>> parse_sensor_crop("680,692,1920,1080")
    (680, 692, 1920, 1080)
    """
    if text is None:
        return None
    parts = [p.strip() for p in str(text).replace("x", ",").split(",")]
    try:
        values = [int(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 4 or min(values[:2]) < 0 or min(values[2:]) < 1:
        raise PicamcalError(
            f"{what} {text!r}: give X,Y,WIDTH,HEIGHT in full-sensor pixels, whole numbers (X and Y from 0)"
        )
    return values[0], values[1], values[2], values[3]


def parse_sensor_mode(text: str | None, what: str = "--sensor-mode") -> tuple[int, int, int | None] | None:
    """``"WIDTHxHEIGHT"`` or ``"WIDTHxHEIGHT:BITS"`` as (width, height, bits or None), or None.

    Examples
    --------
    >>> parse_sensor_mode("1920x1080:10"), parse_sensor_mode("1640x1232")
    ((1920, 1080, 10), (1640, 1232, None))
    """
    if text is None:
        return None
    size, _, bits = str(text).strip().partition(":")
    w, _, h = size.lower().partition("x")
    try:
        values = (int(w), int(h), int(bits) if bits else None)
    except ValueError:
        values = (0, 0, None)
    if values[0] < 1 or values[1] < 1 or (values[2] is not None and not 1 <= values[2] <= 16):
        raise PicamcalError(f"{what} {text!r}: give the mode's size as WIDTHxHEIGHT, optionally :BITS (1920x1080:10)")
    return values


def named_mode(sensor: str | None, text: str, what: str = "--sensor-mode") -> SensorMode:
    """The registry mode a ``--sensor-mode WxH[:BITS]`` option names.

    Raises
    ------
    PicamcalError
        The sensor is not known, or has no such mode; the message lists the modes it has.

    Examples
    --------
    >>> named_mode("imx477", "1332x990").crop
    (696, 528, 2664, 1980)
    """
    parsed = parse_sensor_mode(text, what)
    assert parsed is not None
    width, height, bits = parsed
    entry = SENSORS.get(sensor or "")
    if entry is None:
        raise PicamcalError(
            f"{what} {text}: the sensor is {'not known' if not sensor else sensor + ', not in the registry'}, so "
            "its modes are not either: give --sensor-crop X,Y,WIDTH,HEIGHT instead"
        )
    matches = [m for m in _modes_of_size(entry.name, width, height, bits) if bits in (None, m.bit_depth)]
    if not matches:
        modes = ", ".join(f"{m.width}x{m.height}:{m.bit_depth}" for m in sensor_modes(entry.name))
        raise PicamcalError(f"{what} {text}: the {entry.name} has no such mode (it has {modes})")
    return driver_geometry(entry.size, matches[0], "given")


def check_scaler_crop(mode: SensorMode, scaler_crop: Box, what: str = "ScalerCrop") -> Box:
    """``scaler_crop`` as four whole numbers, checked to lie inside the sensor mode's crop (a stream shows only what
    its mode reads: libcamera encloses the ISP's crop in the mode's image, ``applyScalerCrop`` in
    ``src/libcamera/pipeline/rpi/common/pipeline_base.cpp``).

    Raises
    ------
    PicamcalError
        Not four numbers, an empty area, or an area outside the sensor or the mode's crop; one line naming ``what``.

    Examples
    --------
    >>> binned = SensorMode.full(3280, 2464, binning=2)
    >>> check_scaler_crop(binned, (820, 616, 1640, 1232))  # a 2x zoom
    (820, 616, 1640, 1232)
    >>> check_scaler_crop(SensorMode(3280, 2464, (680, 692, 1920, 1080)), (0, 0, 3280, 2464))
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: ScalerCrop 0,0,3280,2464 lies outside the sensor mode's crop (the 1920x1080 area \
at (680, 692) of the 3280x2464 sensor): a stream shows only what its mode reads
    """
    try:
        x, y, w, h = (int(v) for v in scaler_crop)
    except (TypeError, ValueError):
        raise PicamcalError(f"{what} {scaler_crop!r} is not X,Y,WIDTH,HEIGHT in full-sensor pixels") from None
    if (x, y, w, h) != tuple(scaler_crop) or w < 1 or h < 1:
        raise PicamcalError(f"{what} {scaler_crop!r} is not X,Y,WIDTH,HEIGHT in whole full-sensor pixels")
    sensor_w, sensor_h = mode.sensor_size
    if x < 0 or y < 0 or x + w > sensor_w or y + h > sensor_h:
        raise PicamcalError(f"{what} {x},{y},{w},{h} lies outside the {sensor_w}x{sensor_h} sensor")
    if not mode.contains((x, y, w, h)):
        cx, cy, cw, ch = mode.crop
        raise PicamcalError(
            f"{what} {x},{y},{w},{h} lies outside the sensor mode's crop (the {cw}x{ch} area at ({cx}, {cy}) of the "
            f"{sensor_w}x{sensor_h} sensor): a stream shows only what its mode reads"
        )
    return x, y, w, h


def default_scaler_crop(mode: SensorMode, size: tuple[int, int]) -> Box:
    """The ScalerCrop libcamera gives a stream of ``size`` from ``mode`` until one is set: the largest area of the
    stream's aspect ratio centred in the mode's image, in full-sensor pixels.

    The Raspberry Pi pipeline's ``platformConfigure`` (``src/libcamera/pipeline/rpi/vc4/vc4.cpp``,
    ``pisp/pisp.cpp``): ``Size::boundedToAspectRatio`` of the mode's output size, ``centeredTo`` its centre, and
    ``scaleIspCrop`` to the sensor's pixels, in libcamera's integer arithmetic.

    Examples
    --------
    >>> binned = SensorMode.full(3280, 2464, binning=2)
    >>> default_scaler_crop(binned, (1640, 1232)), default_scaler_crop(binned, (1920, 1080))  # 4:3 and 16:9
    ((0, 0, 3280, 2464), (0, 310, 3280, 1844))
    """
    width, height = size
    out_w, out_h = mode.width, mode.height
    wide, tall = out_w * height, width * out_h
    w, h = (tall // height, out_h) if wide > tall else (out_w, wide // width)
    x, y = out_w // 2 - w // 2, out_h // 2 - h // 2
    cx, cy, cw, ch = mode.crop
    return x * cw // out_w + cx, y * ch // out_h + cy, w * cw // out_w, h * ch // out_h


def stream_positions(mode: SensorMode, size: tuple[int, int], scaler_crop: Box | None = None) -> tuple[np.ndarray, ...]:
    """Where each row and column of a processed stream lies in its sensor mode's image (pixel centres at integers).

    The ISP crops the mode's image to the ScalerCrop (libcamera's ``ispCrop``: the ScalerCrop translated to the mode's
    crop and scaled by the mode's output size over the crop's, ``applyScalerCrop``) and scales that to the stream's
    size, so stream pixel ``i`` (spanning ``[i, i + 1)``) is centred at ``x0 + (i + 0.5) w / W - 0.5`` of the mode's
    image. Mode flips mirror the mode's image inside its crop, not this map (libcamera takes the ScalerCrop as it is).

    Returns
    -------
    rows, columns : ndarray of float64

    Examples
    --------
    >>> rows, cols = stream_positions(SensorMode.full(3280, 2464, binning=2), (410, 308), (820, 616, 1640, 1232))
    >>> float(cols[0]), float(cols[-1])  # a 2x zoom, scaled by half: every other column of the mode's centre half
    (410.5, 1228.5)
    """
    x, y, w, h = mode.crop if scaler_crop is None else check_scaler_crop(mode, scaler_crop)
    cx, cy, cw, ch = mode.crop
    sx, sy = mode.width / cw, mode.height / ch  # the mode's pixels per sensor pixel (1 / binning)
    width, height = size
    cols = (x - cx) * sx + (np.arange(width) + 0.5) * w * sx / width - 0.5
    rows = (y - cy) * sy + (np.arange(height) + 0.5) * h * sy / height - 0.5
    return rows, cols
