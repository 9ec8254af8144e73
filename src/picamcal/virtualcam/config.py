"""Camera configurations as the Raspberry Pi pipeline handler generates and validates them.

``generate_configuration`` gives each role libcamera's defaults (``pipeline_base.cpp``
``PipelineHandlerBase::generateConfiguration``: raw at the sensor's resolution and its best 12-bit mode, CSI-2
packed; still YUV420 at the sensor's size; video YUV420 1920x1080; viewfinder XRGB8888 800x600). ``validate``
follows ``RPiCameraConfiguration::validate``: one colour space shared by the processed streams (``sYCC`` if none
given, its RGB variant for RGB streams), the orientation reachable with the sensor's flips (no transpose), the
sensor mode scored against the requested size and bit depth (``CameraData::findBestFormat``), the raw stream
forced to that mode with the Bayer order of the flips, then each platform's rules (``vc4.cpp``/``pisp.cpp``
``platformValidate``) and the drivers' strides (Unicam and the PiSP front end for raw, the ISP for the outputs).
A request it changes comes back ``Adjusted``; one it cannot meet (two raw streams, three outputs, an invalid sensor
configuration) ``Invalid``.

Examples
--------
>>> from picamcal.virtualcam.values import Size
>>> raw_stride("SRGGB12_CSI2P", 4056, "vc4"), raw_stride("RGGB_PISP_COMP1", 4056, "pisp")
(6112, 4096)
>>> output_layout("RGB888", Size(1332, 990), 0, "vc4").stride
4032
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..raw.packing import packed_row_bytes
from .controls import ConvertibleEnum
from .isp import Layout
from .values import (
    FORMATS,
    ColorSpace,
    Orientation,
    PixelFormat,
    Range,
    Rectangle,
    Size,
    SizeRange,
    YcbcrEncoding,
    _copy,
    colour_space_name,
    compose,
    inverse,
    orientation_bits,
    orientation_of,
    same_colour_space,
)

if TYPE_CHECKING:
    from .modes import ModeSpec


class StreamRole(enum.Enum):
    """libcamera's ``StreamRole`` (``py_enums.cpp``)."""

    StillCapture = 0
    VideoRecording = 1
    Viewfinder = 2
    Raw = 3

    def __str__(self) -> str:
        return f"StreamRole.{self.name}"


class ConfigurationStatus(ConvertibleEnum):
    """``CameraConfiguration.Status``."""

    Valid = 0
    Adjusted = 1
    Invalid = 2


#: The formats the ISP outputs write (``isp.write_output``); any other request becomes the first, as the drivers do.
#: The 16-bit RGB formats are the PiSP back end's only.
OUTPUT_FORMATS = ("YUV420", "YVU420", "NV12", "NV21", "RGB888", "BGR888", "XRGB8888", "XBGR8888")
_PISP_ONLY_FORMATS = ("RGB161616", "BGR161616")
_YUV_ONLY_SECOND_OUTPUT = {"vc4"}  # bcm2835-isp's low resolution output writes only YUV
# libcamera stream.cpp: the discrete sizes StreamFormats::sizes() lists for a range.
_RANGE_SIZES = (
    (160, 120), (240, 160), (320, 240), (400, 240), (480, 320), (640, 360), (640, 480), (720, 480), (720, 576),
    (768, 480), (800, 600), (854, 480), (960, 540), (960, 640), (1024, 576), (1024, 600), (1024, 768),
    (1152, 864), (1280, 1024), (1280, 1080), (1280, 720), (1280, 800), (1360, 768), (1366, 768), (1400, 1050),
    (1440, 900), (1536, 864), (1600, 1200), (1600, 900), (1680, 1050), (1920, 1080), (1920, 1200), (2048, 1080),
    (2048, 1152), (2048, 1536), (2160, 1080), (2560, 1080), (2560, 1440), (2560, 1600), (2560, 2048), (2960, 1440),
    (3200, 1800), (3200, 2048), (3200, 2400), (3440, 1440), (3840, 1080), (3840, 1600), (3840, 2160), (3840, 2400),
    (4096, 2160), (5120, 2160), (5120, 2880), (7680, 4320),
)  # fmt: skip


