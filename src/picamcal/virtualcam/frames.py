"""The virtual camera's sensor: the simulated optics looking at a scene, read out as raw frames of a sensor mode.

The optics are picamcal's simulator (:func:`picamcal.simulate.make_camera`: lenslets shifted for the stock lens
under normally incident light, hence vignetting and colour crosstalk), rendered once per mode and light as the
noiseless response (:func:`picamcal.simulate.expected_response`). Each frame scales it by the light the exposure
collects and adds noise:

- the exposure collects ``brightness * exposure_time / 10 ms * gain`` of the response at exposure 1 (the brightest
  white pixel at the white level), as :class:`picamcal.acquire.cameras.SimCamera` does;
- shot noise (Gaussian with the Poisson variance, in electrons at the optics' conversion gain) and read noise, both
  amplified by the analogue gain, then the black level, rounding and clipping at the mode's bit depth. The unit
  normal deviates come from a bank of twice a frame's worth drawn once per mode from the seed; each frame reads
  them from its own random offset, so frames stay independent while a frame costs no random number generation.

A binned mode is the optics simulated at the binned size (the same vignetting over the field, as binning keeps it);
a cropped mode is a crop of its binned field. A sensor mounted rotated 180 degrees sees the scene rotated; the
sensor's flips (which libcamera sets to undo the mounting) mirror the readout, so the frame shows the scene upright
and its Bayer order is the native one transformed (libcamera ``bayer_format.cpp`` ``BayerFormat::transform``).

Examples
--------
>>> from picamcal.virtualcam.modes import scaled_spec, sensor_spec
>>> spec = scaled_spec(sensor_spec("imx477"), (320, 240))
>>> sensor = VirtualSensor(spec, Scene("white"), seed=1)
>>> frame = sensor.capture(spec.modes[-1], exposure_us=4000, gain=1.0, sequence=0)
>>> frame.shape, frame.dtype.name, 256 < int(frame.mean()) < 4095
((240, 320), 'uint16', True)
"""

from __future__ import annotations

import functools
import threading
from pathlib import Path
from typing import Any

import numpy as np

from ..colour_wheel import wheel_layout, wheel_scene
from ..errors import PicamcalError
from ..sensors import black_level_at, get_sensor
from ..simulate import Optics, expected_response, make_camera
from .modes import ModeSpec, SensorSpec
from .timing import row_blocks

#: The exposure at which ``brightness`` is measured (:class:`picamcal.acquire.cameras.SimCamera`'s reference).
REFERENCE_EXPOSURE_US = 10_000.0
#: The scenes by name; any other value is an image file.
SCENES = ("white", "wheel")


