"""What the spectral simulator is shown: reference illuminations of a light source, and the colour-wheel target.

Two light sources give references (:class:`LightSource`): the calibration jig's RGB LED (:func:`jig_source`) and a
monitor showing full-screen colours (:func:`monitor_source`). A reference role is an amount of each of the
source's three primaries: ``white`` all three, ``red``, ``green``, ``blue`` one each, ``black`` none (a monitor
still leaks light at black), and ``colour_<name>`` any mixture given to it.

The target is the colour-wheel target of :mod:`picamcal.colour_wheel` filling the frame, as the fast simulator
photographs it, in one of two physical forms (:data:`TARGETS`):

- ``monitor``: shown on the monitor, each pixel's linear sRGB amounts driving its primaries;
- ``print``: printed in cyan, magenta and yellow ink and lit by the white LED; a pixel of linear sRGB amounts
  ``(r, g, b)`` is printed with ink coverages ``(1 - r, 1 - g, 1 - b)`` and reflects the Neugebauer mixture of
  the eight ink overprints with the Demichel weights (products of each coverage or its complement), which is
  exact on the target's solid segments and is area coverage on its anti-aliased edges;
- ``led``: made of the jig LED's own three primaries, as the fast simulator's target is (a target on which a
  jig calibration is exact: its floor is 0).

Examples
--------
>>> from picamcal.simulate.spectral import make_spectral_camera
>>> camera = make_spectral_camera("imx219", size=(320, 240))
>>> target = target_scene(camera, "print")
>>> target.weights.shape, target.spectra.shape, target.colour_names[:3]
((240, 320, 8), (8, 61), ['white', 'red', 'yellow'])
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..colour_wheel import SEGMENTS, wheel_layout, wheel_scene
from ..errors import PicamcalError
from ..raw.model import RawImage
from ..references import ROLES
from .scenes import TARGET_STREAM, stream
from .spectra import INK_PRIMARIES, jig_led, monitor_primaries, print_primaries
from .spectral import SpectralCamera, expected_spectral_response, render_spectral, white_balance

__all__ = [
    "PRINT_SHEETS",
    "SECONDARY_COLOURS",
    "SOURCES",
    "TARGETS",
    "LightSource",
    "TargetScene",
    "colour_amounts",
    "jig_source",
    "monitor_source",
    "print_references",
    "reference_spectra",
    "spectral_references",
    "spectral_target",
    "target_scene",
    "target_white",
]

#: The secondaries as amounts of a source's primaries: the extra ``colour_<name>`` references a spectral run
#: writes unless told otherwise, and those of the accuracy table's ``-extras`` workflows.
SECONDARY_COLOURS: dict[str, tuple[float, float, float]] = {
    "cyan": (0.0, 1.0, 1.0),
    "magenta": (1.0, 0.0, 1.0),
    "yellow": (1.0, 1.0, 0.0),
}

#: Physical forms of the colour-wheel target.
TARGETS = ("monitor", "print", "led")
_COLOUR_ROLE = re.compile(r"colour_[A-Za-z0-9-]+")


@dataclass(frozen=True, eq=False)
class LightSource:
    """A source of uniform reference light: three primaries and what it emits when all are off.

    Attributes
    ----------
    name : str
        ``"jig"`` or ``"monitor"``.
    basis : ndarray, shape (4, n)
        Rows 0-2 the red, green and blue primaries at full drive, row 3 the light at zero drive (zero for the jig).

    Examples
    --------
    >>> round(float(monitor_source().spectrum("black").sum() / monitor_source().spectrum("white").sum()), 4)
    0.001
    """

    name: str
    basis: np.ndarray

    def spectrum(self, role: str, amounts: ArrayLike | None = None) -> np.ndarray:
        """The spectrum of a reference role (``white`` ... ``black``, or ``colour_<name>`` with its amounts)."""
        a = colour_amounts(role, amounts)
        return np.asarray(a @ self.basis[:3] + self.basis[3], dtype=np.float64)


def colour_amounts(role: str, amounts: ArrayLike | None = None) -> np.ndarray:
    """Amounts (3,) of the primaries of a reference role; a ``colour_<name>`` role takes them from ``amounts``.

    Examples
    --------
    >>> colour_amounts("red").tolist(), colour_amounts("colour_amber", (1.0, 0.5, 0.0)).tolist()
    ([1.0, 0.0, 0.0], [1.0, 0.5, 0.0])
    """
    if _COLOUR_ROLE.fullmatch(role):
        if amounts is None:
            raise PicamcalError(f"the reference {role!r} needs its amounts of red, green and blue")
        a = np.asarray(amounts, dtype=np.float64)
        if a.shape != (3,) or np.any(a < 0) or np.any(a > 1) or not np.all(np.isfinite(a)):
            raise PicamcalError(f"the amounts of {role!r} must be three numbers from 0 to 1, got {amounts!r}")
        return a
    if role not in ROLES:
        raise PicamcalError(f"unknown reference {role!r} (expected one of {', '.join(ROLES)} or colour_NAME)")
    if role == "white":
        return np.ones(3)
    return np.array([float(role == c) for c in ("red", "green", "blue")])


def jig_source() -> LightSource:
    """The calibration jig: the WS2812-class LED of :func:`picamcal.simulate.spectra.jig_led`, dark when off.

    Examples
    --------
    >>> jig_source().basis.shape
    (4, 61)
    """
    lines = jig_led()
    return LightSource("jig", np.concatenate([lines, np.zeros_like(lines[:1])]))


def monitor_source(contrast: float = 1000.0) -> LightSource:
    """A monitor showing full-screen colours (:func:`picamcal.simulate.spectra.monitor_primaries`).

    Examples
    --------
    >>> monitor_source().name
    'monitor'
    """
    return LightSource("monitor", monitor_primaries(contrast))


#: Reference light sources by name.
SOURCES = {"jig": jig_source, "monitor": monitor_source}


def reference_spectra(source: LightSource, colours: Mapping[str, ArrayLike] | None = None) -> dict[str, np.ndarray]:
    """The spectra of the five references of a source (in the order of ROLES) and of extra ``colour_<name>`` ones.

    Parameters
    ----------
    source : LightSource
    colours : mapping of str to 3 amounts, optional
        Extra references by name (``"cyan"`` or ``"colour_cyan"``) -> amounts of red, green and blue (0 to 1).

    Examples
    --------
    >>> list(reference_spectra(jig_source(), {"cyan": (0, 1, 1)}))
    ['white', 'red', 'green', 'blue', 'black', 'colour_cyan']
    """
    spectra = {role: source.spectrum(role) for role in ROLES}
    for name, amounts in (colours or {}).items():
        role = name if name.startswith("colour_") else f"colour_{name}"
        spectra[role] = source.spectrum(role, amounts)
    return spectra


def spectral_references(
    camera: SpectralCamera,
    source: LightSource,
    *,
    colours: Mapping[str, ArrayLike] | None = None,
    noise: bool = True,
    seed: int = 0,
) -> dict[str, RawImage]:
    """Render the references of a light source: white, red, green, blue, black and any ``colour_<name>``.

    Every frame has its own random stream of the seed (the fast simulator's, :func:`picamcal.simulate.scenes.stream`:
    one per role in the order of ROLES, the extra colours after the target's) and carries the white balance
    frozen on the source's white as ``metadata["colour_gains"]``.

    Examples
    --------
    >>> from picamcal.simulate.spectral import make_spectral_camera
    >>> camera = make_spectral_camera("imx219", size=(320, 240))
    >>> refs = spectral_references(camera, monitor_source(), noise=False)
    >>> list(refs), refs["white"].metadata["scene"]
    (['white', 'red', 'green', 'blue', 'black'], 'white')
    """
    return _render_references(camera, reference_spectra(source, colours), source.name, noise, seed)


def _render_references(
    camera: SpectralCamera, spectra: Mapping[str, np.ndarray], source: str, noise: bool, seed: int
) -> dict[str, RawImage]:
    gains = white_balance(camera, spectra["white"])
    frames = {}
    for i, (role, spectrum) in enumerate(spectra.items()):
        index = i if i < len(ROLES) else i + 2  # after the dust and target streams
        raw = render_spectral(camera, spectrum, noise=noise, rng=stream(seed, index), scene=role)
        raw.metadata.update(colour_gains=gains, source=source)
        frames[role] = raw
    return frames


#: The printed sheets that serve as references for a print target, by role: the Neugebauer primary of
#: :data:`picamcal.simulate.spectra.INK_PRIMARIES` each shows (paper for white; the overprints for red, green and
#: blue; the single inks as extra colours). The overprint of all three inks is too dark to serve.
PRINT_SHEETS = {
    "white": "",
    "red": "my",
    "green": "cy",
    "blue": "cm",
    "colour_cyan": "c",
    "colour_magenta": "m",
    "colour_yellow": "y",
}


def print_references(camera: SpectralCamera, *, noise: bool = True, seed: int = 0) -> dict[str, RawImage]:
    """Render printed reference sheets under the white LED: paper, the red, green and blue overprints, the three
    inks alone (:data:`PRINT_SHEETS`), and a dark frame.

    A print target's colours are mixtures of these eight spectra (the Neugebauer model), so a least-squares unmixing
    over these references fits the print's own spectra: the print's counterpart of a monitor's full-screen colours.

    Examples
    --------
    >>> from picamcal.simulate.spectral import make_spectral_camera
    >>> from picamcal.simulate.spectral_scenes import target_white
    >>> refs = print_references(make_spectral_camera("imx219", size=(320, 240), white=target_white("print")))
    >>> list(refs)
    ['white', 'red', 'green', 'blue', 'black', 'colour_cyan', 'colour_magenta', 'colour_yellow']
    """
    primaries = dict(zip(INK_PRIMARIES, print_primaries(), strict=True))
    spectra = {role: primaries[inks] for role, inks in PRINT_SHEETS.items() if role in ROLES}
    spectra["black"] = np.zeros_like(primaries[""])
    spectra.update({role: primaries[inks] for role, inks in PRINT_SHEETS.items() if role not in ROLES})
    return _render_references(camera, spectra, "print", noise, seed)


@dataclass(frozen=True, eq=False)
class TargetScene:
    """The colour-wheel target as weights of basis spectra, with the spectra of its distinct colours.

    Attributes
    ----------
    kind : str
        A name of :data:`TARGETS`.
    layout : dict
        :func:`picamcal.colour_wheel.wheel_layout` of the frame.
    weights : ndarray of float32, shape (H, W, K)
    spectra : ndarray, shape (K, n)
        The basis spectra, scaled by the target's exposure.
    colour_names : list of str
        ``"white"`` (the background) and the segment names.
    colour_spectra : ndarray, shape (len(colour_names), n)
        The spectrum of each of those colours (same scale).
    """

    kind: str
    layout: dict[str, Any]
    weights: np.ndarray
    spectra: np.ndarray
    colour_names: list[str]
    colour_spectra: np.ndarray


def _demichel(amounts: np.ndarray) -> np.ndarray:
    """Demichel weights (..., 8) of the Neugebauer primaries for linear sRGB amounts (..., 3) printed in CMY."""
    coverage = {"c": 1.0 - amounts[..., 0], "m": 1.0 - amounts[..., 1], "y": 1.0 - amounts[..., 2]}
    weights = []
    for inks in INK_PRIMARIES:
        w = np.ones(amounts.shape[:-1], dtype=amounts.dtype)
        for ink, cover in coverage.items():
            w = w * (cover if ink in inks else 1.0 - cover)
        weights.append(w)
    return np.stack(weights, axis=-1)


def _basis_weights(kind: str, amounts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weights of the basis spectra for sRGB amounts (..., 3), and the basis (K, n)."""
    if kind == "monitor":
        basis = monitor_primaries()
        leak = np.ones((*amounts.shape[:-1], 1), dtype=amounts.dtype)
        return np.concatenate([amounts, leak], axis=-1), basis
    if kind == "print":
        return _demichel(amounts), print_primaries()
    if kind == "led":
        dark = np.ones((*amounts.shape[:-1], 1), dtype=amounts.dtype)  # the jig's zero row: weight irrelevant
        return np.concatenate([amounts, dark], axis=-1), jig_source().basis
    raise PicamcalError(f"unknown target {kind!r} (expected one of {', '.join(TARGETS)})")


def target_scene(camera: SpectralCamera, kind: str = "monitor", *, exposure: float = 0.8) -> TargetScene:
    """The colour-wheel target filling the frame, shown on the monitor or printed, exposed like a reference.

    Parameters
    ----------
    camera : SpectralCamera
    kind : {"monitor", "print", "led"}
    exposure : float
        The target's white (its background) peaks at this fraction of the range (the user exposes the target
        photograph on its own).

    Examples
    --------
    >>> from picamcal.simulate.spectral import make_spectral_camera
    >>> scene = target_scene(make_spectral_camera("imx219", size=(320, 240)), "monitor")
    >>> scene.weights.shape, scene.colour_spectra.shape
    ((240, 320, 4), (7, 61))
    """
    layout = wheel_layout(camera.width, camera.height)
    amounts = wheel_scene(layout).astype(np.float32)
    weights, basis = _basis_weights(kind, amounts)
    colours = np.array([(1.0, 1.0, 1.0), *(c for _, c in SEGMENTS)])
    colour_weights, _ = _basis_weights(kind, colours)
    white = colour_weights[0] @ basis
    peak = float(expected_spectral_response(camera, white).max())
    gain = exposure * (camera.base.white_level - camera.base.black_level) / peak
    spectra = basis * gain
    return TargetScene(
        kind=kind,
        layout=layout,
        weights=weights.astype(np.float32),
        spectra=spectra,
        colour_names=["white", *(name for name, _ in SEGMENTS)],
        colour_spectra=colour_weights @ spectra,
    )


def target_white(kind: str) -> np.ndarray:
    """The white of a target's form: the monitor's full-screen white, paper under the white LED, or the jig's white.

    What an in-situ white reference of that target shows (unscaled: the spectra's own units).

    Examples
    --------
    >>> from picamcal.simulate.spectra import luminance
    >>> round(float(luminance(target_white("monitor"))), 3), round(float(luminance(target_white("print"))), 2)
    (1.001, 0.86)
    """
    if kind not in TARGETS:
        raise PicamcalError(f"unknown target {kind!r} (expected one of {', '.join(TARGETS)})")
    colours, basis = _basis_weights(kind, np.ones((1, 3)))
    return np.asarray(colours[0] @ basis, dtype=np.float64)


def spectral_target(
    camera: SpectralCamera, kind: str = "monitor", *, noise: bool = True, seed: int = 0
) -> tuple[RawImage, TargetScene]:
    """Render the colour-wheel target (:func:`target_scene`) with the target's random stream of the seed.

    Examples
    --------
    >>> from picamcal.simulate.spectral import make_spectral_camera
    >>> raw, scene = spectral_target(make_spectral_camera("imx219", size=(320, 240)), "print", noise=False)
    >>> raw.metadata["scene"], raw.metadata["target"], len(scene.layout["wheels"])
    ('target', 'print', 9)
    """
    scene = target_scene(camera, kind)
    raw = render_spectral(camera, scene.spectra, scene.weights, noise=noise, rng=stream(seed, TARGET_STREAM))
    raw.metadata.update(scene="target", target=kind)
    return raw, scene
