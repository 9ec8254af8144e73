"""libcamera's controls and properties as its Python bindings show them: ids, types, enums, ranges.

The ids, types, sizes and enum values are those of libcamera's ``src/libcamera/control_ids_core.yaml``,
``control_ids_draft.yaml``, ``control_ids_rpi.yaml``, ``property_ids_core.yaml`` and ``property_ids_draft.yaml``
(numbered in file order from each vendor's base in ``control_ranges.yaml``: 0, draft 10000, rpi 20000); their
Python names follow ``src/py/libcamera/gen-py-controls.py`` (an enum's values lose the prefix they share), and
values cross the boundary as ``py_helpers.cpp`` converts them: arrays as tuples, floats through C++ ``float``,
integers refused when given as floats.

Examples
--------
>>> controls.ExposureTime.name, str(controls.ExposureTime.type), controls.draft.NoiseReductionMode.id
('ExposureTime', 'ControlType.Integer32', 10002)
>>> int(controls.draft.NoiseReductionModeEnum.Minimal), properties.draft.ColorFilterArrangementEnum.MONO
(3, <ColorFilterArrangementEnum.MONO: 5>)
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Iterable
from typing import Any

from .values import Point, Rectangle, Size


class ConvertibleEnum(enum.IntEnum):
    """A pybind11 enum of a plain C++ ``enum``: equal to its integer value, printed ``Type.Name``."""

    def __str__(self) -> str:
        return f"{type(self).__name__}.{self.name}"


class ControlType(ConvertibleEnum):
    """libcamera's ``ControlType`` as ``py_enums.cpp`` names it (C++ values of ``controls.h``)."""

    Null = 0
    Bool = 1
    Byte = 2
    Integer32 = 5
    Integer64 = 6
    Float = 7
    String = 8
    Rectangle = 9
    Size = 10
    Point = 11


_TYPES = {
    "bool": ControlType.Bool,
    "uint8": ControlType.Byte,
    "int32": ControlType.Integer32,
    "int64": ControlType.Integer64,
    "float": ControlType.Float,
    "string": ControlType.String,
    "Rectangle": ControlType.Rectangle,
    "Size": ControlType.Size,
    "Point": ControlType.Point,
}
DYNAMIC = 2**64 - 1  # size_t max: an array of any length ("[n]")


class ControlId:
    """A control (or property) id: ``id``, ``name``, ``vendor``, ``type``, ``isArray``, ``size``.

    Compared and hashed by identity, as the bindings' pointers are: one object per control.
    """

    def __init__(self, number: int, name: str, vendor: str, type_: ControlType, size: int, enums: dict[str, int]):
        self._id, self._name, self._vendor, self._type, self._size = number, name, vendor, type_, size
        self._enums = enums

    id = property(lambda self: self._id)
    name = property(lambda self: self._name)
    vendor = property(lambda self: self._vendor)
    type = property(lambda self: self._type)
    isArray = property(lambda self: self._size != 0)
    size = property(lambda self: self._size)

    def enumerators(self) -> dict[int, str]:
        """The enum's values and their C++ names."""
        return {value: name for name, value in self._enums.items()}

    def __str__(self) -> str:
        return self._name

    def __repr__(self) -> str:
        size = "" if not self._size else f"[{'n' if self._size == DYNAMIC else self._size}]"
        return f"libcamera.ControlId({self._id}, {self._vendor}.{self._name}{size}, {self._type})"


