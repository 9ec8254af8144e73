"""The spectral simulator: the sensor of :mod:`picamcal.simulate.physics` lit by spectra instead of three primaries.

The fast simulator describes light as amounts of the three LED primaries, so a per-bin 3 x 3 matrix describes
it exactly. Here light is a spectrum at every lenslet, and what the paper warns about can happen: a target
whose spectra differ from the calibration's, and crosstalk that changes with the optics' chief ray angle.

The model, with the geometry of :mod:`picamcal.simulate.physics` (its steps 2 to 4) and these changes:

1. A scene is a per-pixel weight ``w_k(P)`` of a few basis spectra ``E_k(lambda)`` (a monitor's primaries, a
   print's Neugebauer primaries, the jig's LED lines; :mod:`picamcal.simulate.spectra`). The light behind the
   filter of lenslet ``P``, in wavelength band ``b``, is::

       L_b(P) = scale * sum_k w_k(P) * sum_{lambda in b} S_f(P)(lambda) E_k(lambda) dlambda

   with ``S_f`` the spectral sensitivity of filter colour ``f`` (:func:`~picamcal.simulate.spectra.sensitivities`).
2. The spot is not the same at every wavelength. The lenslet focuses longer wavelengths less tightly (its
   optical spot grows about as ``lambda``), and light of longer wavelength is absorbed deeper in the silicon,
   where the carriers it frees diffuse further before they are collected (the absorption length of silicon
   grows from about 0.4 um at 450 nm to 3.5 um at 650 nm, M. A. Green, Sol. Energy Mater. Sol. Cells 92,
   2008: about ``lambda ** 6`` over the band). The spot of wavelength ``lambda`` is a Gaussian of width::

       sigma(lambda) = hypot(spot_optical * (lambda / 550 nm), spot_diffusion * (lambda / 550 nm) ** 6)

   Each wavelength band ``b`` (:data:`BAND_NM` wide) spreads with ``sigma`` at its centre, so vignetting and
   crosstalk depend on the spectrum, not only on the channel.
3. The spot lands at ``P + d(P)``, ``d(P) = -(k - h * s) (P - c) + t``: ``k`` the lenslet shift (CRA
   compensation), ``t`` the tilt, and ``s`` the chief-ray slope of a lens in front of the sensor, whose exit
   pupil sends the chief ray at ``tan(theta) = s * r`` at distance ``r`` from the axis (``s = 0``: normal
   incidence, the jig or a telecentric microscope). :data:`LENSES` gives the corner angle of each lens.
4. The response of photodiode ``Q`` is the sum over bands of physics' step 3 with ``L_b`` and ``sigma_b``;
   noise, black level and digitisation are physics' :func:`~picamcal.simulate.physics.readout`. Step 3 sums the
   5 x 5 lenslets around ``Q``: of the widest spot (1.2 px, the 650-700 nm band, where the infrared-cut filter
   leaves the sensitivities below a tenth of their peaks) about 6 % per axis falls further out and is lost.

Examples
--------
>>> from picamcal.simulate.spectral_scenes import jig_source
>>> camera = make_spectral_camera("imx219", size=(320, 240))
>>> raw = render_spectral(camera, jig_source().spectrum("white"), rng=1)
>>> raw.bayer.shape, raw.metadata["scene"], raw.metadata["lens"]
((240, 320), 'uniform', 'none')
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from ..bayer import balance_gains, bin_sites, centre_region, sites_to_channels
from ..errors import PicamcalError
from ..raw.model import RawImage, site_channels
from .physics import (
    Optics,
    SimulatedCamera,
    _box_factors,
    _spread,
    _uniform_spread,
    make_camera,
    readout,
)
from .spectra import STEP_NM, WAVELENGTHS, jig_led, sensitivities

__all__ = [
    "BAND_NM",
    "LENSES",
    "SPECTRAL_OPTICS",
    "SpectralCamera",
    "bin_responses",
    "expected_spectral_response",
    "make_spectral_camera",
    "render_spectral",
]

#: Lenses in front of the sensor, by name: the chief ray angle in degrees at the corner of the frame. ``none``
#: is normal incidence (the jig, a microscope with a near-telecentric path); ``long`` a long-focus lens whose
#: exit pupil is far (an HQ Camera with a 25 mm C-mount lens: about 8 degrees); ``short`` a short-focus,
#: wide-angle lens (a 6 mm CS-mount lens: about 16 degrees). The stock phone lens the lenslets are shifted for
#: has about 29 (``atan(lenslet_shift_corner / stack_height)`` of :data:`SPECTRAL_OPTICS`).
LENSES: dict[str, float] = {"none": 0.0, "long": 8.0, "short": 16.0}

#: The spectral camera's default pixel stack: the fast simulator's (:class:`~picamcal.simulate.physics.Optics`) with
#: the lenslets shifted by 0.55 pixel at the corner (compensating a chief ray of ``atan(0.55) = 29`` degrees there,
#: the stock lens's). With the default spot widths the corner bins' response to the jig's white is 0.41 (green and
#: blue) of the centre's, and red stays level (1.07: its own fall-off, 0.94 under the red LED alone, is made up by
#: the light its green and blue neighbours lose to it); the workflows then show docs/simulator.md's figures.
SPECTRAL_OPTICS = Optics(lenslet_shift_corner=0.55)

#: Width of the wavelength bands in which the spot width is taken as constant, in nanometres.
BAND_NM = 50.0


@dataclass(frozen=True, eq=False)
class SpectralCamera:
    """A simulated sensor lit by spectra, made by :func:`make_spectral_camera`.

    Attributes
    ----------
    base : SimulatedCamera
        Size, Bayer order, levels, lenslet geometry, tilt and noise (its ``scale`` is not used).
    sensitivity : ndarray, shape (3, n)
        R, G, B spectral sensitivities on :data:`~picamcal.simulate.spectra.WAVELENGTHS`.
    spot_optical : float
        Width (standard deviation, pixels) of the lenslet's focused spot at 550 nm.
    spot_diffusion : float
        Width of the carriers' diffusion at 550 nm, pixels (grows as ``lambda ** 6``).
    lens : str
        A name of :data:`LENSES`.
    chief_ray_corner_deg : float
        The lens's chief ray angle at the frame's corner, degrees.
    scale : float
        DN per unit of light (a spectrum's units times nm times relative sensitivity): frozen so that the white
        the camera was set up on peaks at the chosen exposure.

    Examples
    --------
    >>> camera = make_spectral_camera("imx219", size=(64, 48), lens="short")
    >>> camera.width, camera.pattern, camera.chief_ray_corner_deg
    (64, 'BGGR', 16.0)
    """

    base: SimulatedCamera
    sensitivity: np.ndarray
    spot_optical: float
    spot_diffusion: float
    lens: str
    chief_ray_corner_deg: float
    scale: float

    @property
    def width(self) -> int:
        return self.base.width

    @property
    def height(self) -> int:
        return self.base.height

    @property
    def pattern(self) -> str:
        return self.base.pattern

    @property
    def sensor(self) -> str:
        return self.base.sensor

    @property
    def ray_slope(self) -> float:
        """Tangent of the chief ray angle per pixel of distance from the optical axis."""
        corner = math.hypot((self.width - 1) / 2.0, (self.height - 1) / 2.0)
        return math.tan(math.radians(self.chief_ray_corner_deg)) / corner

    def band_sigmas(self) -> np.ndarray:
        """Spot width of each wavelength band (at its centre), pixels."""
        ratio = (_band_edges()[:-1] + BAND_NM / 2.0) / 550.0
        return np.hypot(self.spot_optical * ratio, self.spot_diffusion * ratio**6)

    def band_light(self, spectra: ArrayLike) -> np.ndarray:
        """Light behind each filter per band for each spectrum: (3 filters, bands, K), times ``scale``.

        Examples
        --------
        >>> camera = make_spectral_camera("imx219", size=(64, 48))
        >>> camera.band_light(np.ones((2, 61))).shape
        (3, 6, 2)
        """
        e = np.atleast_2d(np.asarray(spectra, dtype=np.float64))
        if e.shape[-1] != WAVELENGTHS.size:
            raise PicamcalError(f"spectra must have {WAVELENGTHS.size} samples (400-700 nm by 5), got {e.shape[-1]}")
        band = _band_index()
        per_sample = self.sensitivity[:, None, :] * e[None, :, :] * STEP_NM  # (3, K, n)
        light = np.stack([per_sample[..., band == b].sum(-1) for b in range(band.max() + 1)], axis=1)
        return light * self.scale

    def boxes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The box factors along x and y of every band (physics' step 3 with the band's spot and the lens)."""
        slope = self.ray_slope
        return [
            (_box_factors(self.base, 0, (s, s, s), slope), _box_factors(self.base, 1, (s, s, s), slope))
            for s in self.band_sigmas()
        ]


def _band_edges() -> np.ndarray:
    return np.arange(WAVELENGTHS[0], WAVELENGTHS[-1] + BAND_NM / 2, BAND_NM)


def _band_index() -> np.ndarray:
    """The band of each wavelength sample (the last band includes its upper edge)."""
    edges = _band_edges()
    return np.minimum(((WAVELENGTHS - edges[0]) // BAND_NM).astype(int), len(edges) - 2)


def make_spectral_camera(
    sensor: str = "imx219",
    *,
    pattern: str | None = None,
    size: tuple[int, int] | None = None,
    tilt: tuple[float, float] = (0.0, 0.0),
    lens: str = "none",
    white: ArrayLike | None = None,
    exposure: float = 0.8,
    spot_optical: float = 0.15,
    spot_diffusion: float = 0.35,
    optics: Optics | None = None,
) -> SpectralCamera:
    """Set up a spectral simulated sensor behind a lens and freeze its exposure on a white.

    Parameters
    ----------
    sensor, pattern, size, tilt, optics
        As :func:`picamcal.simulate.make_camera` (the optics' photodiode, lenslet shift, stack height and noise
        are used; its spectral overlap and per-channel spot widths are replaced by the spectra).
    lens : {"none", "long", "short"}
        The optics in front of the sensor (:data:`LENSES`).
    white : array_like, shape (n,), optional
        The spectrum on which the exposure is frozen; default the jig's white (all three LEDs).
    exposure : float
        Fraction of ``white_level - black_level`` reached by the brightest noiseless pixel of that white.
    spot_optical, spot_diffusion : float
        The spot's optical and diffusion widths at 550 nm, pixels (see the module docstring).

    Returns
    -------
    SpectralCamera

    Examples
    --------
    >>> camera = make_spectral_camera("imx477", size=(64, 48), lens="long")
    >>> camera.base.bit_depth, camera.lens, np.round(camera.band_sigmas(), 2).tolist()
    (12, 'long', [0.14, 0.19, 0.3, 0.48, 0.77, 1.21])
    """
    if lens not in LENSES:
        raise PicamcalError(f"unknown lens {lens!r} (expected one of {', '.join(LENSES)})")
    if not 0 < spot_optical <= 2 or not 0 <= spot_diffusion <= 2:
        raise PicamcalError("spot_optical must be in (0, 2] pixels and spot_diffusion in [0, 2]")
    if not 0 < exposure <= 1:
        raise PicamcalError(f"exposure must be in (0, 1], got {exposure}")
    optics = SPECTRAL_OPTICS if optics is None else optics
    base = make_camera(sensor, pattern=pattern, size=size, tilt=tilt, optics=optics)
    camera = SpectralCamera(
        base=base,
        sensitivity=sensitivities(base.sensor),
        spot_optical=float(spot_optical),
        spot_diffusion=float(spot_diffusion),
        lens=lens,
        chief_ray_corner_deg=LENSES[lens],
        scale=1.0,
    )
    if white is None:
        white = jig_led().sum(axis=0)  # all three LEDs on
    peak = float(expected_spectral_response(camera, white).max())
    return replace(camera, scale=exposure * (base.white_level - base.black_level) / peak)


def expected_spectral_response(camera: SpectralCamera, spectrum: ArrayLike) -> np.ndarray:
    """The noiseless, black-subtracted response (DN, float64, H x W) to a uniform spectrum.

    Parameters
    ----------
    camera : SpectralCamera
    spectrum : array_like, shape (n,)
        Spectral radiance on :data:`~picamcal.simulate.spectra.WAVELENGTHS`.

    Examples
    --------
    >>> from picamcal.simulate.spectral_scenes import jig_source
    >>> camera = make_spectral_camera("imx219", size=(320, 240))
    >>> white = expected_spectral_response(camera, jig_source().spectrum("white"))
    >>> round(float(white.max()), 1) == round(0.8 * (1023 - 64), 1)
    True
    """
    light = camera.band_light(spectrum)[:, :, 0]  # (3, bands)
    out = np.zeros((camera.height, camera.width), dtype=np.float64)
    for b, (bx, by) in enumerate(camera.boxes()):
        out += _uniform_spread(camera.base, light[:, b], bx, by)
    return out


def _scene_response(camera: SpectralCamera, weights: np.ndarray, spectra: np.ndarray) -> np.ndarray:
    """Noiseless response (float32, H x W) to per-pixel weights (H, W, K) of basis spectra (K, n)."""
    light = camera.band_light(spectra).astype(np.float32)  # (3, bands, K)
    colours = site_channels(camera.pattern)
    out = np.zeros((camera.height, camera.width), dtype=np.float32)
    for b, boxes in enumerate(camera.boxes()):
        image = np.empty((camera.height, camera.width), dtype=np.float32)
        for site, f in enumerate(colours):
            sy, sx = divmod(site, 2)
            w = weights[sy::2, sx::2]
            image[sy::2, sx::2] = w @ light[f, b]
        out += _spread(camera.base, image, boxes)
    return out


def render_spectral(
    camera: SpectralCamera,
    spectra: ArrayLike,
    weights: ArrayLike | None = None,
    *,
    noise: bool = True,
    rng: np.random.Generator | int | None = None,
    scene: str | None = None,
) -> RawImage:
    """Expose the spectral sensor to a scene and read out a raw Bayer frame.

    Parameters
    ----------
    camera : SpectralCamera
    spectra : array_like, shape (n,) or (K, n)
        One spectrum (a uniform scene), or K basis spectra.
    weights : array_like, shape (H, W, K), optional
        Weight of each basis spectrum at each pixel; required with K basis spectra.
    noise : bool
        Shot and read noise (:func:`picamcal.simulate.physics.readout`).
    rng : numpy Generator or int, optional
        Random source or seed of the noise.
    scene : str, optional
        Name for ``metadata["scene"]`` (default ``"uniform"`` or ``"custom"``).

    Returns
    -------
    RawImage
        As :func:`picamcal.simulate.render`, with ``metadata["spectral"] = True``, ``metadata["lens"]`` and
        ``metadata["chief_ray_corner_deg"]``. The white balance (``metadata["colour_gains"]``) depends on the white
        the camera was set on: :func:`picamcal.simulate.spectral_scenes.spectral_references` adds it.

    Examples
    --------
    >>> from picamcal.simulate.spectral_scenes import monitor_source
    >>> camera = make_spectral_camera("imx219", size=(320, 240))
    >>> primaries = monitor_source().basis
    >>> weights = np.zeros((240, 320, 4), np.float32)
    >>> weights[..., 3] = 1.0  # the monitor's black leak everywhere
    >>> weights[:, :160, 0] = 1.0  # left half red
    >>> render_spectral(camera, primaries, weights, noise=False).bayer.shape
    (240, 320)
    """
    e = np.asarray(spectra, dtype=np.float64)
    if weights is None:
        if e.ndim != 1:
            raise PicamcalError("several basis spectra need their per-pixel weights")
        signal = expected_spectral_response(camera, e)
        name = "uniform" if scene is None else scene
    else:
        w = np.asarray(weights, dtype=np.float32)
        e = np.atleast_2d(e)
        if w.shape != (camera.height, camera.width, e.shape[0]):
            raise PicamcalError(
                f"weights must have shape ({camera.height}, {camera.width}, {e.shape[0]}), got {w.shape}"
            )
        signal = _scene_response(camera, w, e)
        name = "custom" if scene is None else scene
    raw = readout(camera.base, signal, noise=noise, rng=rng, scene=name)
    raw.metadata.update(spectral=True, lens=camera.lens, chief_ray_corner_deg=camera.chief_ray_corner_deg)
    return raw


def white_balance(camera: SpectralCamera, white: ArrayLike) -> list[float]:
    """The camera's white balance (G / R, G / B over the central half) frozen on a white spectrum.

    Examples
    --------
    >>> from picamcal.simulate.spectral_scenes import jig_source
    >>> gains = white_balance(make_spectral_camera("imx219", size=(320, 240)), jig_source().spectrum("white"))
    >>> len(gains), all(g > 0 for g in gains)
    (2, True)
    """
    return [round(g, 4) for g in balance_gains(expected_spectral_response(camera, white), camera.pattern)]


def bin_responses(camera: SpectralCamera, spectra: ArrayLike, bin_size: int = 16) -> np.ndarray:
    """Noiseless bin means per Bayer site of uniform spectra: (K, nby, nbx, 4), DN above black.

    What the calibration's bins of a reference of that spectrum would hold without noise or rounding.

    Examples
    --------
    >>> from picamcal.simulate.spectral_scenes import jig_source
    >>> camera = make_spectral_camera("imx219", size=(320, 240))
    >>> bin_responses(camera, jig_source().basis[:3], 16).shape  # the LED's three lines
    (3, 15, 20, 4)
    """
    e = np.atleast_2d(np.asarray(spectra, dtype=np.float64))
    return np.stack([bin_sites(expected_spectral_response(camera, s), bin_size) for s in e])


def flat_fielded(responses: np.ndarray, site_white: np.ndarray, pattern: str) -> np.ndarray:
    """Bin responses (K, nby, nbx, 4) divided by a white per site and averaged per channel: (K, nby, nbx, 3).

    What the ``flat`` mode makes of a uniform colour in each bin (the binned correction of
    :func:`picamcal.correct`).

    Examples
    --------
    >>> r = np.ones((1, 2, 2, 4))
    >>> flat_fielded(r, 2 * np.ones((2, 2, 4)), "RGGB")[0, 0, 0].tolist()
    [0.5, 0.5, 0.5]
    """
    return sites_to_channels(responses / site_white, pattern)


def centre_truth(flat: np.ndarray) -> np.ndarray:
    """What the centre of the sensor sees: the mean over the central ninth of flat-fielded responses, (K, 3).

    Examples
    --------
    >>> centre_truth(np.ones((1, 3, 3, 3))).tolist()
    [[1.0, 1.0, 1.0]]
    """
    y0, y1, x0, x1 = centre_region(flat.shape[1], flat.shape[2])
    return flat[:, y0:y1, x0:x1].mean(axis=(1, 2))


def least_squares_unmixing(flat: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per bin, the 3 x 3 ``X`` minimising ``sum_k |X r_k(b) - t_k|^2``: (nby, nbx, 3, 3).

    Parameters
    ----------
    flat : ndarray, shape (K, nby, nbx, 3)
        Flat-fielded responses ``r_k(b)`` of K >= 3 colours.
    truth : ndarray, shape (K, 3)
        The colours ``t_k`` they should become.

    Examples
    --------
    >>> m = np.array([[0.8, 0.2, 0.0], [0.1, 0.8, 0.1], [0.0, 0.2, 0.8]])
    >>> colours = np.eye(3)
    >>> x = least_squares_unmixing((colours @ m.T)[:, None, None], colours)
    >>> bool(np.allclose(x[0, 0] @ m, np.eye(3)))
    True
    """
    r = np.moveaxis(flat, 0, -1)  # (nby, nbx, 3, K)
    gram = r @ np.swapaxes(r, -1, -2)  # R R^T
    cross = truth.T @ np.swapaxes(r, -1, -2)  # T R^T, broadcast
    # X = T R^T (R R^T)^-1, solved as (R R^T) X^T = (T R^T)^T
    return np.swapaxes(np.linalg.solve(gram, np.swapaxes(cross, -1, -2)), -1, -2)
