"""Spectra for the spectral simulator: sensor sensitivities, light sources, a monitor's primaries, printed inks.

Everything is sampled on one wavelength grid, :data:`WAVELENGTHS` (400 to 700 nm in 5 nm steps), as plain
float64 arrays whose last axis is wavelength:

- **Spectral sensitivities** (:func:`sensitivities`, shape (3, n): R, G, B) are the product of a channel's
  colour-filter transmission, the photodiode's quantum efficiency and the module's infrared-cut filter, in
  electrons per photon relative to the green peak (dimensionless, green peak about 1). They are sums of a few
  Gaussians whose peaks, widths and side lobes follow the published curves; the numbers are read by eye from
  the graphs, good to a few nanometres and a few per cent, which is what a simulator needs (shapes that
  overlap like the real ones), not a colorimetric characterisation.
- **Light sources** (:func:`jig_led`, :func:`white_led`, :func:`monitor_primaries`) are spectral power
  distributions in arbitrary radiometric units per nanometre, scaled so that the source's white has a
  luminance of 1 (:func:`luminance` of its sum, with the CIE 1931 ``y-bar`` of :func:`cie_1931`).
- **Inks** (:func:`ink_reflectances`) are reflectance factors (0 to 1) of paper, cyan, magenta, yellow and
  their overprints: the eight Neugebauer primaries of a CMY print.

Examples
--------
>>> WAVELENGTHS[[0, -1]].tolist(), WAVELENGTHS.size
([400.0, 700.0], 61)
>>> sensitivities("imx219").shape, jig_led().shape, monitor_primaries().shape
((3, 61), (3, 61), (4, 61))
"""

from __future__ import annotations

import numpy as np

from ..errors import PicamcalError
from ..sensors import get_sensor

__all__ = [
    "INK_PRIMARIES",
    "SENSITIVITY_FAMILY",
    "STEP_NM",
    "WAVELENGTHS",
    "cie_1931",
    "ink_reflectances",
    "jig_led",
    "luminance",
    "monitor_primaries",
    "print_primaries",
    "sensitivities",
    "white_led",
]

#: Sampling step of the wavelength grid in nanometres.
STEP_NM = 5.0
#: The wavelength grid in nanometres, 400 to 700 inclusive: the visible band the modules' infrared-cut filters
#: leave (every sensitivity is below 2 % of its peak beyond it).
WAVELENGTHS = np.arange(400.0, 700.0 + STEP_NM / 2, STEP_NM)


def _gauss(centre: float, sigma: float) -> np.ndarray:
    return np.exp(-0.5 * ((WAVELENGTHS - centre) / sigma) ** 2)


def _fwhm(centre: float, fwhm: float) -> np.ndarray:
    return _gauss(centre, fwhm / (2.0 * np.sqrt(2.0 * np.log(2.0))))


def _ir_cut(edge: float, width: float) -> np.ndarray:
    """A long-pass-blocking filter: transmission 1/2 at ``edge`` nm, falling over ``width`` nm."""
    return 1.0 / (1.0 + np.exp((WAVELENGTHS - edge) / width))


