"""The registry of Raspberry Pi camera sensors and their constants.

Every sensor constant the project uses lives here (FORMATS.md section 1). The Bayer order given
here is only the default for simulated sensors: files always carry their own order, and readers
take it from the file.
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import PicamcalError


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
    """

    name: str
    camera: str
    width: int
    height: int
    bit_depth: int
    black_level: int
    pixel_pitch_um: float
    default_pattern: str

    @property
    def white_level(self) -> int:
        """Largest raw value, ``2**bit_depth - 1``."""
        return (1 << self.bit_depth) - 1


SENSORS: dict[str, Sensor] = {
    s.name: s
    for s in (
        Sensor("ov5647", "Camera Module v1", 2592, 1944, 10, 16, 1.4, "GBRG"),
        Sensor("imx219", "Camera Module v2", 3280, 2464, 10, 64, 1.12, "BGGR"),
        Sensor("imx477", "HQ Camera", 4056, 3040, 12, 256, 1.55, "RGGB"),
        Sensor("imx708", "Camera Module 3", 4608, 2592, 10, 64, 1.4, "RGGB"),
    )
}


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