def _align(value: int, alignment: int) -> int:
    return -(-value // alignment) * alignment


def raw_stride(name: str, width: int, platform: str, requested: int = 0) -> int:
    """Bytes per row of a raw stream: Unicam aligns rows to 32 bytes (``BPL_ALIGNMENT``), the PiSP front end to 64
    (libpisp ``compute_optimal_stride``); a larger requested stride is kept (aligned)."""
    info = FORMATS[name]
    if info.packing == "PISP_COMP1":
        row = _align(width, 8)
    elif info.packing == "CSI2P":
        row = packed_row_bytes(width, info.bits)
    else:
        row = width * (1 if info.bits == 8 else 2)
    alignment = 64 if platform == "pisp" else 32
    return _align(max(row, requested), alignment)


def output_layout(name: str, size: Size, requested: int, platform: str) -> Layout:
    """Stride and frame size of an ISP output (bcm2835-isp ``get_bytesperline``/``get_sizeimage``; libpisp
    ``compute_optimal_stride`` with libcamera's doubled chroma stride for planar YUV)."""
    width, height = size.width, size.height
    planar = name in ("YUV420", "YVU420")
    semi = name in ("NV12", "NV21")
    channels = 4 if name.startswith("X") else 3 if name in ("RGB888", "BGR888") else 6 if "161616" in name else 1
    if platform == "pisp":
        if planar:
            chroma = _align(max(width, requested) // 2, 64)
            stride = 2 * chroma
        else:
            stride = _align(max(width * channels, requested), 64)
    elif channels == 3:
        stride = max(_align(width, 32) * 3, _align(requested, 32))
    else:
        stride = _align(max(width * channels, requested), 64 if channels == 4 else 32)
    frame = stride * height * 3 // 2 if (planar or semi) else stride * height
    return Layout(name, width, height, stride, frame)


class SensorConfiguration:
    """libcamera's ``SensorConfiguration``: ``bit_depth``, ``output_size``, ``analog_crop``, ``binning``,
    ``skipping``."""

    def __init__(self) -> None:
        self.bit_depth = 0
        self._output_size = Size()
        self._analog_crop = Rectangle()
        self._binning = (1, 1)
        self._skipping = (1, 1, 1, 1)

    output_size = property(lambda self: self._output_size, lambda self, v: setattr(self, "_output_size", _copy(v)))
    analog_crop = property(lambda self: self._analog_crop, lambda self, v: setattr(self, "_analog_crop", _copy(v)))

    @property
    def binning(self) -> tuple[int, int]:
        return self._binning

    @binning.setter
    def binning(self, value: Any) -> None:
        values = [int(v) for v in value]
        if len(values) != 2:
            raise RuntimeError("binning requires iterable of 2 values")
        self._binning = (values[0], values[1])

    @property
    def skipping(self) -> tuple[int, int, int, int]:
        return self._skipping

    @skipping.setter
    def skipping(self, value: Any) -> None:
        values = [int(v) for v in value]
        if len(values) != 4:
            raise RuntimeError("skipping requires iterable of 4 values")
        self._skipping = (values[0], values[1], values[2], values[3])

    def is_valid(self) -> bool:
        """``SensorConfiguration::isValid``: a bit depth, an output size, and binning and skipping that make sense."""
        if not self.bit_depth or not self.output_size.width or not self.output_size.height:
            return False
        if not self._binning[0] or not self._binning[1]:
            return False
        x_odd, x_even, y_odd, y_even = self._skipping
        return bool(x_odd and x_even and y_odd and y_even) and (x_odd + x_even) % 2 == 0 and (y_odd + y_even) % 2 == 0


class StreamFormats:
    """The pixel formats a stream can take, and their sizes (``StreamFormats``)."""

    def __init__(self, formats: dict[str, list[SizeRange]]) -> None:
        self._formats = formats

    @property
    def pixel_formats(self) -> list[PixelFormat]:
        return [PixelFormat(name) for name in sorted(self._formats, key=lambda n: _format_key(n))]

    def sizes(self, pixel_format: PixelFormat) -> list[Size]:
        ranges = self._formats.get(str(pixel_format), [])
        if all(r.min == r.max for r in ranges):
            sizes = [Size(r.min.width, r.min.height) for r in ranges]
        elif len(ranges) == 1:
            sizes = [Size(w, h) for w, h in _RANGE_SIZES if ranges[0].contains(Size(w, h))]
        else:
            return []
        return _sorted_sizes(sizes)

    def range(self, pixel_format: PixelFormat) -> SizeRange:
        ranges = self._formats.get(str(pixel_format), [])
        if not ranges:
            return SizeRange()
        if len(ranges) == 1:
            return SizeRange(ranges[0].min, ranges[0].max, ranges[0].hStep, ranges[0].vStep)
        low = min((r.min for r in ranges), key=lambda s: (s.width * s.height, s.width))
        high = max((r.max for r in ranges), key=lambda s: (s.width * s.height, s.width))
        return SizeRange(low, high, 0, 0)


def _format_key(name: str) -> tuple[int, int]:
    """libcamera orders a map of pixel formats by fourcc, then modifier."""
    pixel = PixelFormat(name)
    return pixel.fourcc, pixel.modifier


def _sorted_sizes(sizes: list[Size]) -> list[Size]:
    """Sizes in libcamera's ``Size`` order (``std::sort`` with ``operator<``)."""
    from functools import cmp_to_key

    return sorted(sizes, key=cmp_to_key(_compare_sizes))


def _compare_sizes(a: Size, b: Size) -> int:
    return -1 if a < b else (1 if b < a else 0)


class Stream:
    """A stream of the camera (a device node of the pipeline): its ``configuration`` once configured."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._configuration: StreamConfiguration | None = None

    @property
    def configuration(self) -> StreamConfiguration:
        """A copy of the configuration the stream was given."""
        if self._configuration is None:
            return StreamConfiguration(StreamFormats({}))
        return self._configuration.copy()

    def __repr__(self) -> str:
        return f"<libcamera.Stream '{self.name}'>"


class StreamConfiguration:
    """One stream of a camera configuration (``StreamConfiguration``)."""

    def __init__(self, formats: StreamFormats) -> None:
        self._formats = formats
        self._size = Size()
        self._pixel_format = PixelFormat()
        self.stride = 0
        self.frame_size = 0
        self.buffer_count = 0
        self._color_space: ColorSpace | None = None
        self._stream: Stream | None = None

    size = property(lambda self: self._size, lambda self, v: setattr(self, "_size", _copy(_checked(v, Size))))
    pixel_format = property(
        lambda self: self._pixel_format, lambda self, v: setattr(self, "_pixel_format", _checked(v, PixelFormat))
    )

    @property
    def color_space(self) -> ColorSpace | None:
        return self._color_space

    @color_space.setter
    def color_space(self, value: ColorSpace | None) -> None:
        self._color_space = None if value is None else _copy(_checked(value, ColorSpace))

    @property
    def stream(self) -> Stream | None:
        return self._stream

    @property
    def formats(self) -> StreamFormats:
        return self._formats

    def copy(self) -> StreamConfiguration:
        other = StreamConfiguration(self._formats)
        other.size, other.pixel_format, other.color_space = self.size, self.pixel_format, self.color_space
        other.stride, other.frame_size, other.buffer_count = self.stride, self.frame_size, self.buffer_count
        other._stream = self._stream
        return other

    def __str__(self) -> str:
        return f"{self.size}-{self.pixel_format}/{colour_space_name(self.color_space)}"


def _checked(value: Any, kind: type) -> Any:
    if not isinstance(value, kind):
        raise TypeError(f"incompatible type: expected libcamera.{kind.__name__}, got {type(value).__name__}")
    return value


class CameraConfiguration:
    """A camera configuration: its streams, ``sensor_config``, ``orientation``, and ``validate()``."""

    Status = ConfigurationStatus

    def __init__(self, data: Any) -> None:
        self._data = data
        self._configs: list[StreamConfiguration] = []
        self.sensor_config: SensorConfiguration | None = None
        self.orientation = Orientation.Rotate0
        # What validate() decided, for configure().
        self.sensor_mode: ModeSpec | None = None
        self.transform_bits = 0

    def __iter__(self) -> Any:
        return iter(self._configs)

    def __len__(self) -> int:
        return len(self._configs)

    def at(self, index: int) -> StreamConfiguration:
        if not 0 <= index < len(self._configs):
            raise IndexError("CameraConfiguration index out of range")
        return self._configs[index]

    @property
    def size(self) -> int:
        return len(self._configs)

    @property
    def empty(self) -> bool:
        return not self._configs

    def add(self, config: StreamConfiguration) -> None:
        self._configs.append(config)

    def validate(self) -> ConfigurationStatus:
        """``RPiCameraConfiguration::validate``."""
        return validate(self._data, self)


@dataclass
class _StreamParams:
    index: int
    cfg: StreamConfiguration


def is_raw(pixel: PixelFormat) -> bool:
    info = pixel.info
    return info is not None and info.kind == "raw"


def _validate_colour_spaces(config: CameraConfiguration) -> tuple[ConfigurationStatus, tuple[ColorSpace, ColorSpace]]:
    """``validateColorSpaces``: raw streams get RAW; the others share the first valid colour space (else sYCC),
    RGB streams its full-range RGB form."""
    status = ConfigurationStatus.Valid
    shared: ColorSpace | None = None
    presets = (ColorSpace.Sycc(), ColorSpace.Smpte170m(), ColorSpace.Rec709())
    for cfg in config:
        if is_raw(cfg.pixel_format):
            if cfg.color_space is not None and not same_colour_space(cfg.color_space, ColorSpace.Raw()):
                status = ConfigurationStatus.Adjusted
            cfg.color_space = ColorSpace.Raw()
            continue
        if cfg.color_space is not None and shared is None:
            space = cfg.color_space
            shared = next(
                (p for p in presets if (p.primaries, p.transferFunction) == (space.primaries, space.transferFunction)),
                None,
            )
    shared = shared or ColorSpace.Sycc()
    rgb = ColorSpace(shared)
    rgb.ycbcrEncoding, rgb.range = YcbcrEncoding.Null, Range.Full
    for cfg in config:
        info = cfg.pixel_format.info
        if same_colour_space(cfg.color_space, ColorSpace.Raw()):
            continue
        if info is not None and info.kind == "yuv" and not same_colour_space(cfg.color_space, shared):
            if cfg.color_space is not None:
                status = ConfigurationStatus.Adjusted
            cfg.color_space = shared
        if info is not None and info.kind == "rgb" and not same_colour_space(cfg.color_space, rgb):
            if cfg.color_space is not None and not same_colour_space(cfg.color_space, shared):
                status = ConfigurationStatus.Adjusted
            cfg.color_space = rgb
    return status, (shared, rgb)


def find_best_mode(modes: tuple[ModeSpec, ...], width: int, height: int, bit_depth: int) -> ModeSpec:
    """``CameraData::findBestFormat``: size closeness (smaller modes preferred, exact matches best), aspect ratio
    (x 1500) and bit depth (x 500); the last of equal scores wins."""

    def score(desired: float, actual: float) -> float:
        value = desired - actual
        if value < 0:
            value = -value / 8
        return value * 2 if actual != desired else value

    best, best_score = modes[0], float("inf")
    # The sensor's formats in media bus code order (a std::map): 10, 12, 14, 16 bits, then 8.
    for mode in sorted(modes, key=lambda m: {8: 99}.get(m.bit_depth, m.bit_depth)):
        total = score(width, mode.width) + score(height, mode.height)
        total += 1500.0 * score(width / height, mode.width / mode.height)
        total += abs(mode.bit_depth - bit_depth) * 500.0
        if total <= best_score:
            best, best_score = mode, total
    return best


def validate(data: Any, config: CameraConfiguration) -> ConfigurationStatus:
    """Validate (and adjust) a configuration for a camera (see the module docstring)."""
    if config.empty:
        return ConfigurationStatus.Invalid
    if config.sensor_config is not None and not config.sensor_config.is_valid():
        return ConfigurationStatus.Invalid
    status, spaces = _validate_colour_spaces(config)
    # computeTransform: the orientation asked for, from the mounting one; flips only.
    mounting = data.mounting_bits
    combined = compose(inverse(mounting), orientation_bits(config.orientation))
    if combined & 4 or not data.spec.supports_flips:
        if config.orientation != orientation_of(mounting):
            status = ConfigurationStatus.Adjusted
        config.orientation = orientation_of(mounting)
        combined = 0
    raws = [_StreamParams(i, c) for i, c in enumerate(config) if is_raw(c.pixel_format)]
    outs = [_StreamParams(i, c) for i, c in enumerate(config) if not is_raw(c.pixel_format)]
    raws.sort(key=lambda p: _size_key(p.cfg.size), reverse=True)
    outs.sort(key=lambda p: _size_key(p.cfg.size), reverse=True)
    if len(raws) > 1 or len(outs) > 2:
        return ConfigurationStatus.Invalid
    if config.sensor_config is not None:
        bits, size = config.sensor_config.bit_depth, config.sensor_config.output_size
    elif raws:
        info = raws[0].cfg.pixel_format.info
        bits, size = (info.bits if info else 12), raws[0].cfg.size
    else:
        bits, size = 12, outs[0].cfg.size
    if not size.width or not size.height:
        return ConfigurationStatus.Invalid
    mode = find_best_mode(data.spec.modes, size.width, size.height, bits)
    if config.sensor_config is not None and (mode.bit_depth, mode.width, mode.height) != (
        bits,
        size.width,
        size.height,
    ):
        return ConfigurationStatus.Invalid
    config.sensor_mode, config.transform_bits = mode, combined
    order = data.order_for(combined)
    for raw in raws:
        info = raw.cfg.pixel_format.info
        assert info is not None
        name = _raw_format(data.platform, order, mode.bit_depth, info.packing)
        if str(raw.cfg.pixel_format) != name or raw.cfg.size != Size(mode.width, mode.height):
            raw.cfg.pixel_format, raw.cfg.size = PixelFormat(name), Size(mode.width, mode.height)
            status = ConfigurationStatus.Adjusted
        raw.cfg.stride = raw_stride(name, mode.width, data.platform, raw.cfg.stride)
        raw.cfg.frame_size = raw.cfg.stride * mode.height
    for i, out in enumerate(outs):
        status = _validate_output(data.platform, out.cfg, i, outs[0].cfg.size, mode, status, spaces)
    return status


def _size_key(size: Size) -> Any:
    from functools import cmp_to_key

    return cmp_to_key(_compare_sizes)(size)


def _raw_format(platform: str, order: str, bits: int, packing: str) -> str:
    """The raw format each platform gives for a request's packing (vc4: packed or unpacked at the sensor's depth,
    8 bits always unpacked; pisp: 16-bit, or PiSP-compressed for a packed request)."""
    if platform == "pisp":
        return f"{order}_PISP_COMP1" if packing in ("CSI2P", "PISP_COMP1") else f"S{order}16"
    if packing == "PISP_COMP1":
        packing = "CSI2P"
    name = f"S{order}{bits}_CSI2P" if packing == "CSI2P" else f"S{order}{bits}"
    return name if name in FORMATS else f"S{order}{bits}"


def _validate_output(
    platform: str,
    cfg: StreamConfiguration,
    index: int,
    largest: Size,
    mode: ModeSpec,
    status: ConfigurationStatus,
    spaces: tuple[ColorSpace, ColorSpace],
) -> ConfigurationStatus:
    """The platform's rules for ISP output ``index`` (0 the largest), and the driver's format and stride."""
    size = Size(cfg.size.width, cfg.size.height)
    if platform == "pisp":
        # pisp.cpp: no more than 64x downscaling of the sensor's field at the output's aspect ratio.
        raw = Size(mode.width, mode.height).bounded_to_aspect_ratio(size) if size.width and size.height else size
        minimum = Size(((raw.width + 63) // 64 + 1) & ~1, ((raw.height + 63) // 64 + 1) & ~1)
        if size.width < minimum.width:
            size = Size(minimum.width, (size.height * minimum.width // max(size.width, 1) + 1) & ~1)
        if size.height < minimum.height:
            size = Size((size.width * minimum.height // max(size.height, 1) + 1) & ~1, minimum.height)
    size = size.bounded_to(largest)
    name = str(cfg.pixel_format)
    allowed = OUTPUT_FORMATS + (_PISP_ONLY_FORMATS if platform == "pisp" else ())
    if index == 1 and platform in _YUV_ONLY_SECOND_OUTPUT:
        allowed = OUTPUT_FORMATS[:4]
    if name not in allowed:
        name = allowed[0]
    if FORMATS[name].kind == "yuv":
        size = Size(size.width & ~1, size.height & ~1)
    if size != cfg.size or name != str(cfg.pixel_format):
        cfg.size, cfg.pixel_format = size, PixelFormat(name)
        status = ConfigurationStatus.Adjusted
    # The device gives the shared colour space, or its RGB form (updateStreamConfig).
    space = spaces[0] if FORMATS[name].kind == "yuv" else spaces[1]
    if not same_colour_space(cfg.color_space, space):
        cfg.color_space = space
        status = ConfigurationStatus.Adjusted
    layout = output_layout(name, size, cfg.stride, platform)
    cfg.stride, cfg.frame_size = layout.stride, layout.frame_size
    return status


def generate(data: Any, roles: list[StreamRole]) -> CameraConfiguration:
    """``generateConfiguration`` for the roles, in order."""
    config = CameraConfiguration(data)
    spec = data.spec
    sensor = Size(spec.width, spec.height)
    for role in roles:
        if not isinstance(role, StreamRole):
            raise TypeError(f"generate_configuration(): incompatible role {role!r}")
        if role == StreamRole.Raw:
            mode = find_best_mode(spec.modes, sensor.width, sensor.height, 12)
            formats: dict[str, list[SizeRange]] = {}
            # libcamera clears the flips when it registers the sensor: the raw formats it lists have the native
            # order (camera_sensor_legacy.cpp init), which a configuration then transforms.
            order = data.order_for(0)
            for m in spec.modes:
                name = _raw_format("vc4", order, m.bit_depth, "CSI2P")
                formats.setdefault(name, []).append(SizeRange(Size(m.width, m.height)))
            cfg = StreamConfiguration(StreamFormats(formats))
            cfg.size = Size(mode.width, mode.height)
            cfg.pixel_format = PixelFormat(_raw_format("vc4", order, mode.bit_depth, "CSI2P"))
            cfg.color_space, cfg.buffer_count = ColorSpace.Raw(), 2
        else:
            ranges = {name: [SizeRange(Size(32, 32), sensor, 2, 2)] for name in OUTPUT_FORMATS}
            cfg = StreamConfiguration(StreamFormats(ranges))
            if role == StreamRole.StillCapture:
                cfg.pixel_format, cfg.size, cfg.color_space, cfg.buffer_count = (
                    PixelFormat("YUV420"),
                    sensor,
                    ColorSpace.Sycc(),
                    1,
                )
            elif role == StreamRole.VideoRecording:
                cfg.pixel_format, cfg.size, cfg.color_space, cfg.buffer_count = (
                    PixelFormat("YUV420"),
                    Size(1920, 1080),
                    ColorSpace.Rec709(),
                    4,
                )
            else:
                cfg.pixel_format, cfg.size, cfg.color_space, cfg.buffer_count = (
                    PixelFormat("XRGB8888"),
                    Size(800, 600),
                    ColorSpace.Sycc(),
                    4,
                )
        config.add(cfg)
    return config