class Scene:
    """What the camera looks at: a white diffuser, the colour-wheel target, or an image, under a light.

    Parameters
    ----------
    name : str
        ``white``, ``wheel`` or the path of an image file (shown as transmission, its sRGB values made linear).
    light : (float, float, float)
        Amounts of the light's red, green and blue primaries (1, 1, 1 is the white light).

    Raises
    ------
    PicamcalError
        An image that does not exist or cannot be read.
    """

    def __init__(self, name: str = "white", light: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> None:
        self.name = str(name)
        self._light = tuple(float(v) for v in light)
        self._image: np.ndarray | None = None
        self.version = 0
        if self.name not in SCENES:
            self._image = _read_image(Path(self.name))

    @property
    def light(self) -> tuple[float, ...]:
        """The light's amounts of red, green and blue."""
        return self._light

    def set_light(self, light: tuple[float, float, float]) -> None:
        """Change the light (the frames after the change see it)."""
        self._light = tuple(float(v) for v in light)
        self.version += 1

    def amounts(self, width: int, height: int) -> np.ndarray:
        """The scene's transmission times the light: (3,) for a uniform one, else (height, width, 3)."""
        light = np.asarray(self._light, dtype=np.float32)
        if self.name == "white":
            return light
        if self.name == "wheel":
            transmission = wheel_scene(wheel_layout(width, height))
        else:
            transmission = _resized(self._image, width, height)
        return transmission * light


def _read_image(path: Path) -> np.ndarray:
    """An image file's pixels as linear transmission on 0..1 (sRGB decoded)."""
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise PicamcalError("no such image for the virtual camera's scene (give white, wheel or an image file)", path)
    try:
        with Image.open(path) as image:
            rgb = np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0
    except (OSError, UnidentifiedImageError) as exc:
        raise PicamcalError(f"cannot read the scene image ({exc})", path) from None
    return np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _resized(image: np.ndarray | None, width: int, height: int) -> np.ndarray:
    """The image stretched to fill the field (nearest pixel)."""
    assert image is not None
    ys = (np.arange(height) * image.shape[0] // height).clip(0, image.shape[0] - 1)
    xs = (np.arange(width) * image.shape[1] // width).clip(0, image.shape[1] - 1)
    return image[ys][:, xs]


class _Rendered:
    """One mode's noiseless response per unit exposure, its digitisation and its bank of unit normal deviates.

    Both are kept as the sensor's flips read them out (:meth:`oriented`, :meth:`deviates`), so that a frame is read
    in memory order, with the same deviate at each sensor pixel as in any other orientation: one copy of each, turned
    when the flips change (mirroring is exact).
    """

    def __init__(
        self,
        response: np.ndarray,
        black: float,
        white: int,
        electrons_per_dn: float,
        read_noise: float,
        bank: np.ndarray,
    ) -> None:
        self.black, self.white = black, white
        self.electrons_per_dn, self.read_noise = electrons_per_dn, read_noise
        self.size = response.size
        self._oriented: tuple[tuple[bool, bool], np.ndarray] = ((False, False), response)
        self._bank: tuple[bool, np.ndarray] = (False, bank)
        self._lock = threading.Lock()

    def oriented(self, hflip: bool, vflip: bool) -> np.ndarray:
        """The response as read out with these flips (float32, C order)."""
        flips, response = self._oriented
        if flips == (hflip, vflip):
            return response
        with self._lock:
            flips, response = self._oriented
            if flips != (hflip, vflip):
                turned = response[:: -1 if vflip != flips[1] else 1, :: -1 if hflip != flips[0] else 1]
                response = np.ascontiguousarray(turned)
                self._oriented = ((hflip, vflip), response)
            return response

    def deviates(self, offset: int, hflip: bool, vflip: bool) -> tuple[np.ndarray, int, int]:
        """The bank as a frame read with these flips takes it from ``offset``: the bank (reversed where the rows are
        read mirrored), where the first row's deviates begin in it, and the step from row to row.

        A frame takes the deviates ``bank[offset:offset + size]`` as the sensor's rows, whatever the flips: the pixel
        at row ``y``, column ``x`` of the sensor takes ``bank[offset + y * width + x]``. Read out mirrored, each row's
        deviates are a run of the reversed bank, in order.
        """
        height, width = self._oriented[1].shape
        reversed_, bank = self._bank
        if reversed_ != hflip:
            with self._lock:
                reversed_, bank = self._bank
                if reversed_ != hflip:
                    bank = np.ascontiguousarray(bank[::-1])
                    reversed_ = hflip
                    self._bank = (reversed_, bank)
        if hflip:  # bank[k] is reversed[len - 1 - k]
            first = bank.size - offset - (height * width if vflip else width)
            return bank, first, width if vflip else -width
        return bank, offset + (height - 1) * width if vflip else offset, -width if vflip else width


#: The modes rendered in this process, shared by the sensors (picamera2 drops its camera manager, and with it the
#: camera, when its last ``Picamera2`` closes; the next one finds the rendering done), the oldest dropped first.
_RENDERED: dict[tuple, _Rendered] = {}
_RENDERED_KEPT = 3
_RENDERED_LOCK = threading.Lock()


class VirtualSensor:
    """The simulated sensor behind the virtual camera.

    Parameters
    ----------
    spec : SensorSpec
    scene : Scene
    seed : int
        Seed of the noise: frame ``n`` of a run draws from stream ``n`` of it.
    brightness : float
        Exposure fraction of the brightest white pixel at 10 ms and gain 1 under white light.
    optics : Optics, optional
        The simulator's physical parameters.
    """

    def __init__(
        self, spec: SensorSpec, scene: Scene, seed: int = 0, brightness: float = 0.25, optics: Optics | None = None
    ) -> None:
        self.spec, self.scene, self.seed = spec, scene, int(seed)
        self.brightness = float(brightness)
        self.optics = optics or Optics()

    def order(self, hflip: bool, vflip: bool) -> str:
        """The Bayer order of frames read with these flips."""
        order = self.spec.native_order
        rows = [order[:2], order[2:]]
        if hflip:
            rows = [row[::-1] for row in rows]
        if vflip:
            rows = rows[::-1]
        return "".join(rows)

    def _rendered(self, mode: ModeSpec) -> _Rendered:
        binning, spec, scene = mode.binning, self.spec, self.scene
        key = (
            (spec.name, spec.width, spec.height, spec.rotation, spec.native_order, scene.name, scene.light, self.seed),
            (self.optics, mode.width, mode.height, mode.bit_depth, binning, tuple(mode.crop)),
        )
        with _RENDERED_LOCK:
            if key in _RENDERED:
                return _RENDERED[key]
            field = (max(4, spec.width // binning // 2 * 2), max(4, spec.height // binning // 2 * 2))
            camera = make_camera(spec.name, pattern=spec.native_order, size=field, exposure=1.0, optics=self.optics)
            x, y = (v // binning // 2 * 2 for v in mode.crop[:2])
            x, y = min(x, field[0] - mode.width), min(y, field[1] - mode.height)
            amounts = self.scene.amounts(*field)
            if spec.rotation == 180 and amounts.ndim == 3:  # the scene reaches a sensor mounted upside down rotated
                amounts = np.ascontiguousarray(amounts[::-1, ::-1])
            response = expected_response(camera, amounts)[y : y + mode.height, x : x + mode.width]
            scale = 2.0 ** (mode.bit_depth - spec.bit_depth)
            bank_rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(self.seed, spawn_key=(1 << 30,))))
            rendered = _Rendered(
                np.ascontiguousarray(response * scale, dtype=np.float32),
                black_level_at(get_sensor(spec.name), mode.bit_depth),
                (1 << mode.bit_depth) - 1,
                self.optics.electrons_per_dn * 2.0 ** (10 - mode.bit_depth),
                self.optics.read_noise_dn * 2.0 ** (mode.bit_depth - 10),
                bank_rng.standard_normal(2 * mode.width * mode.height, dtype=np.float32),
            )
            while len(_RENDERED) >= _RENDERED_KEPT:
                del _RENDERED[next(iter(_RENDERED))]
            _RENDERED[key] = rendered
            return rendered

    def capture(
        self,
        mode: ModeSpec,
        exposure_us: float,
        gain: float,
        sequence: int,
        hflip: bool = False,
        vflip: bool = False,
        noise: bool = True,
    ) -> np.ndarray:
        """One raw frame of a mode: uint16 (height, width) at the mode's bit depth, flips applied.

        Parameters
        ----------
        mode : ModeSpec
        exposure_us, gain : float
            What the sensor applied.
        sequence : int
            The frame's number (its noise stream).
        hflip, vflip : bool
            The sensor's flips.
        noise : bool
            Shot and read noise.
        """
        rendered = self._rendered(mode)
        response = rendered.oriented(hflip, vflip)
        fraction = np.float32(self.brightness * exposure_us / REFERENCE_EXPOSURE_US * gain)
        shot = np.float32(gain / rendered.electrons_per_dn)
        read = np.float32((rendered.read_noise * gain) ** 2)
        offset = 0
        if noise:
            rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(self.seed, spawn_key=(sequence,))))
            offset = int(rng.integers(0, rendered.size + 1))
        bank, first, step = rendered.deviates(offset, hflip, vflip)
        height, width = response.shape
        kernel = _compiled_readout()
        if kernel is not None:
            frame = np.empty(response.shape, dtype=np.uint16)
            black, white = np.float32(rendered.black), np.float32(rendered.white)

            def read_out(start: int, stop: int) -> None:  # rows start..stop, each row's deviates a run of the bank
                rows = response[start:stop]
                at = first + start * step
                kernel(rows, bank, at, step, fraction, shot, read, black, white, noise, frame[start:stop])

            row_blocks("readout", read_out, height)
            return frame
        signal = response * fraction
        if noise:
            spread = signal * shot
            spread += read
            np.sqrt(spread, out=spread)
            spread *= bank[first + np.arange(height)[:, None] * step + np.arange(width)]
            signal += spread
        signal += np.float32(rendered.black)
        np.rint(signal, out=signal)
        np.clip(signal, 0, rendered.white, out=signal)
        return signal.astype(np.uint16)


def _readout_loop(  # pragma: no cover - compiled by numba
    response: np.ndarray,
    bank: np.ndarray,
    first: int,
    step: int,
    fraction: np.float32,
    shot: np.float32,
    read: np.float32,
    black: np.float32,
    white: np.float32,
    noise: bool,
    out: np.ndarray,
) -> None:
    """:meth:`VirtualSensor.capture` in one pass (for numba): the same float32 arithmetic, pixel by pixel, in memory
    order (the compiler vectorises it); row ``y``'s deviates are ``bank[first + y * step:]``."""
    height, width = response.shape
    zero = np.float32(0.0)
    for y in range(height):
        at = first + y * step
        source, dest, normal = response[y], out[y], bank[at : at + width]
        for x in range(width):
            value = source[x] * fraction
            if noise:
                value += np.sqrt(value * shot + read) * normal[x]
            value = np.rint(value + black)
            dest[x] = min(max(value, zero), white)


@functools.cache
def _compiled_readout() -> Any:
    """:func:`_readout_loop` compiled by numba (cached on disk), or None where numba is not installed."""
    try:
        import numba
    except ImportError:
        return None
    return numba.njit(cache=True, nogil=True)(_readout_loop)