# One line per control: name, type (with [size] for arrays), then its enum values in order ("=N" to jump).
_CORE_CONTROLS = """
AeEnable bool
AeState int32 AeStateIdle AeStateSearching AeStateConverged
AeMeteringMode int32 MeteringCentreWeighted MeteringSpot MeteringMatrix MeteringCustom
AeConstraintMode int32 ConstraintNormal ConstraintHighlight ConstraintShadows ConstraintCustom
AeExposureMode int32 ExposureNormal ExposureShort ExposureLong ExposureCustom
ExposureValue float
ExposureTime int32
ExposureTimeMode int32 ExposureTimeModeAuto ExposureTimeModeManual
AnalogueGain float
AnalogueGainMode int32 AnalogueGainModeAuto AnalogueGainModeManual
AeFlickerMode int32 FlickerOff FlickerManual FlickerAuto
AeFlickerPeriod int32
AeFlickerDetected int32
Brightness float
Contrast float
Lux float
AwbEnable bool
AwbMode int32 AwbAuto AwbIncandescent AwbTungsten AwbFluorescent AwbIndoor AwbDaylight AwbCloudy AwbCustom
AwbLocked bool
ColourGains float[2]
ColourTemperature int32
Saturation float
SensorBlackLevels int32[4]
Sharpness float
FocusFoM int32
ColourCorrectionMatrix float[9]
ScalerCrop Rectangle
DigitalGain float
FrameDuration int64
FrameDurationLimits int64[2]
SensorTemperature float
SensorTimestamp int64
AfMode int32 AfModeManual AfModeAuto AfModeContinuous
AfRange int32 AfRangeNormal AfRangeMacro AfRangeFull
AfSpeed int32 AfSpeedNormal AfSpeedFast
AfMetering int32 AfMeteringAuto AfMeteringWindows
AfWindows Rectangle[n]
AfTrigger int32 AfTriggerStart AfTriggerCancel
AfPause int32 AfPauseImmediate AfPauseDeferred AfPauseResume
LensPosition float
AfState int32 AfStateIdle AfStateScanning AfStateFocused AfStateFailed
AfPauseState int32 AfPauseStateRunning AfPauseStatePausing AfPauseStatePaused
HdrMode int32 HdrModeOff HdrModeMultiExposureUnmerged HdrModeMultiExposure HdrModeSingleExposure HdrModeNight
HdrChannel int32 HdrChannelNone HdrChannelShort HdrChannelMedium HdrChannelLong
Gamma float
DebugMetadataEnable bool
FrameWallClock int64
WdrMode int32 WdrOff WdrLinear WdrPower WdrExponential WdrHistogramEqualization
WdrStrength float
WdrMaxBrightPixels float
LensDewarpEnable bool
LensShadingCorrectionEnable bool
Hue float
"""
_DRAFT_CONTROLS = """
AePrecaptureTrigger int32 AePrecaptureTriggerIdle AePrecaptureTriggerStart AePrecaptureTriggerCancel
NoiseReductionMode int32 NoiseReductionModeOff NoiseReductionModeFast NoiseReductionModeHighQuality \
NoiseReductionModeMinimal NoiseReductionModeZSL
ColorCorrectionAberrationMode int32 ColorCorrectionAberrationOff ColorCorrectionAberrationFast \
ColorCorrectionAberrationHighQuality
AwbState int32 AwbStateInactive AwbStateSearching AwbConverged AwbLocked
SensorRollingShutterSkew int64
LensShadingMapMode int32 LensShadingMapModeOff LensShadingMapModeOn
PipelineDepth int32
MaxLatency int32
TestPatternMode int32 TestPatternModeOff TestPatternModeSolidColor TestPatternModeColorBars \
TestPatternModeColorBarsFadeToGray TestPatternModePn9 TestPatternModeCustom1=256
FaceDetectMode int32 FaceDetectModeOff FaceDetectModeSimple FaceDetectModeFull
FaceDetectFaceRectangles Rectangle[n]
FaceDetectFaceScores uint8[n]
FaceDetectFaceLandmarks Point[n]
FaceDetectFaceIds int32[n]
"""
_RPI_CONTROLS = """
StatsOutputEnable bool
Bcm2835StatsOutput uint8[n]
ScalerCrops Rectangle[n]
PispStatsOutput uint8[n]
SyncMode int32 SyncModeOff SyncModeServer SyncModeClient
SyncReady bool
SyncTimer int64
SyncFrames int32
CnnOutputTensor float[n]
CnnOutputTensorInfo uint8[n]
CnnEnableInputTensor bool
CnnInputTensor uint8[n]
CnnInputTensorInfo uint8[n]
CnnKpiInfo int32[2]
"""
_CORE_PROPERTIES = """
Location int32 CameraLocationFront CameraLocationBack CameraLocationExternal
Rotation int32
Model string
UnitCellSize Size
PixelArraySize Size
PixelArrayOpticalBlackRectangles Rectangle[n]
PixelArrayActiveAreas Rectangle[n]
ScalerCropMaximum Rectangle
SensorSensitivity float
SystemDevices int64[n]
PipelineHandler string
"""
_DRAFT_PROPERTIES = """
ColorFilterArrangement int32 RGGB GRBG GBRG BGGR RGB MONO
"""


