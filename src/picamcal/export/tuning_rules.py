"""libcamera's rules for a tuning file, and the ranges of the Raspberry Pi ISP's hardware.

:func:`check_tuning` refuses what libcamera's Raspberry Pi IPA would refuse to load (its controller's version 2
format, a known target, the sections picamcal reads or writes: ``rpi.alsc``, ``rpi.black_level``, ``rpi.ccm``,
``rpi.contrast``); :func:`check_hardware_range` what it would load but the hardware cannot apply (a lens shading
gain or a colour matrix coefficient out of range). :mod:`picamcal.export.isp` emulates what the ISP does with
a file that passes both.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from typing import Any

import numpy as np

from .._json import Fields
from ..errors import PicamcalError
from ..limits import MAX_COLOUR_GAIN
from ..sensors import LSC_GRIDS

#: Largest gain each target's hardware can apply (exclusive): vc4 stores u4.10 (at most 16383 / 1024), the PiSP
#: packs a vertex's three gains in its widest range, [0, 8) in 10 bits (libcamera's ``packLscLut``).
GAIN_LIMITS = {"bcm2835": 16.0, "pisp": 8.0}
#: libcamera clamps every colour matrix coefficient to this range (``Ccm::prepare``).
CCM_LIMITS = (-8.0, 7.9999)


#: The top-level entry where ``export-tuning`` records what it knows of the file (the colour gains that make the
#: calibration's white neutral through it); libcamera's controller reads only ``version``, ``target`` and
#: ``algorithms`` of a version 2 file (src/ipa/rpi/controller/controller.cpp), so it ignores this one.
RECORD_KEY = "picamcal"


class TuningError(PicamcalError):
    """A tuning file that cannot be used, or a table the hardware cannot apply."""


def check_tuning(tuning: Any, source: str | os.PathLike[str] | None = None) -> str:
    """Check a tuning file as libcamera reads it; return its target (``"bcm2835"`` or ``"pisp"``).

    The top level (version 2, a known target, a list of one-key algorithms) and, by libcamera's own rules, the
    sections picamcal reads: ``rpi.alsc`` (tables of the target's grid size, colour temperatures positive and
    strictly increasing, ``corner_strength`` above 1), ``rpi.black_level``, ``rpi.ccm`` (3 x 3 matrices, colour
    temperatures strictly increasing; an empty list only in a base to export into) and ``rpi.contrast``'s
    ``gamma_curve`` (input, output pairs). Every value picamcal uses is a finite number of the right kind.

    Raises
    ------
    TuningError
        One line naming the file, the value and what libcamera requires.

    Examples
    --------
    >>> check_tuning({"version": 2.0, "target": "pisp", "algorithms": [{"rpi.black_level": {"black_level": 4096}}]})
    'pisp'
    >>> alsc = {"calibrations_Cr": [{"ct": 0, "table": [1.0] * 1024}]}
    >>> check_tuning({"version": 2.0, "target": "pisp", "algorithms": [{"rpi.alsc": alsc}]})
    Traceback (most recent call last):
    ...
    picamcal.export.tuning_rules.TuningError: not a usable libcamera tuning file: rpi.alsc \
