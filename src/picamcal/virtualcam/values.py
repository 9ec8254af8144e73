"""The value types of libcamera's Python bindings: geometry, transforms, colour spaces and pixel formats.

They behave as the bindings' classes do (libcamera ``src/py/libcamera/py_geometry.cpp``, ``py_transform.cpp``,
``py_color_space.cpp``, ``py_main.cpp`` for ``PixelFormat``), with libcamera's own arithmetic
(``src/libcamera/geometry.cpp``, ``transform.cpp``, ``color_space.cpp``, ``pixel_format.cpp``):

- ``Size``, ``Rectangle``, ``Point``, ``SizeRange`` and ``PixelFormat`` compare by value and, as pybind11 makes a
  class that defines ``==`` without a hash, cannot be dictionary keys;
- ``Transform`` and ``ColorSpace`` define no ``==`` of their own (picamera2 adds one), so they compare and hash by
  identity until it does;
- setters copy what they are given, as the bindings copy C++ values.

Examples
--------
>>> Size(4056, 3040).bounded_to_aspect_ratio(Size(16, 9))
libcamera.Size(4056, 2281)
>>> print(Transform(rotation=180), PixelFormat("SRGGB12_CSI2P"))
<libcamera.Transform 'hvflip'> SRGGB12_CSI2P
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any


def _int(value: Any, what: str) -> int:
    """An integer argument as pybind11 takes one: ints (and bools, numpy integers), never floats."""
    if isinstance(value, float) or not hasattr(value, "__index__"):
        raise TypeError(f"{what}: incompatible function arguments (expected an integer, got {type(value).__name__})")
    return int(value)


class Point:
    """libcamera's ``Point``: ``x`` and ``y`` in pixels."""

    __hash__ = None  # type: ignore[assignment]

    def __init__(self, x: int = 0, y: int = 0) -> None:
        self.x, self.y = _int(x, "Point"), _int(y, "Point")

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Point) and (self.x, self.y) == (other.x, other.y)

    def __neg__(self) -> Point:
        return Point(-self.x, -self.y)

    def __str__(self) -> str:
        return f"({self.x}, {self.y})"

    def __repr__(self) -> str:
        return f"libcamera.Point({self.x}, {self.y})"