def _common_prefix(names: list[str]) -> str:
    """gen-py-controls.py's ``find_common_prefix``."""
    prefix = names[0]
    for name in names[1:]:
        while name[: len(prefix)] != prefix and prefix:
            prefix = prefix[:-1]
    return prefix


def _parse(text: str, vendor: str, base: int) -> list[tuple[ControlId, dict[str, int]]]:
    """The controls of one of the tables above, with their Python enum members (prefix removed)."""
    out = []
    lines = [line for line in text.replace("\\\n", "").strip().splitlines() if line.strip()]
    for number, line in enumerate(lines, start=base + 1):
        name, kind, *values = line.split()
        size = 0
        if "[" in kind:
            kind, dim = kind[:-1].split("[")
            size = DYNAMIC if dim == "n" else int(dim)
        enums: dict[str, int] = {}
        value = 0
        for item in values:
            label, _, given = item.partition("=")
            value = int(given) if given else value
            enums[label] = value
            value += 1
        out.append((ControlId(number, name, vendor, _TYPES[kind], size, enums), enums))
    return out


_make_enum: Any = ConvertibleEnum  # the functional Enum API, which type checkers do not follow


def _namespace(path: str, entries: list[tuple[ControlId, dict[str, int]]], prefixes: dict[str, str]) -> type:
    """A class holding the ids as attributes and one ``<Name>Enum`` per enum control, as the bindings do.

    ``path`` is where the class is reached from this module (``controls.draft``): the enums pickle by it, as the
    bindings' enums pickle (picamera2 sends configurations holding them to other processes).
    """
    attributes: dict[str, Any] = {"__doc__": f"libcamera's {path}.", "__qualname__": path}
    for control, enums in entries:
        attributes[control.name] = control
        if enums:
            prefix = prefixes.get(control.name, _common_prefix(list(enums)))
            members = [(label[len(prefix) :], value) for label, value in enums.items()]
            attributes[f"{control.name}Enum"] = _make_enum(
                f"{control.name}Enum", members, module=__name__, qualname=f"{path}.{control.name}Enum"
            )
    return type(path.rpartition(".")[2], (), attributes)


_core = _parse(_CORE_CONTROLS, "libcamera", 0)
_draft = _parse(_DRAFT_CONTROLS, "draft", 10000)
_rpi = _parse(_RPI_CONTROLS, "rpi", 20000)
_core_props = _parse(_CORE_PROPERTIES, "libcamera", 0)
_draft_props = _parse(_DRAFT_PROPERTIES, "draft", 10000)

controls: Any = _namespace("controls", _core, {})
controls.draft = _namespace("controls.draft", _draft, {"LensShadingMapMode": "LensShadingMapMode"})
controls.rpi = _namespace("controls.rpi", _rpi, {})
properties: Any = _namespace("properties", _core_props, {})
properties.draft = _namespace("properties.draft", _draft_props, {})

#: Every control id by name (the controls the metadata and requests use), and every property id.
CONTROLS: dict[str, ControlId] = {c.name: c for c, _ in (*_core, *_draft, *_rpi)}
PROPERTIES: dict[str, ControlId] = {c.name: c for c, _ in (*_core_props, *_draft_props)}


def enum_value(name: str, label: str) -> int:
    """The value of a control's enum member by its C++ name: ``enum_value("AeState", "AeStateConverged")`` is 2."""
    return next(c._enums[label] for c, _ in (*_core, *_draft, *_rpi) if c.name == name)


def as_float32(value: float) -> float:
    """A float as it comes back through C++ ``float``."""
    return struct.unpack("f", struct.pack("f", value))[0]