calibrations_Cr[0].ct must be a positive number, not 0 (libcamera would refuse it)
    """
    if not isinstance(tuning, dict) or "algorithms" not in tuning:
        raise TuningError("not a version 2 libcamera tuning file (no 'algorithms' list)", source)
    version = tuning.get("version")
    if isinstance(version, bool) or not isinstance(version, (int, float)) or not 2.0 <= version < 3.0:
        shown = repr(version) if isinstance(version, (int, float)) and abs(version) < 1e6 else type(version).__name__
        raise TuningError(f"tuning file version {shown} is not 2.x (libcamera reads 2.x only)", source)
    target = tuning.get("target")
    if not isinstance(target, str) or target not in LSC_GRIDS:
        shown = repr(target) if isinstance(target, str) else type(target).__name__
        raise TuningError(f"unknown tuning target {shown[:40]} (expected {' or '.join(LSC_GRIDS)})", source)
    algorithms = tuning["algorithms"]
    if not isinstance(algorithms, list) or not all(isinstance(a, dict) and len(a) == 1 for a in algorithms):
        raise TuningError("'algorithms' must be a list of one-key objects", source)
    fields = Fields(source, TuningError, "a usable libcamera tuning file", "libcamera would refuse it")
    if RECORD_KEY in tuning:  # libcamera ignores it; apply-tuning uses its colour gains
        own = Fields(source, TuningError, "a usable tuning file", "export-tuning writes it: export again")
        gains = own.mapping(tuning[RECORD_KEY], RECORD_KEY).get("colour_gains", [1, 1])
        own.numbers(gains, f"{RECORD_KEY}.colour_gains", 2, positive=True, maximum=MAX_COLOUR_GAIN)
    names = [next(iter(algorithm)) for algorithm in algorithms]
    for algorithm in algorithms:
        name, params = next(iter(algorithm.items()))
        check = _SECTION_CHECKS.get(name)
        if check is not None:
            if names.count(name) > 1:  # libcamera's controller: "Algorithm type ... already exists"
                fields.fail(name, "appears twice, and libcamera runs one algorithm of each type")
            check(fields, fields.mapping(params, name), target)
    return target


def _check_alsc(fields: Fields, alsc: dict[str, Any], target: str) -> None:
    cols, rows = LSC_GRIDS[target]
    cells = cols * rows
    if "luminance_lut" in alsc:
        fields.numbers(alsc["luminance_lut"], "rpi.alsc luminance_lut", cells, positive=True)
    for key in ("calibrations_Cr", "calibrations_Cb"):
        last = 0.0
        for i, entry in enumerate(fields.items(alsc.get(key, []), f"rpi.alsc {key}")):
            where = f"rpi.alsc {key}[{i}]"
            fields.mapping(entry, where, ("ct", "table"))
            ct = fields.number(entry["ct"], f"{where}.ct", positive=True)
            if ct <= last:
                fields.fail(f"rpi.alsc {key}", f"must be in increasing ct order: {ct:g} K follows {last:g} K")
            last = ct
            fields.numbers(entry["table"], f"{where}.table", cells, positive=True)
    if "corner_strength" in alsc and fields.number(alsc["corner_strength"], "rpi.alsc corner_strength") <= 1:
        fields.fail("rpi.alsc corner_strength", f"must be above 1, not {alsc['corner_strength']!r}")
    if "asymmetry" in alsc:
        fields.number(alsc["asymmetry"], "rpi.alsc asymmetry", minimum=0)
    if "luminance_strength" in alsc:
        fields.number(alsc["luminance_strength"], "rpi.alsc luminance_strength")
    if "default_ct" in alsc:
        fields.number(alsc["default_ct"], "rpi.alsc default_ct", positive=True)
    if "n_iter" in alsc:
        fields.number(alsc["n_iter"], "rpi.alsc n_iter", integer=True, minimum=0)


def _check_black_level(fields: Fields, section: dict[str, Any], target: str) -> None:
    if "black_level" in section:
        fields.number(section["black_level"], "rpi.black_level black_level", minimum=0, maximum=65535)


def _check_ccm(fields: Fields, section: dict[str, Any], target: str) -> None:
    last = -math.inf
    # An empty list is a base to fill (export_tuning with ccm=True); check_hardware_range refuses writing it.
    for i, entry in enumerate(fields.items(section.get("ccms", []), "rpi.ccm ccms")):
        fields.mapping(entry, f"rpi.ccm ccms[{i}]", ("ct", "ccm"))
        ct = fields.number(entry["ct"], f"rpi.ccm ccms[{i}].ct")
        if ct <= last:
            fields.fail("rpi.ccm ccms", f"must be in increasing ct order: {ct:g} K follows {last:g} K")
        last = ct
        fields.numbers(entry["ccm"], f"rpi.ccm ccms[{i}].ccm", 9)


def _check_contrast(fields: Fields, section: dict[str, Any], target: str) -> None:
    if "gamma_curve" in section:
        curve = fields.numbers(section["gamma_curve"], "rpi.contrast gamma_curve")
        if len(curve) % 2:
            fields.fail("rpi.contrast gamma_curve", f"must hold (input, output) pairs, not {len(curve)} numbers")


_SECTION_CHECKS: dict[str, Callable[[Fields, dict[str, Any], str], None]] = {
    "rpi.alsc": _check_alsc,
    "rpi.black_level": _check_black_level,
    "rpi.ccm": _check_ccm,
    "rpi.contrast": _check_contrast,
}


def check_hardware_range(tuning: dict[str, Any], source: str | os.PathLike[str] | None = None) -> None:
    """Raise TuningError unless every gain the tuning's static lens shading asks for can be applied by the ISP.

    After :func:`check_tuning`: at every colour temperature of ``rpi.alsc``, the gains libcamera programs
    (``R = Cr / min(Cr) (1 + s (L - 1))``, ``G = 1 + s (L - 1)``, ``B = Cb / min(Cb) (1 + s (L - 1))``) must
    be positive and below the target's :data:`GAIN_LIMITS` (the ISP would clip them silently), and every
    ``rpi.ccm`` coefficient within :data:`CCM_LIMITS` (libcamera would clamp it).

    Examples
    --------
    >>> from picamcal.export.tuning import load_tuning, stock_tuning_path
    >>> tuning = load_tuning(stock_tuning_path("imx219", "pisp"))
    >>> check_hardware_range(tuning)  # Raspberry Pi's own file: every gain within range
    >>> tuning["algorithms"] = [{"rpi.alsc": {"luminance_lut": [9.0] * 1024}}]
    >>> check_hardware_range(tuning)
    Traceback (most recent call last):
    ...
    picamcal.export.tuning_rules.TuningError: rpi.alsc luminance gives a gain of 9, outside the pisp hardware's \
range of 0 to 8 (it would be clipped): export with clip_gains (--clip-gains), or a smoother white
    """
    target = check_tuning(tuning, source)
    limit = GAIN_LIMITS[target]
    for algorithm in tuning["algorithms"]:
        if "rpi.ccm" in algorithm:
            if not algorithm["rpi.ccm"].get("ccms"):
                raise TuningError(
                    'rpi.ccm holds no colour matrix, and libcamera refuses such a file ("No CCMs specified"): '
                    "export with ccm=True (--ccm), or start from a tuning file that has them",
                    source,
                )
            for entry in algorithm["rpi.ccm"]["ccms"]:
                worst = max(entry["ccm"], key=abs)
                if not CCM_LIMITS[0] <= worst <= CCM_LIMITS[1]:
                    raise TuningError(
                        f"rpi.ccm at {entry['ct']:g} K has a coefficient {worst:g}, outside the {CCM_LIMITS[0]:g} to "
                        f"{CCM_LIMITS[1]:g} libcamera applies (it would be clamped)",
                        source,
                    )
        if "rpi.alsc" not in algorithm:
            continue
        alsc = algorithm["rpi.alsc"]
        lum = np.asarray(alsc.get("luminance_lut", 1.0), dtype=np.float64)
        green = 1 + float(alsc.get("luminance_strength", 1.0)) * (lum - 1)
        entries = [(key, e) for key in ("calibrations_Cr", "calibrations_Cb") for e in alsc.get(key, [])]
        for where, gains in [("luminance", green)] + [
            (f"{key} at {e['ct']:g} K", np.asarray(e["table"], np.float64) / min(e["table"]) * green)
            for key, e in entries
        ]:
            if not np.all(np.isfinite(gains)) or gains.min() <= 0 or gains.max() >= limit:
                shown = gains.max() if np.all(gains > 0) else gains.min()
                raise TuningError(
                    f"rpi.alsc {where} gives a gain of {shown:.4g}, outside the {target} hardware's range of 0 to "
                    f"{limit:g} (it would be clipped): export with clip_gains (--clip-gains), or a smoother white",
                    source,
                )