class Size:
    """libcamera's ``Size``: ``width`` and ``height``, with its alignment and aspect-ratio arithmetic."""

    __hash__ = None  # type: ignore[assignment]

    def __init__(self, width: int = 0, height: int = 0) -> None:
        self.width, self.height = _int(width, "Size"), _int(height, "Size")

    @property
    def is_null(self) -> bool:
        """Both dimensions zero."""
        return not self.width and not self.height

    def _set(self, width: int, height: int) -> Size:
        self.width, self.height = max(int(width), 0), max(int(height), 0)
        return Size(self.width, self.height)

    def align_down_to(self, h: int, v: int) -> Size:
        return self._set(self.width // h * h, self.height // v * v)

    def align_up_to(self, h: int, v: int) -> Size:
        return self._set(-(-self.width // h) * h, -(-self.height // v) * v)

    def bound_to(self, bound: Size) -> Size:
        return self._set(min(self.width, bound.width), min(self.height, bound.height))

    def expand_to(self, expand: Size) -> Size:
        return self._set(max(self.width, expand.width), max(self.height, expand.height))

    def grow_by(self, margins: Size) -> Size:
        return self._set(self.width + margins.width, self.height + margins.height)

    def shrink_by(self, margins: Size) -> Size:
        return self._set(self.width - margins.width, self.height - margins.height)

    def aligned_up_to(self, h: int, v: int) -> Size:
        return Size(-(-self.width // h) * h, -(-self.height // v) * v)

    def bounded_to(self, bound: Size) -> Size:
        return Size(min(self.width, bound.width), min(self.height, bound.height))

    def expanded_to(self, expand: Size) -> Size:
        return Size(max(self.width, expand.width), max(self.height, expand.height))

    def grown_by(self, margins: Size) -> Size:
        return Size(self.width + margins.width, self.height + margins.height)

    def shrunk_by(self, margins: Size) -> Size:
        return Size(max(self.width - margins.width, 0), max(self.height - margins.height, 0))

    def bounded_to_aspect_ratio(self, ratio: Size) -> Size:
        r1, r2 = self.width * ratio.height, ratio.width * self.height
        return Size(r2 // ratio.height, self.height) if r1 > r2 else Size(self.width, r1 // ratio.width)

    def expanded_to_aspect_ratio(self, ratio: Size) -> Size:
        r1, r2 = self.width * ratio.height, ratio.width * self.height
        return Size(r2 // ratio.height, self.height) if r1 < r2 else Size(self.width, r1 // ratio.width)

    def centered_to(self, center: Point) -> Rectangle:
        return Rectangle(center.x - self.width // 2, center.y - self.height // 2, self.width, self.height)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Size) and (self.width, self.height) == (other.width, other.height)

    def __lt__(self, other: Size) -> bool:
        # geometry.cpp operator<: both smaller, else both not smaller, else by area, else by width.
        if self.width < other.width and self.height < other.height:
            return True
        if self.width >= other.width and self.height >= other.height:
            return False
        la, ra = self.width * self.height, other.width * other.height
        return la < ra if la != ra else self.width < other.width

    def __le__(self, other: Size) -> bool:
        return self == other or self < other

    def __gt__(self, other: Size) -> bool:
        return other < self

    def __mul__(self, factor: float) -> Size:
        return Size(int(self.width * factor), int(self.height * factor))

    def __truediv__(self, factor: float) -> Size:
        return Size(int(self.width / factor), int(self.height / factor))

    def __str__(self) -> str:
        return f"{self.width}x{self.height}"

    def __repr__(self) -> str:
        return f"libcamera.Size({self.width}, {self.height})"


class SizeRange:
    """libcamera's ``SizeRange``: ``min``, ``max`` and the steps ``hStep``, ``vStep``."""

    __hash__ = None  # type: ignore[assignment]

    def __init__(self, *args: Any) -> None:
        self.hStep = self.vStep = 0
        self.min, self.max = Size(), Size()
        if len(args) == 1:
            self.min, self.max, self.hStep, self.vStep = _copy(args[0]), _copy(args[0]), 1, 1
        elif len(args) in (2, 4):
            self.min, self.max = _copy(args[0]), _copy(args[1])
            self.hStep, self.vStep = (1, 1) if len(args) == 2 else (int(args[2]), int(args[3]))

    def contains(self, size: Size) -> bool:
        w, h = size.width, size.height
        if not (self.min.width <= w <= self.max.width and self.min.height <= h <= self.max.height):
            return False
        return not (
            (self.hStep and (w - self.min.width) % self.hStep) or (self.vStep and (h - self.min.height) % self.vStep)
        )

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SizeRange) and self.min == other.min and self.max == other.max

    def __str__(self) -> str:
        return f"({self.min})-({self.max})/(+{self.hStep},+{self.vStep})"

    def __repr__(self) -> str:
        return (
            f"libcamera.SizeRange(({self.min.width}, {self.min.height}), ({self.max.width}, {self.max.height}), "
            f"{self.hStep}, {self.vStep})"
        )


class Rectangle:
    """libcamera's ``Rectangle``: ``x``, ``y``, ``width``, ``height``."""

    __hash__ = None  # type: ignore[assignment]

    def __init__(self, *args: Any) -> None:
        if not args:
            x, y, w, h = 0, 0, 0, 0
        elif len(args) == 1 and isinstance(args[0], Size):
            x, y, w, h = 0, 0, args[0].width, args[0].height
        elif len(args) == 3 and isinstance(args[2], Size):
            x, y, w, h = args[0], args[1], args[2].width, args[2].height
        elif len(args) == 4:
            x, y, w, h = args
        else:
            raise TypeError(f"Rectangle(): incompatible constructor arguments {args!r}")
        self.x, self.y = _int(x, "Rectangle"), _int(y, "Rectangle")
        self.width, self.height = _int(w, "Rectangle"), _int(h, "Rectangle")

    @property
    def is_null(self) -> bool:
        return not self.width and not self.height

    @property
    def center(self) -> Point:
        return Point(self.x + self.width // 2, self.y + self.height // 2)

    @property
    def size(self) -> Size:
        return Size(self.width, self.height)

    @property
    def topLeft(self) -> Point:
        return Point(self.x, self.y)

    def scaled_by(self, numerator: Size, denominator: Size) -> Rectangle:
        return Rectangle(
            _trunc_div(self.x * numerator.width, denominator.width),
            _trunc_div(self.y * numerator.height, denominator.height),
            self.width * numerator.width // denominator.width,
            self.height * numerator.height // denominator.height,
        )

    def translated_by(self, point: Point) -> Rectangle:
        return Rectangle(self.x + point.x, self.y + point.y, self.width, self.height)

    def scale_by(self, numerator: Size, denominator: Size) -> Rectangle:
        scaled = self.scaled_by(numerator, denominator)
        self.x, self.y, self.width, self.height = scaled.x, scaled.y, scaled.width, scaled.height
        return scaled

    def translate_by(self, point: Point) -> Rectangle:
        self.x, self.y = self.x + point.x, self.y + point.y
        return Rectangle(self.x, self.y, self.width, self.height)

    def bounded_to(self, bound: Rectangle) -> Rectangle:
        x, y = max(self.x, bound.x), max(self.y, bound.y)
        right = min(self.x + self.width, bound.x + bound.width)
        bottom = min(self.y + self.height, bound.y + bound.height)
        return Rectangle(x, y, max(right - x, 0), max(bottom - y, 0))

    def enclosed_in(self, boundary: Rectangle) -> Rectangle:
        result = self.bounded_to(Rectangle(self.x, self.y, boundary.size))
        result.x = min(max(result.x, boundary.x), boundary.x + boundary.width - result.width)
        result.y = min(max(result.y, boundary.y), boundary.y + boundary.height - result.height)
        return result

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Rectangle) and (self.x, self.y, self.width, self.height) == (
            other.x,
            other.y,
            other.width,
            other.height,
        )

    def __str__(self) -> str:
        return f"({self.x}, {self.y})/{self.width}x{self.height}"

    def __repr__(self) -> str:
        return f"libcamera.Rectangle({self.x}, {self.y}, {self.width}, {self.height})"


def _trunc_div(a: int, b: int) -> int:
    """C++ integer division (towards zero)."""
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b > 0) else -q


def _copy(value: Any) -> Any:
    """A copy of a geometry value, as the bindings copy C++ values in and out."""
    if isinstance(value, Size):
        return Size(value.width, value.height)
    if isinstance(value, Rectangle):
        return Rectangle(value.x, value.y, value.width, value.height)
    if isinstance(value, Point):
        return Point(value.x, value.y)
    if isinstance(value, ColorSpace):
        return ColorSpace(value)
    if isinstance(value, Transform):
        return Transform(value)
    return value


class _StrictEnum(enum.Enum):
    """A pybind11 enum of a C++ ``enum class``: equal only to itself, convertible with ``int()``."""

    def __int__(self) -> int:
        return int(self.value)

    def __str__(self) -> str:
        return f"{type(self).__name__}.{self.name}"


class Orientation(_StrictEnum):
    """libcamera's ``Orientation`` (``py_enums.cpp``), numbered as EXIF numbers them (``orientation.h``)."""

    Rotate0 = 1
    Rotate0Mirror = 2
    Rotate180 = 3
    Rotate180Mirror = 4
    Rotate90Mirror = 5
    Rotate270 = 6
    Rotate270Mirror = 7
    Rotate90 = 8


HFLIP, VFLIP, TRANSPOSE = 1, 2, 4
_TRANSFORM_NAMES = ("identity", "hflip", "vflip", "hvflip", "transpose", "rot270", "rot90", "rot180transpose")
# transform.cpp transformFromOrientation, and its inverse.
_ORIENTATION_BITS = {
    "Rotate0": 0,
    "Rotate0Mirror": HFLIP,
    "Rotate180": HFLIP | VFLIP,
    "Rotate180Mirror": VFLIP,
    "Rotate90Mirror": TRANSPOSE,
    "Rotate90": VFLIP | TRANSPOSE,
    "Rotate270Mirror": HFLIP | VFLIP | TRANSPOSE,
    "Rotate270": HFLIP | TRANSPOSE,
}
_ROTATIONS = {0: 0, 90: VFLIP | TRANSPOSE, 180: HFLIP | VFLIP, 270: HFLIP | TRANSPOSE}


def compose(t0: int, t1: int) -> int:
    """``t0 * t1`` of transform.cpp (t1 first, then t0), on the transforms' bit sets (hflip 1, vflip 2, transpose 4).

    Examples
    --------
    >>> compose(TRANSPOSE, HFLIP)  # a transpose after an hflip is a vflip after the transpose
    6
    """
    reordered = t1
    if t0 & TRANSPOSE:
        reordered = (t1 & TRANSPOSE) | (VFLIP if t1 & HFLIP else 0) | (HFLIP if t1 & VFLIP else 0)
    return reordered ^ t0


def inverse(t: int) -> int:
    """``-t`` of transform.cpp: every transform is its own inverse except rot90 and rot270."""
    return {VFLIP | TRANSPOSE: HFLIP | TRANSPOSE, HFLIP | TRANSPOSE: VFLIP | TRANSPOSE}.get(t, t)


def orientation_bits(orientation: Any) -> int:
    """The transform (bit set) that takes an image from ``Rotate0`` to ``orientation``."""
    return _ORIENTATION_BITS[orientation.name]


def orientation_of(bits: int) -> Any:
    """The orientation reached from ``Rotate0`` by the transform ``bits`` (transform.cpp ``operator*``)."""
    return next(o for o in Orientation if _ORIENTATION_BITS[o.name] == bits)


class Transform:
    """libcamera's ``Transform``: a rotation and flips (``py_transform.cpp``).

    Examples
    --------
    >>> t = Transform(hflip=True)
    >>> t.hflip, t.vflip, t.transpose, str(t.inverse())
    (True, False, False, "<libcamera.Transform 'hflip'>")
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        if args and isinstance(args[0], Transform):
            if len(args) > 1 or kwargs:
                raise TypeError("Transform(): incompatible constructor arguments")
            self._bits: int = args[0]._bits
            return
        names = ("rotation", "hflip", "vflip", "transpose")
        if len(args) > len(names) or set(kwargs) - set(names):
            raise TypeError("Transform(): incompatible constructor arguments")
        values = dict(zip(names, args, strict=False))
        values.update(kwargs)
        rotation = _int(values.get("rotation", 0), "Transform") % 360
        if rotation not in _ROTATIONS:
            raise ValueError("Invalid rotation")
        bits = _ROTATIONS[rotation]
        for name, bit in (("hflip", HFLIP), ("vflip", VFLIP), ("transpose", TRANSPOSE)):
            if values.get(name, False):
                bits ^= bit
        self._bits = bits

    def _flag(self, bit: int) -> bool:
        return bool(self._bits & bit)

    def _set(self, bit: int, on: bool) -> None:
        self._bits = self._bits | bit if on else self._bits & ~bit

    hflip = property(lambda self: self._flag(HFLIP), lambda self, on: self._set(HFLIP, bool(on)))
    vflip = property(lambda self: self._flag(VFLIP), lambda self, on: self._set(VFLIP, bool(on)))
    transpose = property(lambda self: self._flag(TRANSPOSE), lambda self, on: self._set(TRANSPOSE, bool(on)))

    def inverse(self) -> Transform:
        result = Transform()
        result._bits = inverse(self._bits)
        return result

    def invert(self) -> None:
        self._bits = inverse(self._bits)

    def compose(self, other: Transform) -> None:
        self._bits = compose(self._bits, other._bits)

    def __str__(self) -> str:
        return f"<libcamera.Transform '{_TRANSFORM_NAMES[self._bits]}'>"


class Primaries(_StrictEnum):
    Raw = 0
    Smpte170m = 1
    Rec709 = 2
    Rec2020 = 3


class TransferFunction(_StrictEnum):
    Linear = 0
    Srgb = 1
    Rec709 = 2


# "None" is the C++ name; the bindings call it Null (py_color_space.cpp).
class YcbcrEncoding(_StrictEnum):
    Null = 0
    Rec601 = 1
    Rec709 = 2
    Rec2020 = 3


class Range(_StrictEnum):
    Full = 0
    Limited = 1


# color_space.cpp: the presets and their short names.
_PRESETS = {
    "Raw": ((Primaries.Raw, TransferFunction.Linear, YcbcrEncoding.Null, Range.Full), "RAW"),
    "Srgb": ((Primaries.Rec709, TransferFunction.Srgb, YcbcrEncoding.Null, Range.Full), "sRGB"),
    "Sycc": ((Primaries.Rec709, TransferFunction.Srgb, YcbcrEncoding.Rec601, Range.Full), "sYCC"),
    "Smpte170m": ((Primaries.Smpte170m, TransferFunction.Rec709, YcbcrEncoding.Rec601, Range.Limited), "SMPTE170M"),
    "Rec709": ((Primaries.Rec709, TransferFunction.Rec709, YcbcrEncoding.Rec709, Range.Limited), "Rec709"),
    "Rec2020": ((Primaries.Rec2020, TransferFunction.Rec709, YcbcrEncoding.Rec2020, Range.Limited), "Rec2020"),
}
_PART_NAMES = {
    Primaries.Raw: "RAW",
    Primaries.Smpte170m: "SMPTE170M",
    Primaries.Rec709: "Rec709",
    Primaries.Rec2020: "Rec2020",
    TransferFunction.Linear: "Linear",
    TransferFunction.Srgb: "sRGB",
    TransferFunction.Rec709: "Rec709",
    YcbcrEncoding.Null: "None",
    YcbcrEncoding.Rec601: "Rec601",
    YcbcrEncoding.Rec709: "Rec709",
    YcbcrEncoding.Rec2020: "Rec2020",
    Range.Full: "Full",
    Range.Limited: "Limited",
}


class ColorSpace:
    """libcamera's ``ColorSpace``: primaries, transfer function, Y'CbCr encoding and range.

    Examples
    --------
    >>> str(ColorSpace.Sycc()), colour_space_name(ColorSpace.Rec709())
    ("<libcamera.ColorSpace 'sYCC'>", 'Rec709')
    """

    Primaries = Primaries
    TransferFunction = TransferFunction
    YcbcrEncoding = YcbcrEncoding
    Range = Range

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        if len(args) == 1 and not kwargs and isinstance(args[0], ColorSpace):
            other = args[0]
            args = (other.primaries, other.transferFunction, other.ycbcrEncoding, other.range)
        names = ("primaries", "transferFunction", "ycbcrEncoding", "range")
        values = dict(zip(names, args, strict=False))
        values.update(kwargs)
        if set(values) != set(names):
            raise TypeError("ColorSpace(): incompatible constructor arguments")
        self.primaries: Primaries = Primaries(values["primaries"])
        self.transferFunction: TransferFunction = TransferFunction(values["transferFunction"])
        self.ycbcrEncoding: YcbcrEncoding = YcbcrEncoding(values["ycbcrEncoding"])
        self.range: Range = Range(values["range"])

    def _parts(self) -> tuple[Any, ...]:
        return (self.primaries, self.transferFunction, self.ycbcrEncoding, self.range)

    def __str__(self) -> str:
        return f"<libcamera.ColorSpace '{colour_space_name(self)}'>"

    @staticmethod
    def Raw() -> ColorSpace:
        return ColorSpace(*_PRESETS["Raw"][0])

    @staticmethod
    def Srgb() -> ColorSpace:
        return ColorSpace(*_PRESETS["Srgb"][0])

    @staticmethod
    def Sycc() -> ColorSpace:
        return ColorSpace(*_PRESETS["Sycc"][0])

    @staticmethod
    def Smpte170m() -> ColorSpace:
        return ColorSpace(*_PRESETS["Smpte170m"][0])

    @staticmethod
    def Rec709() -> ColorSpace:
        return ColorSpace(*_PRESETS["Rec709"][0])

    @staticmethod
    def Rec2020() -> ColorSpace:
        return ColorSpace(*_PRESETS["Rec2020"][0])


def same_colour_space(a: ColorSpace | None, b: ColorSpace | None) -> bool:
    """libcamera's ``ColorSpace::operator==`` (every field), with None as an unset ``std::optional``."""
    if a is None or b is None:
        return a is b
    return ColorSpace._parts(a) == ColorSpace._parts(b)


def colour_space_name(space: ColorSpace | None) -> str:
    """libcamera's ``ColorSpace::toString``: a preset's short name, else the four parts; ``Unset`` for None."""
    if space is None:
        return "Unset"
    parts = ColorSpace._parts(space)
    for preset, name in _PRESETS.values():
        if parts == preset:
            return name
    return "/".join(_PART_NAMES[p] for p in parts)


@dataclass(frozen=True)
class FormatInfo:
    """What the pipeline needs to know of a pixel format (libcamera ``formats.yaml``, ``formats.cpp``).

    Attributes
    ----------
    name : str
    fourcc : str
        The DRM four-character code (``drm_fourcc.h``).
    modifier : int
        The DRM format modifier (CSI-2 packing, PiSP compression), else 0.
    kind : str
        ``rgb``, ``yuv`` or ``raw``.
    bits : int
        Bits per sample of a raw format (the compressed PiSP format counts as 16).
    order : str
        A Bayer format's order (``RGGB`` ...), else ``""``.
    packing : str
        ``""`` (unpacked), ``CSI2P`` or ``PISP_COMP1``.
    """

    name: str
    fourcc: str
    modifier: int = 0
    kind: str = "rgb"
    bits: int = 8
    order: str = ""
    packing: str = ""


_MIPI_CSI2_PACKED = (0x0B << 56) | 1  # drm_fourcc.h: fourcc_mod_code(MIPI, 1)
_PISP_COMPRESS_MODE1 = (0x0C << 56) | 1  # drm_fourcc.h: fourcc_mod_code(RPI, 1)
_BAYER_FOURCC = {  # drm_fourcc.h, by order then bit depth
    "RGGB": {8: "RGGB", 10: "RG10", 12: "RG12", 14: "RG14", 16: "RGB6"},
    "GRBG": {8: "GRBG", 10: "BA10", 12: "BA12", 14: "BA14", 16: "GR16"},
    "GBRG": {8: "GBRG", 10: "GB10", 12: "GB12", 14: "GB14", 16: "GB16"},
    "BGGR": {8: "BA81", 10: "BG10", 12: "BG12", 14: "BG14", 16: "BYR2"},
}


def _format_table() -> dict[str, FormatInfo]:
    table = {
        name: FormatInfo(name, fourcc)
        for name, fourcc in (
            ("RGB888", "RG24"),
            ("BGR888", "BG24"),
            ("XRGB8888", "XR24"),
            ("XBGR8888", "XB24"),
            ("RGB161616", "RG48"),
            ("BGR161616", "BG48"),
        )
    }
    for name, fourcc in (("YUV420", "YU12"), ("YVU420", "YV12"), ("NV12", "NV12"), ("NV21", "NV21"), ("YUYV", "YUYV")):
        table[name] = FormatInfo(name, fourcc, kind="yuv")
    table["MJPEG"] = FormatInfo("MJPEG", "MJPG", kind="yuv")
    for order, codes in _BAYER_FOURCC.items():
        for bits, fourcc in codes.items():
            table[f"S{order}{bits}"] = FormatInfo(f"S{order}{bits}", fourcc, 0, "raw", bits, order)
            if bits in (10, 12, 14):
                name = f"S{order}{bits}_CSI2P"
                table[name] = FormatInfo(name, fourcc, _MIPI_CSI2_PACKED, "raw", bits, order, "CSI2P")
        name = f"{order}_PISP_COMP1"
        table[name] = FormatInfo(name, codes[16], _PISP_COMPRESS_MODE1, "raw", 16, order, "PISP_COMP1")
    return table


#: The pixel formats the virtual camera knows, by libcamera's name.
FORMATS: dict[str, FormatInfo] = _format_table()


def _fourcc_value(code: str) -> int:
    return sum(ord(c) << (8 * i) for i, c in enumerate(code))


class PixelFormat:
    """libcamera's ``PixelFormat``: a DRM fourcc and modifier, made from its name (``PixelFormat("YUV420")``).

    An unknown name gives the invalid format, whose string is ``<INVALID>`` (``pixel_format.cpp``).

    Examples
    --------
    >>> PixelFormat("XBGR8888") == PixelFormat("XBGR8888"), str(PixelFormat("nonsense"))
    (True, '<INVALID>')
    """

    __hash__ = None  # type: ignore[assignment]

    def __init__(self, *args: Any) -> None:
        if len(args) == 1 and isinstance(args[0], str):
            info = FORMATS.get(args[0])
            self._fourcc, self._modifier = (_fourcc_value(info.fourcc), info.modifier) if info else (0, 0)
        elif len(args) == 2:
            self._fourcc, self._modifier = _int(args[0], "PixelFormat"), _int(args[1], "PixelFormat")
        elif not args:
            self._fourcc = self._modifier = 0
        else:
            raise TypeError(f"PixelFormat(): incompatible constructor arguments {args!r}")

    @property
    def fourcc(self) -> int:
        return self._fourcc

    @property
    def modifier(self) -> int:
        return self._modifier

    @property
    def info(self) -> FormatInfo | None:
        """The format's description, or None for an invalid or unknown one (not part of the bindings)."""
        return _BY_CODE.get((self._fourcc, self._modifier))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PixelFormat) and (self._fourcc, self._modifier) == (other._fourcc, other._modifier)

    def __str__(self) -> str:
        info = self.info
        if info is not None:
            return info.name
        if not self._fourcc and not self._modifier:
            return "<INVALID>"
        chars = "".join(chr((self._fourcc >> (8 * i)) & 0xFF) for i in range(4))
        return f"<{chars}>-0x{self._modifier:016x}" if self._modifier else f"<{chars}>"

    def __repr__(self) -> str:
        return f"libcamera.PixelFormat('{self}')"


_BY_CODE = {(_fourcc_value(info.fourcc), info.modifier): info for info in FORMATS.values()}