class ControlInfo:
    """The range of a control: ``min``, ``max``, ``default`` (None when libcamera gives none), ``values``.

    Examples
    --------
    >>> info = ControlInfo(1, 66666, 20000)
    >>> info.min, info.max, info.default, str(info)
    (1, 66666, 20000, '[1..66666]')
    """

    def __init__(self, minimum: Any = None, maximum: Any = None, default: Any = None, values: Iterable[Any] = ()):
        self._min, self._max, self._def, self._values = minimum, maximum, default, list(values)

    @classmethod
    def of_values(cls, values: Iterable[Any], default: Any = None) -> ControlInfo:
        """``ControlInfo(Span<const ControlValue>, def)``: min and max are the first and last values."""
        values = list(values)
        return cls(values[0], values[-1], default, values)

    min = property(lambda self: _out(self._min))
    max = property(lambda self: _out(self._max))
    default = property(lambda self: _out(self._def))
    values = property(lambda self: [_out(v) for v in self._values])

    def __str__(self) -> str:
        return f"[{_text(self._min)}..{_text(self._max)}]"

    def __repr__(self) -> str:
        return f"libcamera.ControlInfo({self})"


def _text(value: Any) -> str:
    """ControlValue::toString of a value."""
    if value is None:
        return "<ValueType Error>"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:f}"
    if isinstance(value, (tuple, list)):
        return "[ " + ", ".join(_text(v) for v in value) + " ]"
    return str(value)


def _out(value: Any) -> Any:
    """controlValueToPy: arrays as tuples of fresh objects, geometry values copied."""
    if isinstance(value, (tuple, list)):
        return tuple(_out(v) for v in value)
    if isinstance(value, Rectangle):
        return Rectangle(value.x, value.y, value.width, value.height)
    if isinstance(value, Size):
        return Size(value.width, value.height)
    if isinstance(value, Point):
        return Point(value.x, value.y)
    return value


def metadata_value(value: Any) -> Any:
    """What a metadata or property value looks like on the Python side (``controlValueToPy``)."""
    return _out(value)


def stored(control: ControlId, value: Any) -> Any:
    """A value as a ``ControlValue`` of the control's type holds it: floats through C++ ``float``, integers whole.

    Examples
    --------
    >>> stored(controls.ColourGains, (1.7, 1.2))
    (1.7000000476837158, 1.2000000476837158)
    >>> stored(controls.ExposureTime, 9994.9)
    9994
    """
    if isinstance(value, (tuple, list)):
        return tuple(stored(control, v) for v in value)
    if control.type == ControlType.Float:
        return as_float32(float(value))
    if control.type in (ControlType.Integer32, ControlType.Integer64, ControlType.Byte):
        return int(value)
    if control.type == ControlType.Bool:
        return bool(value)
    return value


def _scalar(value: Any, kind: ControlType, name: str) -> Any:
    if kind == ControlType.Bool:
        return bool(value)
    if kind in (ControlType.Integer32, ControlType.Integer64, ControlType.Byte):
        if isinstance(value, float) or not hasattr(value, "__index__"):
            raise RuntimeError(
                f"Unable to cast Python instance of type {type(value)} to C++ type "
                f"'{'long' if kind == ControlType.Integer64 else 'int'}' (control {name})"
            )
        return int(value)
    if kind == ControlType.Float:
        try:
            return as_float32(float(value))
        except (TypeError, ValueError):
            raise RuntimeError(f"Unable to cast Python instance of type {type(value)} to C++ type 'float'") from None
    expected = {ControlType.Rectangle: Rectangle, ControlType.Size: Size, ControlType.Point: Point}.get(kind)
    if expected is not None:
        if not isinstance(value, expected):
            raise RuntimeError(
                f"Unable to cast Python instance of type {type(value)} to C++ type 'libcamera::{expected.__name__}'"
            )
        return _out(value)
    if kind == ControlType.String:
        return str(value)
    return None


def control_value(control: ControlId, value: Any) -> Any:
    """``pyToControlValue``: a Python value for a control, converted by its type (lists and tuples as arrays).

    Raises
    ------
    RuntimeError
        A value the bindings cannot cast (a float for an integer control, a tuple for a Rectangle).
    """
    kind = control.type
    if kind not in (ControlType.Bool, ControlType.Size, ControlType.String) and isinstance(value, (list, tuple)):
        return tuple(_scalar(v, kind, control.name) for v in value)
    return _scalar(value, kind, control.name)