# Per sensor: for R, G, B a list of (height, centre nm, sigma nm) lobes, a floor (the filters' leak across the
# whole band), and the module's infrared-cut filter (edge nm, width nm).
_CURVES: dict[str, tuple[tuple[tuple[tuple[float, float, float], ...], ...], float, tuple[float, float]]] = {
    # IMX219 (Camera Module v2): Sony IMX219PQ datasheet, "Spectral sensitivity characteristics", and the
    # measurement of the whole module (with its infrared-cut filter) by Pagnutti et al., J. Electron. Imaging
    # 26(1) 013014 (2017), Fig. 9: blue peaks near 460 nm at about 0.7 of green, green near 535 nm with a broad
    # shoulder into the red, red near 600 nm cut sharply by the module's filter near 650 nm.
    "imx219": (
        (
            ((0.80, 602.0, 26.0), (0.07, 530.0, 30.0), (0.04, 460.0, 25.0)),
            ((1.00, 535.0, 36.0), (0.12, 470.0, 22.0), (0.16, 598.0, 22.0)),
            ((0.72, 460.0, 26.0), (0.20, 505.0, 22.0)),
        ),
        0.02,
        (652.0, 9.0),
    ),
    # IMX477 (HQ Camera): Sony IMX477 datasheet spectral sensitivity, with the HQ Camera's Hoya CM500 infrared-cut
    # filter (Raspberry Pi HQ Camera documentation: half transmission near 650 nm). Back-illuminated: broader,
    # higher blue.
    "imx477": (
        (
            ((0.85, 598.0, 28.0), (0.08, 525.0, 30.0), (0.03, 455.0, 25.0)),
            ((1.00, 530.0, 38.0), (0.14, 465.0, 24.0), (0.14, 595.0, 22.0)),
            ((0.82, 455.0, 28.0), (0.18, 500.0, 24.0)),
        ),
        0.02,
        (650.0, 8.0),
    ),
    # OV5647 (Camera Module v1): OmniVision OV5647 product brief and datasheet spectral response graph, with the
    # v1 module's infrared-cut filter near 650 nm: older front-side illuminated pixels, lower blue, wider overlaps.
    "ov5647": (
        (
            ((0.75, 608.0, 28.0), (0.10, 535.0, 35.0), (0.05, 465.0, 30.0)),
            ((1.00, 540.0, 40.0), (0.15, 475.0, 25.0), (0.20, 600.0, 25.0)),
            ((0.60, 455.0, 30.0), (0.25, 510.0, 25.0)),
        ),
        0.04,
        (650.0, 10.0),
    ),
    # IMX708 (Camera Module 3): Sony IMX708 spectral sensitivity as shown in the Camera Module 3 product brief,
    # with the module's infrared-cut filter (the NoIR variant has none and is outside this model).
    "imx708": (
        (
            ((0.82, 600.0, 27.0), (0.07, 528.0, 30.0), (0.03, 458.0, 25.0)),
            ((1.00, 532.0, 37.0), (0.12, 468.0, 22.0), (0.15, 597.0, 22.0)),
            ((0.78, 457.0, 27.0), (0.18, 503.0, 22.0)),
        ),
        0.02,
        (655.0, 9.0),
    ),
}

#: The sensors without a curve of their own in this model, and whose curves they take: the closest family
#: (Sony's back-illuminated STARVIS and Exmor RS sensors take the IMX477's, OmniVision's the OV5647's).
SENSITIVITY_FAMILY = {
    "imx296": "imx477",
    "imx290": "imx477",
    "imx462": "imx477",
    "se327m12": "imx477",
    "imx378": "imx477",
    "imx519": "imx708",
    "imx500": "imx477",
    "imx283": "imx477",
    "imx415": "imx477",
    "imx335": "imx477",
    "imx585": "imx477",
    "imx662": "imx477",
    "ov64a40": "ov5647",
}


def sensitivities(sensor: str) -> np.ndarray:
    """Spectral sensitivities of a colour sensor's R, G and B pixels (filter x quantum efficiency x IR cut).

    Parameters
    ----------
    sensor : str
        A colour sensor of :mod:`picamcal.sensors`. The IMX219, IMX477, OV5647 and IMX708 have their own curves
        (sources in this module's code); the others take their family's (:data:`SENSITIVITY_FAMILY`).

    Returns
    -------
    ndarray of float64, shape (3, len(WAVELENGTHS))
        Relative electrons per photon, the green peak about 1.

    Raises
    ------
    PicamcalError
        A monochrome sensor, or one the registry does not know.

    Examples
    --------
    >>> s = sensitivities("imx219")
    >>> [int(WAVELENGTHS[i]) for i in s.argmax(axis=1)]  # R, G, B peaks in nm
    [600, 535, 465]
    >>> bool(np.allclose(sensitivities("imx290"), sensitivities("imx477")))  # the family's curves
    True
    """
    spec = get_sensor(sensor)
    if spec.monochrome:
        raise PicamcalError(f"the {spec.name} is a monochrome sensor: it has no colour filters to model")
    lobes, floor, (edge, width) = _CURVES[SENSITIVITY_FAMILY.get(spec.name, spec.name)]
    curves = [floor + sum(h * _gauss(c, s) for h, c, s in channel) for channel in lobes]
    return np.stack(curves) * _ir_cut(edge, width)


