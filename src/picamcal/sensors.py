"""The registry of Raspberry Pi camera sensors and their constants.

Every sensor constant the project uses lives here (FORMATS.md section 1). The Bayer order given
here is only the default for simulated sensors: files always carry their own order, and readers
take it from the file.
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import PicamcalError


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
class Sensor:
    """Constants of one image sensor.

    Attributes
    ----------
    name : str
        Lower-case sensor name as libcamera spells it (``"imx219"``).
    camera : str
        The Raspberry Pi camera module that carries it.
    width, height : int
        Full active pixel array in pixels.
    bit_depth : int
        Native bits per pixel of its raw output.
    black_level : int
        Black level in native DN.
    pixel_pitch_um : float
        Pixel pitch in micrometres.
    default_pattern : str
        Bayer order of the unflipped sensor, used by the simulator only.
    legacy_model : str or None
        EXIF ``Model`` the legacy firmware writes in JPEG+raw files (LibRaw identifies files by it).
    legacy_modes : tuple of LegacyMode
        Raw modes of the legacy firmware; empty for sensors it does not support.
    """

    name: str
    camera: str
    width: int
    height: int
    bit_depth: int
    black_level: int
    pixel_pitch_um: float
    default_pattern: str
    legacy_model: str | None = None
    legacy_modes: tuple[LegacyMode, ...] = ()

    @property
    def white_level(self) -> int:
        """Largest raw value, ``2**bit_depth - 1``."""
        return (1 << self.bit_depth) - 1


#: libcamera's lens shading grid (columns, rows) per target: it comes from the target, not the file.
LSC_GRIDS: dict[str, tuple[int, int]] = {"bcm2835": (16, 12), "pisp": (32, 32)}

SENSORS: dict[str, Sensor] = {
    s.name: s
    for s in (
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
        ),
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
        ),
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
        ),
        # The Camera Module 3 has no legacy raw format (libcamera only).
        Sensor("imx708", "Camera Module 3", 4608, 2592, 10, 64, 1.4, "RGGB"),
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

    Examples
    --------
    >>> get_sensor("IMX219").width
    3280
    """
    try:
        return SENSORS[name.lower()]
    except KeyError:
        known = ", ".join(SENSORS)
        raise PicamcalError(f"unknown sensor {name!r} (known: {known})") from None


def find_sensor_name(text: str | None) -> str | None:
    """Return the registry name that occurs in a free-text camera model string, or None.

    Examples
    --------
    >>> find_sensor_name("RP_imx477")
    'imx477'
    >>> find_sensor_name("Canon EOS") is None
    True
    """
    if not text:
        return None
    lowered = text.lower()
    for name in SENSORS:
        if name in lowered:
            return name
    return None
