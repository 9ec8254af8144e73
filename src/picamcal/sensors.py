"""The registry of Raspberry Pi camera sensors and their constants.

Every sensor constant the project uses lives here (FORMATS.md section 1). The Bayer order given
here is only the default for simulated sensors: files always carry their own order, and readers
take it from the file.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass

from .errors import PicamcalError, PicamcalWarning, closest


@dataclass(frozen=True)
class LegacyMode:
    """A sensor mode of the legacy firmware's raw capture (JPEG with a BRCM block; FORMATS.md section 2).

    Attributes
    ----------
    modes : tuple of int
        raspistill/picamera ``sensor_mode`` numbers that give this size (empty where unnumbered).
    width, height : int
        Image size in pixels.
    bit_depth : int
        Bits per pixel in the block.
    block_size : int
        Bytes of the BRCM block (32768-byte header plus padded rows): the last ``block_size`` bytes of the file.
    """

    modes: tuple[int, ...]
    width: int
    height: int
    bit_depth: int
    block_size: int


@dataclass(frozen=True)
class DriverMode:
    """A sensor mode of the Linux driver (``drivers/media/i2c/<sensor>.c``: ``supported_modes``).

    Attributes
    ----------
    width, height : int
        Output size in pixels.
    bit_depth : int
        Bits per pixel of the mode's media bus code.
    crop : (x, y, width, height)
        The area of the active pixel array the mode reads (libcamera's ``analogCrop``, picamera2's ``crop_limits``).
    """

    width: int
    height: int
    bit_depth: int
    crop: tuple[int, int, int, int]


@dataclass(frozen=True)
class Sensor:
    """Constants of one image sensor.

    Attributes
    ----------
    name : str
        Lower-case sensor name as libcamera spells it (``"imx219"``); ``_mono`` marks a monochrome variant that
        has a tuning file of its own.
    camera : str
        The camera module (or kind of module) that carries it.
    width, height : int
        Full active pixel array in pixels (the sensor's largest mode).
    bit_depth : int
        Native bits per pixel of its raw output (its deepest mode).
    black_level : int
        Black level in native DN (libcamera's ``rpi.black_level`` is the same on a 16-bit scale).
    pixel_pitch_um : float
        Pixel pitch in micrometres.
    default_pattern : str or None
        Bayer order of the unflipped sensor, used by the simulator only; None for a monochrome sensor.
    legacy_model : str or None
        EXIF ``Model`` the legacy firmware writes in JPEG+raw files (LibRaw identifies files by it).
    legacy_modes : tuple of LegacyMode
        Raw modes of the legacy firmware; empty for sensors it does not support.
    monochrome : bool
        No colour filter array: picamcal, which unmixes colour crosstalk, refuses its images.
    legacy_ident : str
        What the legacy firmware's raw block starts with: ``BRCM``, ``BRCMo`` on the HQ camera.
    legacy_aliases : tuple of str
        Other EXIF ``Model`` texts of early legacy firmware that mean this sensor without naming it.
    binned_modes : tuple of (int, int)
        (width, height) of the driver's binned modes of the whole pixel array (2 x 2 and more; not the cropped
        ones), by which a frame that does not name its sensor can be told (:func:`sensors_of_size`).
    """

    name: str
    camera: str
    width: int
    height: int
    bit_depth: int
    black_level: int
    pixel_pitch_um: float
    default_pattern: str | None
    legacy_model: str | None = None
    legacy_modes: tuple[LegacyMode, ...] = ()
    monochrome: bool = False
    legacy_ident: str = "BRCM"
    legacy_aliases: tuple[str, ...] = ()
    binned_modes: tuple[tuple[int, int], ...] = ()

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the full pixel array."""
        return self.width, self.height

    @property
    def white_level(self) -> int:
        """Largest raw value, ``2**bit_depth - 1``."""
        return (1 << self.bit_depth) - 1


#: libcamera's lens shading grid (columns, rows) per target: it comes from the target, not the file.
LSC_GRIDS: dict[str, tuple[int, int]] = {"bcm2835": (16, 12), "pisp": (32, 32)}

# Sources, cited per entry: black levels from Raspberry Pi's libcamera tuning files
# (raspberrypi/libcamera src/ipa/rpi/vc4/data/<name>.json, rpi.black_level on a 16-bit scale: 4096 = 64 at
# 10 bits = 256 at 12); sizes, bit depths and the unflipped Bayer order from the Linux sensor drivers
# (drivers/media/i2c/<driver>.c: pixel array defines and media bus codes); pixel pitches from libcamera's
# src/libcamera/sensor/camera_sensor_properties.cpp (unitCellSize) where listed there, else the maker's datasheet.
SENSORS: dict[str, Sensor] = {
    s.name: s
    for s in (
        # ov5647.json 1024 (16 at 10 bits); ov5647.c 2592x1944 10-bit, ov5647_modes' 2x2 binned 1296x972 of the whole
        # array; unitCellSize 1400. The Bayer orders of the first four entries are the simulator's defaults since the
        # registry's first version; files carry their own.
        Sensor(
            "ov5647",
            "Camera Module v1",
            2592,
            1944,
            10,
            16,
            1.4,
            "GBRG",
            "RP_ov5647",
            (
                LegacyMode((0, 2, 3), 2592, 1944, 10, 6404096),
                LegacyMode((1,), 1920, 1080, 10, 2717696),
                LegacyMode((4,), 1296, 972, 10, 1625600),
                LegacyMode((5,), 1296, 730, 10, 1233920),
                LegacyMode((6, 7), 640, 480, 10, 445440),
            ),
            legacy_aliases=("testc",),  # early firmware's RP_testc (LibRaw does not take it)
            binned_modes=((1296, 972),),
        ),
        # imx219.json 4096 (64 at 10 bits); imx219.c 3280x2464 10-bit, supported_modes' "2x2 binned" 1640x1232;
        # unitCellSize 1120.
        Sensor(
            "imx219",
            "Camera Module v2",
            3280,
            2464,
            10,
            64,
            1.12,
            "BGGR",
            "RP_imx219",
            (
                LegacyMode((0, 2, 3), 3280, 2464, 10, 10270208),
                LegacyMode((1,), 1920, 1080, 10, 2678784),
                LegacyMode((4,), 1640, 1232, 10, 2628608),
                LegacyMode((5,), 1640, 922, 10, 1963008),
                LegacyMode((6,), 1280, 720, 10, 1233920),
                LegacyMode((7,), 640, 480, 10, 445440),
            ),
            binned_modes=((1640, 1232),),
        ),
        # imx477.json 4096 (256 at 12 bits); imx477.c 4056x3040 SRGGB12, "2x2 binned" 2028x1520; unitCellSize 1550.
        Sensor(
            "imx477",
            "HQ Camera",
            4056,
            3040,
            12,
            256,
            1.55,
            "RGGB",
            "RP_imx477",
            (
                LegacyMode((), 4056, 3040, 12, 18711040),
                LegacyMode((), 2028, 1520, 12, 4751360),
                LegacyMode((), 2028, 1080, 12, 3375104),
                LegacyMode((), 1012, 760, 10, 1015808),
            ),
            legacy_ident="BRCMo",
            binned_modes=((2028, 1520),),
        ),
        # The Camera Module 3 has no legacy raw format (libcamera only).
        # imx708.json 4096 (64 at 10 bits); imx708.c 4608x2592 SRGGB10, supported_modes_10bit_no_hdr's "regular 2x2
        # binned" 2304x1296; unitCellSize 1400.
        Sensor("imx708", "Camera Module 3", 4608, 2592, 10, 64, 1.4, "RGGB", binned_modes=((2304, 1296),)),
        # imx296.json 3840 (60 at 10 bits); imx296.c IMX296_PIXEL_ARRAY 1456x1088, SBGGR10_1X10 (Y10 when mono);
        # unitCellSize 3450.
        Sensor("imx296", "Global Shutter Camera", 1456, 1088, 10, 60, 3.45, "BGGR"),
        # imx296_mono.json 3840: the same sensor without a colour filter array.
        Sensor("imx296_mono", "IMX296 monochrome modules", 1456, 1088, 10, 60, 3.45, None, monochrome=True),
        # imx290.json 3840 (240 at 12 bits); imx290.c 1920x1080, SRGGB10/SRGGB12; unitCellSize 2900.
        Sensor("imx290", "IMX290 modules (third party)", 1920, 1080, 12, 240, 2.9, "RGGB"),
        # imx462.json 3840 (240 at 12 bits); driven by imx290.c (1920x1080, SRGGB12); unitCellSize 2900.
        Sensor("imx462", "IMX462 modules (third party)", 1920, 1080, 12, 240, 2.9, "RGGB"),
        # se327m12.json 3840 (240 at 12 bits); an IMX327 module, driven by imx290.c (1920x1080, SRGGB12);
        # unitCellSize 2900 (imx327).
        Sensor("se327m12", "SE327M12 module (IMX327)", 1920, 1080, 12, 240, 2.9, "RGGB"),
        # imx327.json (vc4 only) 3840 (240 at 12 bits); driven by imx290.c (model IMX327LQR, "sony,imx327lqr":
        # 1920x1080, SRGGB12); unitCellSize 2900.
        Sensor("imx327", "IMX327 modules (third party)", 1920, 1080, 12, 240, 2.9, "RGGB"),
        # imx378.json 4096 (256 at 12 bits); driven by imx477.c (4056x3040, SRGGB12, 2x2 binned 2028x1520); 1.55 um
        # (Sony IMX378).
        Sensor(
            "imx378", "IMX378 modules (third party)", 4056, 3040, 12, 256, 1.55, "RGGB", binned_modes=((2028, 1520),)
        ),
        # imx519.json 4096 (64 at 10 bits); imx519.c IMX519_PIXEL_ARRAY 4656x3496, SRGGB10 unflipped, 2328x1748
        # binned from the whole array; unitCellSize 1220.
        Sensor("imx519", "Arducam 16MP (IMX519)", 4656, 3496, 10, 64, 1.22, "RGGB", binned_modes=((2328, 1748),)),
        # imx500.json 4096 (64 at 10 bits); imx500.c 4056x3040 SRGGB10, imx500_supported_modes' "2x2 binned"
        # 2028x1520; 1.55 um (Sony IMX500).
        Sensor("imx500", "AI Camera", 4056, 3040, 10, 64, 1.55, "RGGB", binned_modes=((2028, 1520),)),
        # imx283.json 3200 (200 at 12 bits); imx283.c IMX283_PIXEL_ARRAY 5472x3648, SRGGB12 first, readout modes 2
        # ("2/2 binned", 2736x1824) and 3 ("3/3 binned", 1824x1216); unitCellSize 2400.
        Sensor(
            "imx283",
            "IMX283 modules (third party)",
            5472,
            3648,
            12,
            200,
            2.4,
            "RGGB",
            binned_modes=((2736, 1824), (1824, 1216)),
        ),
        # imx415.json 3840 (60 at 10 bits); imx415.c IMX415_PIXEL_ARRAY 3864x2192, SGBRG10; unitCellSize 1450.
        Sensor("imx415", "IMX415 modules (third party)", 3864, 2192, 10, 60, 1.45, "GBRG"),
        # imx335.json 3200 (200 at 12 bits); imx335.c IMX335_PIXEL_ARRAY 2592x1944, SRGGB12; unitCellSize 2000.
        Sensor("imx335", "IMX335 modules (third party)", 2592, 1944, 12, 200, 2.0, "RGGB"),
        # imx585.json 3200 (200 at 12 bits); imx585.c IMX585_PIXEL_ARRAY 3840x2160, SRGGB12; 2.9 um (Sony IMX585).
        Sensor("imx585", "IMX585 modules (third party)", 3840, 2160, 12, 200, 2.9, "RGGB"),
        # imx585_mono.json: the same sensor without a colour filter array.
        Sensor("imx585_mono", "IMX585 monochrome modules", 3840, 2160, 12, 200, 2.9, None, monochrome=True),
        # imx662.json black_level_func 3200 at gain 1 (200 at 12 bits; it rises with gain); imx662.c
        # IMX662_PIXEL_ARRAY 1920x1080, SRGGB12; 2.9 um (Sony IMX662).
        Sensor("imx662", "IMX662 modules (third party)", 1920, 1080, 12, 200, 2.9, "RGGB"),
        # ov64a40.json 4096 (64 at 10 bits); ov64a40.c OV64A40_PIXEL_ARRAY 9248x6944, SBGGR10 unflipped, "2x2
        # downscaled" 4624x3472 of the whole array; unitCellSize 1008.
        Sensor("ov64a40", "Arducam 64MP (OV64A40)", 9248, 6944, 10, 64, 1.008, "BGGR", binned_modes=((4624, 3472),)),
        # ov9281_mono.json 4096 (64 at 10 bits); ov9282.c 1280x800 Y10; unitCellSize 3000.
        Sensor("ov9281", "OV9281 global shutter modules", 1280, 800, 10, 64, 3.0, None, monochrome=True),
        # ov7251_mono.json 4096 (64 at 10 bits); ov7251.c 640x480 Y10; unitCellSize 3000.
        Sensor("ov7251", "OV7251 global shutter modules", 640, 480, 10, 64, 3.0, None, monochrome=True),
        # vd55g1.json 4096 (64 at 10 bits) is for the colour variant: vd55g1.c drives the VD55G1 (mono) and the VD65G4
        # (RGB), whose media bus codes are Bayer (vd55g1_mbus_formats_bayer, SRGGB10 unflipped); VD55G1_WIDTH x
        # VD55G1_HEIGHT 804x704, 8 or 10 bits; libcamera's pipeline adds "_mono" to a monochrome sensor's model to
        # name its tuning file (pipeline_base.cpp); unitCellSize 2160.
        Sensor("vd55g1", "VD55G1 family modules (colour: VD65G4)", 804, 704, 10, 64, 2.16, "RGGB"),
        # vd55g1_mono.json 4096: the VD55G1 itself, monochrome (Y8, Y10).
        Sensor("vd55g1_mono", "VD55G1 monochrome modules", 804, 704, 10, 64, 2.16, None, monochrome=True),
        # vd56g3.json 4096 (64 at 10 bits) is for the colour variant: vd56g3.c drives the VD56G3 (mono) and the VD66GY
        # (Bayer RGB: VD56G3_OPTICAL_REVISION_BAYER), SGRBG10 unflipped; VD56G3_NATIVE_WIDTH x _HEIGHT 1124x1364 (a
        # portrait sensor), 8 or 10 bits; unitCellSize 2610.
        Sensor("vd56g3", "VD56G3 family modules (colour: VD66GY)", 1124, 1364, 10, 64, 2.61, "GRBG"),
        # vd56g3_mono.json 4096: the VD56G3 itself, monochrome (Y8, Y10).
        Sensor("vd56g3_mono", "VD56G3 monochrome modules", 1124, 1364, 10, 64, 2.61, None, monochrome=True),
    )
}


def black_level_at(sensor: Sensor, bit_depth: int) -> float:
    """The sensor's black level in DN at another bit depth (it scales with the range).

    Examples
    --------
    >>> black_level_at(get_sensor("imx477"), 10)
    64.0
    """
    return sensor.black_level * 2.0 ** (bit_depth - sensor.bit_depth)


def get_sensor(name: str) -> Sensor:
    """Return the registry entry for a sensor name (case-insensitive).

    Raises
    ------
    PicamcalError
        The name is not in the registry: the message lists the known names (and the nearest one).

    Examples
    --------
    >>> get_sensor("IMX219").width
    3280
    """
    try:
        return SENSORS[name.lower()]
    except KeyError:
        key = _key(name) if isinstance(name, str) else ""
        slips = [known for known in SENSORS if _slip(key, _key(known))]
        near = or_list(slips) if slips else closest(name, SENSORS)
        hint = f"; did you mean {near}?" if near else ""
        raise PicamcalError(f"unknown sensor {name!r} (known: {', '.join(SENSORS)}){hint}") from None


def find_sensor_name(text: str | None) -> str | None:
    """Return the registry name that occurs in a free-text camera model string, or None.

    The longest name that occurs wins, so a variant with its own entry (``imx296_mono``) is not taken for its
    base sensor, and a model such as picamera2's ``"imx708_wide"`` gives ``"imx708"``.

    Examples
    --------
    >>> find_sensor_name("RP_imx477")
    'imx477'
    >>> find_sensor_name("imx708_wide_noir"), find_sensor_name("IMX296_MONO")
    ('imx708', 'imx296_mono')
    >>> find_sensor_name("Canon EOS") is None
    True
    """
    if not text:
        return None
    lowered = text.lower()
    return next((name for name in _BY_LENGTH if name in lowered), None)


_BY_LENGTH = sorted(SENSORS, key=len, reverse=True)


def sensors_of_size(width: int, height: int, bit_depth: int | None = None) -> tuple[str, ...]:
    """The colour sensors of the registry whose frames have this size: their full-resolution mode, a binned mode of
    the whole array (:attr:`Sensor.binned_modes`) or any mode of their driver, cropped ones included
    (:data:`DRIVER_MODES`: the IMX219's 1920x1080 is a crop), in registry order.

    With ``bit_depth``, a sensor whose deepest mode has fewer bits is left out (a 12-bit frame is no IMX219's); 16
    bits is the Pi 5's container for every depth, and leaves none out.

    One name identifies a frame that does not name its sensor (picamera2's DNGs, headless dumps); several are the
    sensors it could be. A monochrome variant is never among them: it shares its colour sensor's sizes, and
    picamcal calibrates colour sensors only.

    Examples
    --------
    >>> sensors_of_size(3280, 2464), sensors_of_size(1456, 1088)
    (('imx219',), ('imx296',))
    >>> sensors_of_size(4056, 3040), sensors_of_size(320, 240)
    (('imx477', 'imx378', 'imx500'), ())
    >>> sensors_of_size(1920, 1080, 10)
    ('ov5647', 'imx219', 'imx290', 'imx462', 'se327m12', 'imx327', 'imx662')
    >>> sensors_of_size(1920, 1080, 12), sensors_of_size(1332, 990)
    (('imx290', 'imx462', 'se327m12', 'imx327', 'imx662'), ('imx477',))
    """
    size = (width, height)

    def gives(sensor: Sensor) -> bool:
        if sensor.monochrome or (bit_depth is not None and bit_depth < 16 and sensor.bit_depth < bit_depth):
            return False
        sizes = (sensor.size, *sensor.binned_modes, *((m.width, m.height) for m in sensor_modes(sensor.name)))
        return size in sizes

    return tuple(s.name for s in SENSORS.values() if gives(s))


def size_note(names: tuple[str, ...] | list[str], width: int, height: int) -> str:
    """What is said of frames of ``width`` x ``height`` that do not name their sensor, by the registry sensors of
    that size (:func:`sensors_of_size`): taken as the one, or could be from several. It names no file: every frame
    of a folder or a batch gives the same one, shown once.

    Examples
    --------
    >>> size_note(("imx296",), 1456, 1088)
    'frames of 1456x1088 that do not name their sensor are taken as the imx296, the one sensor of that size ...'
    >>> size_note(("imx477", "imx378"), 4056, 3040)
    'frames of 4056x3040 that do not name their sensor could be from the imx477 or imx378: give --sensor NAME ...'
    """
    size = f"{width}x{height}"
    if len(names) == 1:
        return (
            f"frames of {size} that do not name their sensor are taken as the {names[0]}, the one sensor of that "
            "size (give --sensor if it is another)"
        )
    return (
        f"frames of {size} that do not name their sensor could be from the {or_list(names)}: give --sensor NAME to "
        "say which"
    )


def or_list(names: tuple[str, ...] | list[str]) -> str:
    """Names for a message: ``a``, ``a or b``, ``a, b or c``.

    Examples
    --------
    >>> or_list(["imx477", "imx378", "imx500"])
    'imx477, imx378 or imx500'
    """
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


def given_sensor(value: object, *, warn: bool = True) -> str:
    """A sensor the user names (``--sensor``, ``sensor=``): the registry's name for it, or the name of a sensor
    outside the registry.

    Case, separators and a variant's suffix are forgiven (``IMX-219`` and ``imx708_wide_noir`` are registry
    sensors). A near miss of a registry name (one character left out, added, swapped or mistyped, as ``imx2l9``) is
    refused with "did you mean"; a digit for a digit is another sensor's model number (``imx298`` is not the
    ``imx290``). Any other name is a sensor picamcal knows nothing of: it is kept (lower case), with a
    ``PicamcalWarning`` unless ``warn`` is false.

    Raises
    ------
    PicamcalError
        Not a name, or a near miss of a registry name.

    Examples
    --------
    >>> given_sensor("IMX-219"), given_sensor("imx708_wide")
    ('imx219', 'imx708')
    >>> given_sensor("imx298", warn=False)
    'imx298'
    >>> given_sensor("imx2l9")
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: unknown sensor 'imx2l9'; did you mean imx219?
    """
    if not isinstance(value, str) or not _key(value):
        raise PicamcalError(f"the sensor is a name such as 'imx219', not {value!r:.40}")
    text = " ".join(value.lower().split())
    exact = [name for name in SENSORS if _key(text) == _key(name)]
    if exact:
        return exact[0]
    slips = [name for name in SENSORS if _slip(_key(text), _key(name))]
    if slips:  # before the variants: imx296_mon is the imx296_mono mistyped, not a variant of the imx296
        raise PicamcalError(f"unknown sensor {value.strip()!r}; did you mean {or_list(slips)}?")
    for name in _BY_LENGTH:  # the longest first: imx296_mono_16mm is the imx296_mono
        if re.search(rf"(?:^|[^a-z0-9]){re.escape(name)}(?![0-9])", text):
            return name
    if warn:
        others = [name for name in SENSORS if _other_digit(_key(text), _key(name))]
        hint = f"; if it is the {or_list(others)}, give that name" if others else ""
        warnings.warn(
            f"sensor {text!r} is not in picamcal's registry: picamcal knows nothing of it (no black level, no stock "
            f"tuning file){hint}",
            PicamcalWarning,
            stacklevel=2,
        )
    return text


def _key(text: str) -> str:
    """A name's letters and digits, lower case: what tells two names apart."""
    return re.sub(r"[^a-z0-9]", "", text.lower())


def _slip(typed: str, name: str) -> bool:
    """Whether ``typed`` is ``name`` with one slip of the keys: a character left out, added, swapped with its
    neighbour, or replaced, but not a digit by a digit (that is another model number)."""
    if len(typed) == len(name):
        diff = [i for i, (a, b) in enumerate(zip(typed, name, strict=True)) if a != b]
        if len(diff) == 1:
            return not _other_digit(typed, name)
        if len(diff) != 2 or diff[1] != diff[0] + 1:
            return False
        i, j = diff
        return typed[i] == name[j] and typed[j] == name[i]
    longer, shorter = (typed, name) if len(typed) > len(name) else (name, typed)
    return len(longer) == len(shorter) + 1 and any(longer[:i] + longer[i + 1 :] == shorter for i in range(len(longer)))


def _other_digit(typed: str, name: str) -> bool:
    """Whether ``typed`` is ``name`` with one digit replaced by another: the model number of another sensor."""
    if len(typed) != len(name):
        return False
    diff = [(a, b) for a, b in zip(typed, name, strict=True) if a != b]
    return len(diff) == 1 and diff[0][0].isdigit() and diff[0][1].isdigit()


def _imx219_modes() -> tuple[DriverMode, ...]:
    # imx219.c supported_modes (crop relative to the active array), in 8 and 10 bits (imx219_mbus_formats).
    sizes = (
        (640, 480, (1000, 752, 1280, 960)),
        (1640, 1232, (0, 0, 3280, 2464)),
        (1920, 1080, (680, 692, 1920, 1080)),
        (3280, 2464, (0, 0, 3280, 2464)),
    )
    return tuple(DriverMode(w, h, bits, crop) for bits in (8, 10) for w, h, crop in sizes)


#: The driver's modes of the sensors whose driver tables picamcal holds, as libcamera lists them (by bit depth, then
#: size); other sensors have nominal modes (:func:`sensor_modes`). Sources: the Raspberry Pi kernel's drivers
#: (``drivers/media/i2c/<sensor>.c``), crops relative to the active array (without the PIXEL_ARRAY_LEFT/TOP offsets).
DRIVER_MODES: dict[str, tuple[DriverMode, ...]] = {
    # imx477.c supported_modes_12bit and _10bit.
    "imx477": (
        DriverMode(1332, 990, 10, (696, 528, 2664, 1980)),
        DriverMode(2028, 1080, 12, (0, 440, 4056, 2160)),
        DriverMode(2028, 1520, 12, (0, 0, 4056, 3040)),
        DriverMode(4056, 3040, 12, (0, 0, 4056, 3040)),
    ),
    "imx219": _imx219_modes(),
    # imx708.c supported_modes_10bit_no_hdr.
    "imx708": (
        DriverMode(1536, 864, 10, (768, 432, 3072, 1728)),
        DriverMode(2304, 1296, 10, (0, 0, 4608, 2592)),
        DriverMode(4608, 2592, 10, (0, 0, 4608, 2592)),
    ),
    # ov5647.c ov5647_modes.
    "ov5647": (
        DriverMode(640, 480, 10, (16, 0, 2560, 1920)),
        DriverMode(1296, 972, 10, (0, 0, 2592, 1944)),
        DriverMode(1920, 1080, 10, (348, 434, 1928, 1080)),
        DriverMode(2592, 1944, 10, (0, 0, 2592, 1944)),
    ),
}


def sensor_modes(name: str, size: tuple[int, int] | None = None) -> tuple[DriverMode, ...]:
    """The modes of a registry sensor: its driver's (:data:`DRIVER_MODES`), else nominal ones (its binned modes of
    the whole array and the full array, at its native bit depth); with ``size``, of the sensor reduced to that many
    pixels (:func:`scaled_mode`: the simulator's and the virtual camera's ``--size``).

    Examples
    --------
    >>> [(m.width, m.height, m.crop) for m in sensor_modes("imx477")][:2]
    [(1332, 990, (696, 528, 2664, 1980)), (2028, 1080, (0, 440, 4056, 2160))]
    >>> [(m.width, m.height) for m in sensor_modes("imx296")]
    [(1456, 1088)]
    >>> [(m.width, m.height, m.crop) for m in sensor_modes("imx219", (640, 480))][:2]
    [(124, 94, (196, 146, 248, 188)), (320, 240, (0, 0, 640, 480))]
    """
    sensor = get_sensor(name)
    if sensor.name in DRIVER_MODES:
        modes = DRIVER_MODES[sensor.name]
    else:
        full = (0, 0, sensor.width, sensor.height)
        modes = tuple(DriverMode(w, h, sensor.bit_depth, full) for w, h in (*sorted(sensor.binned_modes), sensor.size))
    if size is None or tuple(size) == sensor.size:
        return modes
    scaled = []
    for mode in modes:
        width, height, crop = scaled_mode(mode.width, mode.height, mode.crop, sensor.size, size)
        scaled.append(DriverMode(width, height, mode.bit_depth, crop))
    # Two modes may meet at one size on a small sensor: libcamera lists each size once per bit depth.
    return tuple({(m.bit_depth, m.width, m.height): m for m in scaled}.values())


def _even(value: float) -> int:
    return max(2, 2 * round(value / 2))


def scaled_mode(
    width: int, height: int, crop: tuple[int, int, int, int], full: tuple[int, int], size: tuple[int, int]
) -> tuple[int, int, tuple[int, int, int, int]]:
    """A mode of a sensor whose pixel array is reduced from ``full`` to ``size``: its output size, each scaled and
    kept even, and its crop, scaled, at the same binning and inside the reduced array.

    Examples
    --------
    >>> scaled_mode(1920, 1080, (680, 692, 1920, 1080), (3280, 2464), (640, 480))
    (374, 210, (132, 134, 374, 210))
    """
    sx, sy = size[0] / full[0], size[1] / full[1]
    binning = max(1, round(crop[2] / width))
    out = (_even(width * sx), _even(height * sy))
    area = (min(out[0] * binning, size[0]), min(out[1] * binning, size[1]))
    out = (area[0] // binning // 2 * 2, area[1] // binning // 2 * 2)
    x, y = crop[:2]
    origin = (min(_even(x * sx) if x else 0, size[0] - area[0]), min(_even(y * sy) if y else 0, size[1] - area[1]))
    return out[0], out[1], (origin[0], origin[1], out[0] * binning, out[1] * binning)