def cie_1931() -> np.ndarray:
    """The CIE 1931 2-degree colour-matching functions x-bar, y-bar, z-bar on :data:`WAVELENGTHS`, shape (3, n).

    The multi-lobe Gaussian fit of Wyman, Sloan and Shirley, "Simple analytic approximations to the CIE XYZ
    colour matching functions", JCGT 2(2), 2013 (their eq. 2), within a few per cent of the tabulated functions.

    Examples
    --------
    >>> int(WAVELENGTHS[cie_1931()[1].argmax()])  # y-bar peaks at 555 nm
    555
    """
    lam = WAVELENGTHS

    def g(mu: float, s1: float, s2: float) -> np.ndarray:
        return np.exp(-0.5 * ((lam - mu) / np.where(lam < mu, s1, s2)) ** 2)

    x = 1.056 * g(599.8, 37.9, 31.0) + 0.362 * g(442.0, 16.0, 26.7) - 0.065 * g(501.1, 20.4, 26.2)
    y = 0.821 * g(568.8, 46.9, 40.5) + 0.286 * g(530.9, 16.3, 31.1)
    z = 1.217 * g(437.0, 11.8, 36.0) + 0.681 * g(459.0, 26.0, 13.8)
    return np.stack([x, y, z])


def luminance(spectrum: np.ndarray) -> np.ndarray:
    """Luminance (``integral of spectrum x y-bar``, in the spectrum's units times nm) over the last axis.

    Examples
    --------
    >>> round(float(luminance(np.ones_like(WAVELENGTHS))), 1)  # an equal-energy spectrum
    106.9
    """
    return np.asarray(spectrum, dtype=np.float64) @ cie_1931()[1] * STEP_NM


def _unit_white(primaries: np.ndarray) -> np.ndarray:
    """Primaries scaled together so that their sum (the white) has a luminance of 1."""
    return primaries / luminance(primaries.sum(axis=0))


def jig_led() -> np.ndarray:
    """The calibration jig's RGB LED (WS2812 class): red, green and blue emission spectra, shape (3, n).

    Narrow lines as the WS2812B datasheet gives them (dominant wavelengths red 620-630 nm, green 515-530 nm,
    blue 465-475 nm) with the typical widths of AlInGaP red (FWHM 18 nm) and InGaN green (35 nm) and blue
    (24 nm) dies. The three dies emit the same radiant power (a few milliwatts each at their rated current,
    which is what the datasheet's luminous intensities, red 390-420, green 660-720 and blue 180-200 mcd, amount
    to), so that all three on together (the jig's white) is the bluish-purple white of the real LED. The white
    has a luminance of 1.

    Examples
    --------
    >>> [int(WAVELENGTHS[i]) for i in jig_led().argmax(axis=1)]
    [625, 520, 465]
    >>> round(float(luminance(jig_led().sum(axis=0))), 6)
    1.0
    """
    lines = np.stack([_fwhm(625.0, 18.0), _fwhm(520.0, 35.0), _fwhm(467.0, 24.0)])
    return _unit_white(lines / lines.sum(axis=1, keepdims=True))


def white_led() -> np.ndarray:
    """A white LED: an InGaN blue pump near 450 nm and a broad YAG:Ce phosphor emission near 560 nm, shape (n,).

    The shape of a typical cool-white LED (correlated colour temperature near 6000 K): a pump of FWHM 20 nm and a
    phosphor band of FWHM about 120 nm, the pump's peak about 1.6 times the phosphor's. Luminance 1.

    Examples
    --------
    >>> int(WAVELENGTHS[white_led().argmax()]), round(float(luminance(white_led())), 6)
    (450, 1.0)
    """
    spectrum = 1.6 * _fwhm(450.0, 20.0) + 1.0 * _fwhm(560.0, 120.0)
    return spectrum / luminance(spectrum)


