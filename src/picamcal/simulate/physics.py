"""The physics of the simulated sensor: lenslets, colour filters and photodiodes under normally incident light.

The model follows the paper's section "Chief Ray Angle compensation" and its Figure "lenslets": every
pixel has a lenslet, a colour filter and a photodiode. To suit the oblique chief rays of the stock phone
lens, the lenslets are spaced slightly closer than the pixels, so away from the centre each lenslet sits
shifted towards the sensor centre. Under normally incident light (a microscope, a lens made for a larger
sensor, the paper's LED jig) the focused spot then misses its own photodiode: the response falls off
towards the edges (vignetting), and part of the light lands on the neighbouring photodiodes, which sit
under filters of other colours (colour crosstalk, hence desaturated colours at the edges).

All lengths are in pixels; pixel centres are at integer coordinates and the sensor centre is
``c = ((W - 1) / 2, (H - 1) / 2)``.

1. Filtered light at lenslet ``P`` with filter colour ``f(P)`` (from the Bayer pattern)::

       L(P) = T[f] * sum_l S[f, l] * a_l(P) * scale

   where ``a(P)`` are the amounts of the red, green and blue primaries (LEDs or screen) in the scene,
   ``S`` the spectral overlap of filter ``f`` and primary ``l``, ``T`` the channel sensitivity and
   ``scale`` the illumination that exposes the brightest white pixel to ``exposure`` of the range.
2. The spot of lenslet ``P`` lands at ``P + d(P)`` with ``d(P) = -k (P - c) + t``: ``k`` makes the shift
   ``lenslet_shift_corner`` pixels at the corner, and a tilt of the sensor adds
   ``t = stack_height * (tan(tilt_x), tan(tilt_y))``, which moves the vignetting centre by ``t / k``.
3. The spot is a Gaussian whose width depends on the filter colour (the lenslets are not achromatic);
   photodiode ``Q`` is a square of width ``a``. The fraction of ``P``'s light that ``Q`` collects is
   ``box(Qx - Px - dx; s) * box(Qy - Py - dy; s)`` with ``box(u; s) = Phi((u + a/2)/s) - Phi((u - a/2)/s)``,
   ``d`` evaluated at ``Q`` (it varies slowly), summed over the 5x5 lenslets around ``Q``. Light beyond
   the frame is the mirror image of the frame (numpy ``"reflect"``, which keeps the Bayer parity).
4. Shot noise (Poisson in electrons), Gaussian read noise, the black level, rounding and clipping to
   ``[0, white_level]`` give the raw mosaic.

The sum in step 3 is evaluated per 2x2 site parity of ``Q``: for a given parity and offset the colour of
the source lenslet is fixed, and the box factors are 1-D arrays along x and y, so the whole frame is a few
dozen shifted slices times row and column weights (an 8-megapixel frame renders in about a second).

Examples
--------
>>> camera = make_camera("imx219", size=(320, 240))
>>> raw = render(camera, "white", rng=1)
>>> raw.bayer.shape, raw.pattern, raw.metadata["scene"]
((240, 320), 'BGGR', 'white')
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import ndtr

from ..bayer import balance_gains, bin_sites
from ..errors import PicamcalError
from ..limits import MAX_PIXELS_VARIABLE, max_pixels
from ..raw.model import PATTERNS, RawImage, site_channels
from ..references import COLOURS, ROLES
from ..sensors import get_sensor

__all__ = [
    "MAX_DUST",
    "REFERENCE_AMOUNTS",
    "Optics",
    "SimulatedCamera",
    "check_dust_count",
    "dust_specks",
    "expected_response",
    "ground_truth",
    "make_camera",
    "readout",
    "render",
    "white_balance_gains",
]


def _reference_amounts(role: str) -> tuple[float, float, float]:
    if role == "white":
        return (1.0, 1.0, 1.0)
    red, green, blue = (float(role == colour) for colour in COLOURS)
    return (red, green, blue)


#: Amounts of the red, green and blue primaries (LEDs) of each reference illumination, keyed by
#: :data:`picamcal.references.ROLES` in their order: all three for the white, one for each colour, none for the black.
REFERENCE_AMOUNTS = {role: _reference_amounts(role) for role in ROLES}

_OFFSETS = range(-2, 3)  # lenslets P = Q - n that can reach photodiode Q
_PAD = 2

_EXPOSURE_TIME_S = 0.01
_ANALOGUE_GAIN = 1.0

#: The most dust specks a white reference gets: far more than any real sensor shows, and each costs a blob of up
#: to 250 x 250 pixels to render.
MAX_DUST = 1000


@dataclass(frozen=True)
class Optics:
    """Physical parameters of the simulated pixel stack (lenslet, colour filter, photodiode) and readout.

    The defaults are tuned so that a full-size IMX219 under normally incident white light keeps about
    half its green and blue response in the corners and red falls off more gently (corner / centre of
    16-pixel bins: R 0.89, G 0.52, B 0.53; the paper's Figure "example_run"), colours desaturate
    visibly towards the corners, and every per-bin 3x3 crosstalk matrix (channels x primaries) stays
    well conditioned (condition number 2.6 to 6.3). ``S[G][R]`` is 0.05 so that a green pixel's
    response to red light is dominated by crosstalk from its red neighbours and rises towards the
    corners.

    Attributes
    ----------
    spectral_overlap : 3x3 tuple of float
        ``S[f][l]``: transmission of filter ``f`` (rows R, G, B) for primary ``l`` (columns R, G, B).
    sensitivity : 3 floats
        ``T[f]``: quantum efficiency of the R, G, B channels relative to green.
    spot_sigma : 3 floats
        Standard deviation in pixels of the focused spot behind an R, G, B filter (red widest: the
        lenslets focus red light least tightly, giving red its gentler fall-off).
    photodiode_width : float
        Edge of the square light-sensitive area of a pixel, in pixels.
    lenslet_shift_corner : float
        Shift of the focused spot towards the centre at the sensor corner, in pixels (CRA compensation).
    stack_height : float
        Height of the lenslet above the photodiode in pixels: a tilt of the incident light by ``theta``
        moves the spot by ``stack_height * tan(theta)``. The default makes the compensated chief ray
        angle at the corner ``atan(lenslet_shift_corner / stack_height)`` about 27 degrees, close to the
        stock lens's.
    electrons_per_dn : float
        Conversion gain at 10 bits (e-/DN); scaled by ``2**(10 - bit_depth)`` for other bit depths.
    read_noise_dn : float
        Standard deviation of the read noise at 10 bits in DN; scaled by ``2**(bit_depth - 10)``.

    Examples
    --------
    >>> Optics().photodiode_width
    0.6
    >>> Optics(lenslet_shift_corner=0.0).lenslet_shift_corner  # no CRA compensation: no vignetting
    0.0
    """

    spectral_overlap: tuple[tuple[float, float, float], ...] = (
        (0.90, 0.10, 0.02),
        (0.05, 0.85, 0.12),
        (0.02, 0.12, 0.88),
    )
    sensitivity: tuple[float, float, float] = (0.55, 1.0, 0.75)
    spot_sigma: tuple[float, float, float] = (0.35, 0.30, 0.25)
    photodiode_width: float = 0.6
    lenslet_shift_corner: float = 0.5
    stack_height: float = 1.0
    electrons_per_dn: float = 4.0
    read_noise_dn: float = 2.0

    def __post_init__(self) -> None:
        s = np.asarray(self.spectral_overlap, dtype=float)
        if s.shape != (3, 3) or np.any(s < 0):
            raise PicamcalError(f"spectral_overlap must be a 3x3 table of non-negative numbers, got {s.tolist()}")
        for name in ("sensitivity", "spot_sigma"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or np.any(v <= 0):
                raise PicamcalError(f"{name} must be 3 positive numbers, got {v.tolist()}")
        if not 0 < self.photodiode_width <= 1:
            raise PicamcalError(f"photodiode_width must be in (0, 1] pixel, got {self.photodiode_width}")
        if self.lenslet_shift_corner < 0 or self.stack_height <= 0:
            raise PicamcalError("lenslet_shift_corner must be >= 0 and stack_height > 0")
        if self.electrons_per_dn <= 0 or self.read_noise_dn < 0:
            raise PicamcalError("electrons_per_dn must be > 0 and read_noise_dn >= 0")

    def filtered_light(self) -> np.ndarray:
        """``T[f] * S[f, l]``: light behind filter ``f`` per unit amount of primary ``l``, shape (3, 3).

        Examples
        --------
        >>> Optics().filtered_light()[1].round(2).tolist()
        [0.05, 0.85, 0.12]
        """
        return np.asarray(self.sensitivity, dtype=float)[:, None] * np.asarray(self.spectral_overlap, dtype=float)


@dataclass(frozen=True)
class SimulatedCamera:
    """A simulated sensor with frozen exposure settings, made by :func:`make_camera`.

    Attributes
    ----------
    sensor : str
        Registry name of the sensor.
    width, height : int
        Simulated frame size in pixels.
    pattern : str
        Bayer order of the top-left 2x2 block.
    bit_depth, black_level, white_level : int
        Digitisation, from the sensor registry.
    optics : Optics
        The physical parameters.
    tilt : (float, float)
        Tilt of the incident light in degrees about the y and x axes: a positive value moves the
        vignetting centre towards +x (right) and +y (down).
    scale : float
        Illumination per unit scene amount that puts the brightest noiseless white pixel at the exposure
        chosen in :func:`make_camera`; the same for every frame (frozen camera settings).

    Examples
    --------
    >>> camera = make_camera("imx477", size=(64, 48))
    >>> camera.bit_depth, camera.black_level, camera.electrons_per_dn
    (12, 256, 1.0)
    """

    sensor: str
    width: int
    height: int
    pattern: str
    bit_depth: int
    black_level: int
    white_level: int
    optics: Optics
    tilt: tuple[float, float]
    scale: float

    @property
    def electrons_per_dn(self) -> float:
        """Conversion gain at this bit depth in electrons per DN."""
        return self.optics.electrons_per_dn * 2.0 ** (10 - self.bit_depth)

    @property
    def read_noise_dn(self) -> float:
        """Read noise standard deviation at this bit depth in DN."""
        return self.optics.read_noise_dn * 2.0 ** (self.bit_depth - 10)

    @property
    def vignetting_centre(self) -> tuple[float, float]:
        """Where the spots are centred on their photodiodes, ``c + t / k`` (x, y in pixels).

        The light a photodiode collects under a uniform scene is an even function of the spot
        displacement ``d``, so every channel's noiseless white response has its extremum where ``d = 0``
        (its peak, for any sensible optics). Without compensation (``k = 0``) there is no vignetting and
        the frame centre is returned.
        """
        k, t = _lenslet_geometry(self)
        c = ((self.width - 1) / 2.0, (self.height - 1) / 2.0)
        if k == 0:
            return c
        return (c[0] + t[0] / k, c[1] + t[1] / k)


def _lenslet_geometry(camera: SimulatedCamera) -> tuple[float, tuple[float, float]]:
    """``k`` (spot shift per pixel of distance from the centre) and ``t`` (tilt displacement, x and y)."""
    optics = camera.optics
    corner = math.hypot((camera.width - 1) / 2.0, (camera.height - 1) / 2.0)
    k = optics.lenslet_shift_corner / corner
    tilt_x, tilt_y = (optics.stack_height * math.tan(math.radians(a)) for a in camera.tilt)
    return k, (tilt_x, tilt_y)


def make_camera(
    sensor: str = "imx219",
    *,
    pattern: str | None = None,
    size: tuple[int, int] | None = None,
    tilt: tuple[float, float] = (0.0, 0.0),
    exposure: float = 0.8,
    optics: Optics | None = None,
) -> SimulatedCamera:
    """Set up a simulated sensor and freeze its exposure on the white reference.

    Parameters
    ----------
    sensor : str
        A sensor of the registry (``"ov5647"``, ``"imx219"``, ``"imx477"``, ``"imx708"``).
    pattern : str, optional
        Bayer order (``"RGGB"``, ``"GBRG"``, ``"BGGR"``, ``"GRBG"``); default the sensor's own.
    size : (int, int), optional
        Frame ``(width, height)``, both even; default the full sensor. The optics scale with the frame:
        the spot shift at the corner is ``optics.lenslet_shift_corner`` whatever the size.
    tilt : (float, float)
        Angle of incidence in degrees (x, y); positive moves the vignetting centre right and down.
    exposure : float
        Fraction of ``white_level - black_level`` reached by the brightest noiseless white pixel.
    optics : Optics, optional
        Physical parameters; default ``Optics()``.

    Returns
    -------
    SimulatedCamera

    Examples
    --------
    >>> camera = make_camera("imx219", size=(320, 240), tilt=(2.0, 0.0))
    >>> camera.width, camera.height, camera.pattern, camera.white_level
    (320, 240, 'BGGR', 1023)
    >>> round(camera.vignetting_centre[0] - 159.5)  # the tilt moved the vignetting centre right
    14
    """
    spec = get_sensor(sensor)
    if spec.monochrome:
        raise PicamcalError(f"the {spec.name} is a monochrome sensor: the simulator models colour (Bayer) sensors")
    pattern = spec.default_pattern if pattern is None else str(pattern).upper()
    if pattern not in PATTERNS:
        raise PicamcalError(f"unknown Bayer pattern {pattern!r} (expected one of {', '.join(PATTERNS)})")
    width, height = (spec.width, spec.height) if size is None else (int(size[0]), int(size[1]))
    if width < 4 or height < 4 or width % 2 or height % 2:
        raise PicamcalError(f"the frame size must be even and at least 4x4 pixels, got {width}x{height}")
    limit = max_pixels()
    if width * height > limit:  # the simulator holds several float frames of this size: refuse before any
        raise PicamcalError(
            f"a simulated frame of {width}x{height} pixels ({width * height / 1e6:.0f} MP) is over the limit of "
            f"{limit / 1e6:.0f} MP (set {MAX_PIXELS_VARIABLE} to simulate larger frames)"
        )
    if not 0 < exposure <= 1:
        raise PicamcalError(f"exposure must be in (0, 1], got {exposure}")
    tilt_xy = (float(tilt[0]), float(tilt[1]))
    if not all(abs(a) < 60 for a in tilt_xy):
        raise PicamcalError(f"tilt must be within +-60 degrees, got {tilt_xy}")
    camera = SimulatedCamera(
        sensor=spec.name,
        width=width,
        height=height,
        pattern=pattern,
        bit_depth=spec.bit_depth,
        black_level=spec.black_level,
        white_level=spec.white_level,
        optics=Optics() if optics is None else optics,
        tilt=tilt_xy,
        scale=1.0,
    )
    peak = float(_uniform_response(camera, REFERENCE_AMOUNTS["white"]).max())
    return replace(camera, scale=exposure * (camera.white_level - camera.black_level) / peak)


def _box_factors(
    camera: SimulatedCamera, axis: int, sigma: ArrayLike | None = None, ray_slope: float = 0.0
) -> np.ndarray:
    """``box(n - d(q); s_f)`` for filter colour f, offset n in -2..2 and pixel q along an axis: (3, 5, N).

    ``sigma`` replaces the optics' three spot widths (the spectral model passes one wavelength band's width
    three times); ``ray_slope`` is the tangent of the chief ray angle per pixel of distance from the optical
    axis of a lens in front of the sensor, which moves each spot outwards by ``stack_height * ray_slope * r``
    and so undoes part of the lenslet shift (all of it for the lens the compensation was designed for).
    """
    optics = camera.optics
    k, t = _lenslet_geometry(camera)
    k -= optics.stack_height * ray_slope
    n_pix = camera.width if axis == 0 else camera.height
    q = np.arange(n_pix, dtype=np.float64)
    d = -k * (q - (n_pix - 1) / 2.0) + t[axis]
    u = np.asarray(_OFFSETS, dtype=np.float64)[:, None] - d[None, :]
    half = optics.photodiode_width / 2.0
    widths = optics.spot_sigma if sigma is None else sigma
    spot = np.asarray(widths, dtype=np.float64)[:, None, None]
    return ndtr((u + half) / spot) - ndtr((u - half) / spot)


def _offsets_of_parity(parity: int) -> list[int]:
    return [n for n in _OFFSETS if n % 2 == parity]


def _source_colour(colours: np.ndarray, sy: int, sx: int, py: int, px: int) -> int:
    """Filter colour of the lenslets at offsets of parity (py, px) from a photodiode at site (sy, sx)."""
    return int(colours[2 * ((sy - py) % 2) + (sx - px) % 2])


def _uniform_response(camera: SimulatedCamera, amounts: ArrayLike) -> np.ndarray:
    """Noiseless response (DN, black-subtracted, float64) to a uniform scene, as a sum of outer products."""
    light = camera.optics.filtered_light() @ np.asarray(amounts, dtype=np.float64) * camera.scale
    return _uniform_spread(camera, light, _box_factors(camera, 0), _box_factors(camera, 1))


def _uniform_spread(camera: SimulatedCamera, light: np.ndarray, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
    """Noiseless response (float64, H x W) to uniform light ``light[f]`` behind every filter of colour f.

    ``bx`` and ``by`` are the box factors of :func:`_box_factors` along x and y.
    """
    colours = site_channels(camera.pattern)
    out = np.zeros((camera.height, camera.width), dtype=np.float64)
    for sy in (0, 1):
        for sx in (0, 1):
            plane = np.zeros((camera.height // 2, camera.width // 2), dtype=np.float64)
            for py in (0, 1):
                for px in (0, 1):
                    f = _source_colour(colours, sy, sx, py, px)
                    col = by[f, [n + _PAD for n in _offsets_of_parity(py)], sy::2].sum(axis=0)
                    row = bx[f, [n + _PAD for n in _offsets_of_parity(px)], sx::2].sum(axis=0)
                    plane += light[f] * np.outer(col, row)
            out[sy::2, sx::2] = plane
    return out


def _light_image(camera: SimulatedCamera, scene: np.ndarray) -> np.ndarray:
    """Filtered light ``L(P)`` behind each lenslet (float32, H x W) for a scene of amounts (H, W, 3)."""
    coeff = (camera.optics.filtered_light() * camera.scale).astype(np.float32)
    colours = site_channels(camera.pattern)
    light = np.empty((camera.height, camera.width), dtype=np.float32)
    for site, f in enumerate(colours):
        sy, sx = divmod(site, 2)
        a = scene[sy::2, sx::2]
        light[sy::2, sx::2] = coeff[f, 0] * a[..., 0] + coeff[f, 1] * a[..., 1] + coeff[f, 2] * a[..., 2]
    return light


def _spread(
    camera: SimulatedCamera, light: np.ndarray, boxes: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """Collect the light of every lenslet on the photodiodes (float32, H x W), per site parity and offset.

    For photodiode site (sy, sx) the lenslets at offsets of parity (py, px) all have the same colour and
    lie on one parity plane of the padded light image; a horizontal pass over their column offsets and a
    vertical pass over their row offsets, each weighted by its 1-D box factor, give their contribution.
    ``boxes`` are the box factors along x and y (:func:`_box_factors`), by default the optics' own.
    """
    colours = site_channels(camera.pattern)
    bx, by = (_box_factors(camera, 0), _box_factors(camera, 1)) if boxes is None else boxes
    bx, by = bx.astype(np.float32), by.astype(np.float32)
    h2, w2 = camera.height // 2, camera.width // 2
    padded = np.pad(light, _PAD, mode="reflect")  # reflect keeps the Bayer parity of mirrored pixels
    planes = [[np.ascontiguousarray(padded[pr::2, pc::2]) for pc in (0, 1)] for pr in (0, 1)]
    out = np.empty((camera.height, camera.width), dtype=np.float32)
    rows = np.empty((h2 + _PAD, w2), dtype=np.float32)
    term = np.empty_like(rows)
    for sy in (0, 1):
        for sx in (0, 1):
            acc = np.zeros((h2, w2), dtype=np.float32)
            for px in (0, 1):
                pc = (sx - px) % 2
                for pr in (0, 1):
                    py = (sy - pr) % 2
                    f = _source_colour(colours, sy, sx, py, px)
                    plane = planes[pr][pc]
                    rows.fill(0)
                    for nx in _offsets_of_parity(px):
                        ox = (sx - nx - pc) // 2 + 1
                        np.multiply(plane[:, ox : ox + w2], bx[f, nx + _PAD, sx::2], out=term)
                        rows += term
                    for ny in _offsets_of_parity(py):
                        oy = (sy - ny - pr) // 2 + 1
                        np.multiply(rows[oy : oy + h2], by[f, ny + _PAD, sy::2, None], out=term[:h2])
                        acc += term[:h2]
            out[sy::2, sx::2] = acc
    return out


def _scene_amounts(camera: SimulatedCamera, scene: str | ArrayLike) -> tuple[np.ndarray, str]:
    """The scene as (3,) or (H, W, 3) amounts, and its name for the metadata."""
    if isinstance(scene, str):
        if scene not in REFERENCE_AMOUNTS:
            raise PicamcalError(f"unknown scene {scene!r} (expected one of {', '.join(ROLES)} or an array)")
        return np.asarray(REFERENCE_AMOUNTS[scene], dtype=np.float64), scene
    amounts = np.asarray(scene)
    if amounts.shape == (3,):
        amounts = amounts.astype(np.float64)
        names = [k for k, v in REFERENCE_AMOUNTS.items() if np.array_equal(amounts, v)]
        return amounts, names[0] if names else "uniform"
    if amounts.shape != (camera.height, camera.width, 3):
        raise PicamcalError(
            f"a scene must be 3 amounts or an array of shape ({camera.height}, {camera.width}, 3), "
            f"got shape {amounts.shape}"
        )
    return amounts.astype(np.float32, copy=False), "custom"


def _dust_attenuation(camera: SimulatedCamera, specks: Sequence[Mapping[str, float]]) -> np.ndarray:
    """``prod(1 - depth * exp(-r^2 / (2 radius^2)))`` over the specks, float32 (H, W)."""
    att = np.ones((camera.height, camera.width), dtype=np.float32)
    for speck in specks:
        x, y, radius, depth = (float(speck[k]) for k in ("x", "y", "radius", "depth"))
        reach = 5.0 * radius  # beyond five radii the blob is below 4e-6: negligible
        x0, x1 = max(0, math.floor(x - reach)), min(camera.width, math.ceil(x + reach) + 1)
        y0, y1 = max(0, math.floor(y - reach)), min(camera.height, math.ceil(y + reach) + 1)
        if x0 >= x1 or y0 >= y1:
            continue
        dx2 = (np.arange(x0, x1) - x) ** 2
        dy2 = (np.arange(y0, y1) - y) ** 2
        blob = np.exp(-(dy2[:, None] + dx2[None, :]) / (2.0 * radius**2))
        att[y0:y1, x0:x1] *= (1.0 - depth * blob).astype(np.float32)
    return att


def _response(
    camera: SimulatedCamera, amounts: np.ndarray, specks: Sequence[Mapping[str, float]] | None = None
) -> np.ndarray:
    """Noiseless black-subtracted response in DN; float64 for uniform scenes, else float32."""
    if amounts.ndim == 1 and not specks:
        return _uniform_response(camera, amounts)
    if amounts.ndim == 1:
        amounts = np.broadcast_to(amounts.astype(np.float32), (camera.height, camera.width, 3))
    light = _light_image(camera, amounts)
    if specks:
        light *= _dust_attenuation(camera, specks)
    return _spread(camera, light)


def expected_response(camera: SimulatedCamera, scene: str | ArrayLike) -> np.ndarray:
    """The noiseless, black-subtracted, unquantised response of the sensor to a scene.

    Parameters
    ----------
    camera : SimulatedCamera
        From :func:`make_camera`.
    scene : str or array_like
        A reference name (``"white"``, ``"red"``, ...), 3 amounts of the R, G, B primaries (uniform), or an
        (H, W, 3) array of amounts per pixel.

    Returns
    -------
    ndarray of float64, shape (H, W)
        Mean DN above black of each pixel (not clipped).

    Examples
    --------
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> white = expected_response(camera, "white")
    >>> bool(white.max() <= 0.8 * (1023 - 64) + 1e-9)
    True
    """
    amounts, _ = _scene_amounts(camera, scene)
    return np.asarray(_response(camera, amounts), dtype=np.float64)


def white_balance_gains(camera: SimulatedCamera) -> list[float]:
    """The camera's own white balance: G / R and G / B of its noiseless white response over the central half.

    The central half of the frame (whole 2x2 blocks) is where ``picamcal acquire``'s auto white balance
    measures, so simulated and acquired frames carry the same ``colour_gains`` (up to noise); a DNG's
    AsShotNeutral made from them renders the white reference neutral there.

    Returns
    -------
    list of 2 float
        Red and blue gains, rounded to 4 decimals.

    Examples
    --------
    >>> white_balance_gains(make_camera("imx219", size=(320, 240)))
    [2.0023, 1.0316]
    """
    return [round(g, 4) for g in balance_gains(_uniform_response(camera, REFERENCE_AMOUNTS["white"]), camera.pattern)]


def dust_specks(
    camera: SimulatedCamera, count: int, *, rng: np.random.Generator | int | None = None
) -> list[dict[str, float]]:
    """Random dark specks of dust for the white reference.

    Each speck multiplies the illumination by ``1 - depth * exp(-r^2 / (2 radius^2))``, with a radius of
    4 to 25 pixels and a depth of 5 to 30 %, centred inside the frame.

    Parameters
    ----------
    camera : SimulatedCamera
    count : int
        Number of specks.
    rng : numpy Generator or int, optional
        Random source or seed.

    Returns
    -------
    list of dict
        ``{"x", "y", "radius", "depth"}`` per speck (pixels, fraction), JSON-serialisable.

    Examples
    --------
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> speck = dust_specks(camera, 1, rng=0)[0]
    >>> sorted(speck), 4 <= speck["radius"] <= 25
    (['depth', 'radius', 'x', 'y'], True)
    """
    check_dust_count(count)
    rng = np.random.default_rng(rng)
    specks = []
    for _ in range(int(count)):
        radius = float(rng.uniform(4.0, 25.0))
        specks.append(
            {
                "x": float(rng.uniform(0, camera.width - 1)),
                "y": float(rng.uniform(0, camera.height - 1)),
                "radius": radius,
                "depth": float(rng.uniform(0.05, 0.30)),
            }
        )
    return specks


def render(
    camera: SimulatedCamera,
    scene: str | ArrayLike,
    *,
    noise: bool = True,
    rng: np.random.Generator | int | None = None,
    dust: Sequence[Mapping[str, float]] | None = None,
) -> RawImage:
    """Expose the sensor to a scene and read out a raw Bayer frame.

    Parameters
    ----------
    camera : SimulatedCamera
        From :func:`make_camera`.
    scene : str or array_like
        A reference name, 3 amounts of the R, G, B primaries (uniform), or an (H, W, 3) array.
    noise : bool
        Add shot noise (Poisson in electrons) and Gaussian read noise. The frame is rounded to integers
        and clipped to ``[0, white_level]`` either way.
    rng : numpy Generator or int, optional
        Random source or seed of the noise.
    dust : sequence of dict, optional
        Specks ``{"x", "y", "radius", "depth"}`` (see :func:`dust_specks`) darkening the illumination.

    Returns
    -------
    RawImage
        uint16 mosaic with the camera's pattern, black level (4 equal values), white level and bit depth;
        metadata ``simulated``, ``exposure_time_s``, ``analogue_gain``, ``tilt_deg``, ``scene`` (and
        ``dust`` when specks were applied).

    Examples
    --------
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> raw = render(camera, "black", rng=0)
    >>> raw.bayer.dtype.name, raw.metadata["scene"], round(float(raw.bayer.mean()))
    ('uint16', 'black', 64)
    """
    amounts, name = _scene_amounts(camera, scene)
    raw = readout(camera, _response(camera, amounts, dust), noise=noise, rng=rng, scene=name)
    if dust:
        raw.metadata["dust"] = [dict(speck) for speck in dust]
    return raw


def readout(
    camera: SimulatedCamera,
    signal: np.ndarray,
    *,
    noise: bool = True,
    rng: np.random.Generator | int | None = None,
    scene: str = "custom",
) -> RawImage:
    """Read a noiseless exposure out as a raw frame: shot and read noise, black level, rounding and clipping.

    Parameters
    ----------
    camera : SimulatedCamera
    signal : ndarray, shape (H, W)
        Mean DN above black of each pixel (:func:`expected_response`, or the spectral model's).
    noise : bool
        Add shot noise (Poisson in electrons) and Gaussian read noise.
    rng : numpy Generator or int, optional
        Random source or seed of the noise.
    scene : str
        The scene's name, ``metadata["scene"]``.

    Returns
    -------
    RawImage
        As :func:`render`.

    Examples
    --------
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> raw = readout(camera, np.full((240, 320), 100.0), noise=False, scene="grey")
    >>> int(raw.bayer[0, 0]), raw.metadata["scene"]
    (164, 'grey')
    """
    if noise:
        rng = np.random.default_rng(rng)
        gain = camera.electrons_per_dn
        electrons = rng.poisson(np.maximum(signal, 0, dtype=np.float64) * gain)
        signal = electrons.astype(np.float32) / np.float32(gain)
        signal += np.float32(camera.read_noise_dn) * rng.standard_normal(signal.shape, dtype=np.float32)
    frame = np.rint(signal + np.float32(camera.black_level))
    bayer = np.clip(frame, 0, camera.white_level).astype(np.uint16)
    metadata: dict[str, Any] = {
        "simulated": True,
        # The simulated frame is the whole (possibly reduced) sensor: lens shading maps onto all of it.
        "sensor_size": [camera.width, camera.height],
        "sensor_crop": [0, 0, camera.width, camera.height],
        "geometry_source": "file",
        "exposure_time_s": _EXPOSURE_TIME_S,
        "analogue_gain": _ANALOGUE_GAIN,
        "tilt_deg": list(camera.tilt),
        "scene": scene,
    }
    return RawImage(
        bayer,
        camera.pattern,
        (float(camera.black_level),) * 4,
        camera.white_level,
        camera.bit_depth,
        camera.sensor,
        metadata,
    )


def check_dust_count(count: int) -> int:
    """``count`` if it is a number of dust specks the simulator draws: a whole number from 0 to :data:`MAX_DUST`.

    Examples
    --------
    >>> check_dust_count(3)
    3
    >>> check_dust_count(-1)
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: the number of dust specks must be a whole number from 0 to 1000, got -1
    """
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or not 0 <= count <= MAX_DUST:
        raise PicamcalError(f"the number of dust specks must be a whole number from 0 to {MAX_DUST}, got {count!r}")
    return int(count)


def ground_truth(camera: SimulatedCamera, *, bin_size: int = 16) -> dict[str, np.ndarray]:
    """The noiseless per-bin response of the camera, what a calibration should recover.

    Parameters
    ----------
    camera : SimulatedCamera
    bin_size : int
        Even bin edge in sensor pixels, as :func:`picamcal.bayer.bin_sites`.

    Returns
    -------
    dict of str to ndarray
        ``"site_response"`` (4, nby, nbx, 4): bin means of the black-subtracted white, red, green and blue
        references per 2x2 site (row-major), without dust or quantisation;
        ``"site_mixing"`` (nby, nbx, 4, 3): DN per unit amount of each primary, per bin and site, so
        ``site_response[0] == site_mixing.sum(-1)`` and ``site_response[1 + l] == site_mixing[..., l]``;
        ``"vignetting_centre"`` (2,): x, y where the white response peaks (``camera.vignetting_centre``).

    Examples
    --------
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> truth = ground_truth(camera, bin_size=16)
    >>> truth["site_response"].shape, truth["site_mixing"].shape
    ((4, 15, 20, 4), (15, 20, 4, 3))
    """
    mixing = np.stack(
        [bin_sites(_uniform_response(camera, primary), bin_size) for primary in np.eye(3)],
        axis=-1,
    )
    response = np.stack([mixing.sum(axis=-1), mixing[..., 0], mixing[..., 1], mixing[..., 2]])
    return {
        "site_response": response,
        "site_mixing": mixing,
        "vignetting_centre": np.array(camera.vignetting_centre, dtype=np.float64),
    }