def monitor_primaries(contrast: float = 1000.0) -> np.ndarray:
    """An LCD monitor's red, green and blue primaries at full drive, and the light it leaks at black, shape (4, n).

    A white-LED backlight (:func:`white_led`) behind the panel's colour filters (absorption-dye filters of an
    sRGB office monitor: red a long-pass edge near 585 nm, green a band near 535 nm, blue a band near 450 nm,
    each leaking a few per cent across the band). The three are scaled so that full white is the white point of
    D65 (chromaticity x 0.3127, y 0.3290 with :func:`cie_1931`), at a luminance of 1. Row 3 is the black
    screen's light, ``1 / contrast`` of the white's luminance: the white's spectrum tilted towards the blue as
    ``(lambda / 550 nm) ** -4``, since the crossed polarisers and the liquid crystal's dark state leak most at
    short wavelengths (the bluish black of LCD panels). An sRGB image shows linear amounts ``a`` of the three
    primaries: ``a @ rows[:3] + rows[3]``.

    Parameters
    ----------
    contrast : float
        The panel's contrast ratio (white / black), at least 1.

    Examples
    --------
    >>> primaries = monitor_primaries()
    >>> xyz = cie_1931() @ primaries[:3].sum(axis=0)
    >>> np.round(xyz[:2] / xyz.sum(), 4).tolist()  # D65
    [0.3127, 0.329]
    """
    if not contrast >= 1:
        raise PicamcalError(f"a monitor's contrast ratio must be at least 1, got {contrast}")
    backlight = white_led()
    red = 0.03 + 0.95 / (1.0 + np.exp(-(WAVELENGTHS - 588.0) / 9.0))
    green = 0.02 + 0.85 * _gauss(535.0, 32.0)
    blue = 0.02 + 0.88 * _gauss(452.0, 30.0)
    filtered = np.stack([red, green, blue]) * backlight
    xyz = cie_1931() @ filtered.T * STEP_NM  # columns: XYZ of each primary
    d65 = np.array([0.3127 / 0.3290, 1.0, (1.0 - 0.3127 - 0.3290) / 0.3290])
    gains = np.linalg.solve(xyz, d65)
    primaries = _unit_white(filtered * gains[:, None])
    leak = primaries.sum(axis=0) * (WAVELENGTHS / 550.0) ** -4
    leak /= luminance(leak) * contrast
    return np.concatenate([primaries, leak[None]])


def ink_reflectances() -> np.ndarray:
    """Reflectance factors of a CMY print: the eight Neugebauer primaries, shape (8, n).

    Rows: paper, cyan, magenta, yellow, magenta + yellow (red), cyan + yellow (green), cyan + magenta (blue),
    cyan + magenta + yellow (near black) — the order of :data:`INK_PRIMARIES`. Paper is an uncoated office paper
    without optical brighteners (0.86, falling to 0.78 in the violet). Each ink is a transparent layer whose
    double-pass transmission ``10**(-density(lambda))`` has the absorption band of process inks: cyan absorbs
    600-700 nm (and some green), magenta 500-600 nm (and some blue), yellow 400-500 nm. Overprints multiply
    their transmissions (the subtractive model behind the Neugebauer equations, Wyble and Berns, Color Res.
    Appl. 25, 2000).

    Examples
    --------
    >>> r = ink_reflectances()
    >>> r.shape, bool(r[0].min() > 0.75), bool(r[7].max() < 0.2)  # paper is light, the overprint of all dark
    ((8, 61), True, True)
    """
    lam = WAVELENGTHS
    paper = 0.86 - 0.08 / (1.0 + np.exp((lam - 430.0) / 12.0))
    cyan = 1.6 / (1.0 + np.exp(-(lam - 585.0) / 14.0)) + 0.25 * _gauss(520.0, 35.0) + 0.05
    magenta = 1.5 * _gauss(545.0, 38.0) + 0.2 * _gauss(440.0, 30.0) + 0.04
    yellow = 1.4 / (1.0 + np.exp((lam - 490.0) / 12.0)) + 0.04
    density = {"c": cyan, "m": magenta, "y": yellow}
    rows = [paper * 10.0 ** -sum((density[ink] for ink in inks), np.zeros_like(lam)) for inks in INK_PRIMARIES]
    return np.stack(rows)


#: The inks on each Neugebauer primary of :func:`ink_reflectances`, in its row order.
INK_PRIMARIES = ("", "c", "m", "y", "my", "cy", "cm", "cmy")


def print_primaries() -> np.ndarray:
    """The light reflected by the eight Neugebauer primaries of a print under the white LED, shape (8, n).

    :func:`ink_reflectances` times :func:`white_led`: what a print of the target sends to the camera.

    Examples
    --------
    >>> round(float(luminance(print_primaries()[0])), 2)  # bare paper
    0.86
    """
    return ink_reflectances() * white_led()
