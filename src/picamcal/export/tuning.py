"""The calibration's flat field as a static lens shading table in a libcamera tuning file (``rpi.alsc``).

The exported tables are not simply the flat field sampled at the cell centres: libcamera and the ISP
interpolate them (see :mod:`picamcal.export.isp`), so the table values are chosen by least squares so
that the *interpolated* gains fit the measured field best, over every bin of the frame, edges included.
"""

from __future__ import annotations

import copy
import json
import math
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .._atomic import atomic_path
from .._json import read_libcamera_yaml
from .._version import __version__
from ..calibration import Calibration
from ..errors import CalibrationFileError, PicamcalWarning
from ..sensors import LSC_GRIDS, find_sensor_name
from .isp import (
    RECORD_KEY,
    TuningError,
    check_hardware_range,
    check_tuning,
)
from .tuning_fit import (  # noqa: F401 - how the table is chosen, importable from here as before
    IMPORTED_KEY,
    SMOOTHNESS,
    GainFit,
    alsc_tables,
    fit_gain_tables,
    mode_coverage,
    neutral_colour_gains,
    sensor_mode_geometries,
)

#: Where libcamera installs the stock tuning files on Raspberry Pi OS.
STOCK_TUNING_DIR = Path("/usr/share/libcamera/ipa/rpi")
_TARGET_DIRS = {"bcm2835": "vc4", "pisp": "pisp"}


def installed_tuning_dirs(folder: str) -> list[Path]:
    """Where a Raspberry Pi keeps libcamera's tuning files for ``folder`` (``vc4`` or ``pisp``), in the order
    picamera2 looks (``Picamera2.load_tuning_file``): a libcamera built in ``~/libcamera``, one installed in
    ``/usr/local``, then Raspberry Pi OS's own.

    Examples
    --------
    >>> [str(path) for path in installed_tuning_dirs("pisp")][1:]
    ['/usr/local/share/libcamera/ipa/rpi/pisp', '/usr/share/libcamera/ipa/rpi/pisp']
    """
    return [
        Path(os.path.expanduser(f"~/libcamera/src/ipa/rpi/{folder}/data")),
        Path("/usr/local/share/libcamera/ipa/rpi") / folder,
        STOCK_TUNING_DIR / folder,
    ]


#: Raspberry Pi's stock tuning files that ship with picamcal, for computers that are not a Raspberry Pi.
BUNDLED_TUNING_DIR = Path(__file__).resolve().parent.parent / "data" / "libcamera-tuning"
#: The names users know the targets by (libcamera's IPA directories) -> tuning file targets.
TARGET_NAMES = {"vc4": "bcm2835", "pisp": "pisp"}


def load_tuning(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read and check a libcamera tuning file (version 2, a known target), as libcamera would.

    libcamera reads tuning files with its YAML parser, so a JSON file with a trailing comma (two of Raspberry Pi's
    own have one) loads, and what that parser refuses is refused with the reason and line
    (:func:`picamcal._json.parse_libcamera_yaml`).

    Raises
    ------
    TuningError
        Missing, not a regular file, unreadable, not what libcamera's parser reads (or nested absurdly deep), not
        version 2, an unknown target, or sections that break libcamera's rules
        (:func:`~picamcal.export.tuning_rules.check_tuning`).

    Examples
    --------
    >>> tuning = load_tuning(stock_tuning_path("imx219", "bcm2835"))  # on a Pi: /usr/share/libcamera/ipa/rpi/vc4/...
    >>> tuning["target"]
    'bcm2835'
    """
    path = Path(path)
    if not os.path.lexists(path):
        raise TuningError("no such tuning file", path)
    tuning = read_libcamera_yaml(path, TuningError, "a libcamera tuning file")
    check_tuning(tuning, path)
    return tuning


def bundled_tuning_sensors(target: str) -> list[str]:
    """The names of the stock tuning files for ``target`` that ship with picamcal (every one libcamera ships).

    Examples
    --------
    >>> names = bundled_tuning_sensors("pisp")
    >>> len(names), names[:3]
    (34, ['imx219', 'imx219_noir', 'imx283'])
    """
    return sorted(p.stem for p in (BUNDLED_TUNING_DIR / _TARGET_DIRS[target]).glob("*.json"))


def stock_tuning_files(sensor: str) -> dict[str, dict[str, Path]]:
    """A sensor's stock tuning files: variant (``""`` for the sensor's own file) -> target -> path.

    The variants are the files named ``<sensor>_<variant>.json`` (``imx708_wide_noir.json``, ``imx477_16mm.json``)
    that are not another registry sensor's (``imx296_mono.json`` is the monochrome ``imx296_mono``'s). Each file is
    the one picamera2 finds on a Raspberry Pi (:func:`installed_tuning_dirs`: the file the camera loads), else the
    copy picamcal ships.

    Examples
    --------
    >>> files = stock_tuning_files("imx708")
    >>> sorted(files), sorted(files["wide"])
    (['', 'noir', 'wide', 'wide_noir'], ['bcm2835', 'pisp'])
    >>> {variant: sorted(targets) for variant, targets in stock_tuning_files("imx296").items()}
    {'': ['bcm2835', 'pisp'], '6mm': ['pisp'], '16mm': ['pisp']}
    """
    sensor = sensor.lower()
    files: dict[str, dict[str, Path]] = {}
    for target, folder in _TARGET_DIRS.items():
        for root in (*installed_tuning_dirs(folder), BUNDLED_TUNING_DIR / folder):
            for path in sorted(root.glob(f"{sensor}*.json")):
                stem = path.stem.lower()
                if stem == sensor:
                    variant = ""
                elif stem.startswith(f"{sensor}_") and find_sensor_name(stem) in (None, sensor):
                    variant = stem[len(sensor) + 1 :]
                else:
                    continue
                if path.is_file():
                    files.setdefault(variant, {}).setdefault(target, path)
    return dict(sorted(files.items(), key=lambda item: _variant_order(item[0])))


def _variant_order(variant: str) -> tuple[int, int, str]:
    """The sensor's own file, the variants by name, then the lens variants by focal length (6mm before 16mm)."""
    digits = variant.removesuffix("mm")
    return (2, int(digits), "") if variant.endswith("mm") and digits.isdigit() else (int(bool(variant)), 0, variant)


def describe_variants(sensor: str) -> str:
    """The variants of a sensor's stock tuning files, for a message: ``noir, wide, wide_noir`` (with the targets
    of those that are not for both), or ``none``.

    Examples
    --------
    >>> describe_variants("imx477")
    'noir, scientific, v1 (vc4 only), 6mm (pisp only), 16mm (pisp only)'
    """
    names = {target: name for name, target in TARGET_NAMES.items()}
    described = [
        f"{variant} ({names[next(iter(targets))]} only)" if len(targets) == 1 else variant
        for variant, targets in stock_tuning_files(sensor).items()
        if variant
    ]
    return ", ".join(described) or "none"


def stock_tuning_path(sensor: str, target: str, variant: str | None = None) -> Path:
    """The stock tuning file of a sensor (or of one of its variants) for a target (``"bcm2835"`` or ``"pisp"``).

    On a Raspberry Pi, the file picamera2 finds (:func:`installed_tuning_dirs`; it matches the libcamera the camera
    runs); elsewhere the copy picamcal ships (Raspberry Pi's stock files, BSD-2-Clause,
    ``picamcal/data/libcamera-tuning``).

    Raises
    ------
    TuningError
        The sensor has no stock file (then ``--base`` is needed), has no such variant (the message lists those it
        has), or has none for this target.

    Examples
    --------
    >>> stock_tuning_path("imx219", "pisp").name, stock_tuning_path("imx708", "bcm2835", "wide").name
    ('imx219.json', 'imx708_wide.json')
    >>> stock_tuning_path("imx477", "vc4").parent.name  # the platform's name is taken too
    'vc4'

    """
    return stock_tuning_bases(sensor, (target,), variant)[0][0]


def stock_tuning_bases(
    sensor: str, targets: Sequence[str] = ("bcm2835", "pisp"), variant: str | None = None
) -> tuple[list[Path], str | None]:
    """The stock tuning files of a sensor (or of one of its variants) for ``targets``, and a note on the targets
    that have none (None if every one has a file).

    Where several targets are asked for, those with a file are enough (``imx296_16mm`` is for the Pi 5 only;
    ``imx327`` for earlier Pis only); where one is asked for, it must have one.

    Raises
    ------
    TuningError
        No stock file for the sensor (give ``--base``), no such variant (the message lists the sensor's), or none
        for the targets asked for.

    Examples
    --------
    >>> paths, note = stock_tuning_bases("imx296", variant="16mm")
    >>> [p.name for p in paths], note
    (['imx296_16mm.json'], 'Raspberry Pi ships no vc4 tuning file for the imx296_16mm: wrote the pisp one only')
    """
    sensor, variant = sensor.lower(), (variant or "").lower().replace("-", "_")
    targets = [TARGET_NAMES.get(target, target) for target in targets]  # vc4 and pisp, as users name them, too
    unknown = [target for target in targets if target not in _TARGET_DIRS]
    if unknown:
        raise TuningError(f"unknown tuning target {unknown[0]!r} (expected vc4, pisp, bcm2835)")
    files = stock_tuning_files(sensor)
    name = f"{sensor}_{variant}" if variant else sensor
    labels = {target: label for label, target in TARGET_NAMES.items()}
    if not files:
        raise TuningError(
            f"Raspberry Pi ships no stock tuning file for the {sensor}: give the sensor's tuning file with --base"
        )
    if variant not in files:
        if variant:
            other = find_sensor_name(name)
            aside = f" ({name}.json is for the {other}, another sensor)" if other and other != sensor else ""
            raise TuningError(
                f"the {sensor} has no stock tuning variant {variant!r}{aside}; "
                f"its variants: {describe_variants(sensor)}"
            )
        raise TuningError(
            f"Raspberry Pi ships no standard tuning file for the {sensor}, only its variants: choose one with "
            f"--variant ({describe_variants(sensor)})"
        )
    found = [files[variant][target] for target in targets if target in files[variant]]
    missing = [labels[target] for target in targets if target not in files[variant]]
    if not found:
        raise TuningError(
            f"Raspberry Pi ships no {' or '.join(missing)} tuning file for the {name}, only a "
            f"{' and a '.join(labels[t] for t in files[variant])} one (--target)"
        )
    note = None
    if missing:
        written = " and ".join(labels[t] for t in targets if t in files[variant])
        note = f"Raspberry Pi ships no {' or '.join(missing)} tuning file for the {name}: wrote the {written} one only"
    return found, note


class ExportBases(NamedTuple):
    """What :func:`export_bases` chose: the base files, their name for the outputs, and a note for the user."""

    #: The base tuning files, one per target.
    paths: list[Path]
    #: The sensor the export is for (given, the calibration's, or from the base's name), or None if nothing says.
    sensor: str | None
    #: The outputs' name before ``_<vc4|pisp>.json``: the sensor and variant (``imx708_wide``), else the base's.
    stem: str
    #: Which targets have no stock file (where others have), or that the generic base was taken; None if neither.
    note: str | None
    #: The bases are libcamera's generic ``uncalibrated.json``: the sensor has no stock file (:func:`load_export_base`
    #: sets its black level).
    generic: bool = False


#: libcamera's tuning file for a sensor it has none for, which picamcal ships for each target.
GENERIC_TUNING = "uncalibrated"


def generic_tuning_path(target: str) -> Path:
    """libcamera's generic tuning file (``uncalibrated.json``) for a target, as picamcal ships it.

    Examples
    --------
    >>> generic_tuning_path("pisp").name, generic_tuning_path("vc4").parent.name
    ('uncalibrated.json', 'vc4')
    """
    target = TARGET_NAMES.get(target, target)
    if target not in _TARGET_DIRS:
        raise TuningError(f"unknown tuning target {target!r} (expected vc4, pisp, bcm2835)")
    return BUNDLED_TUNING_DIR / _TARGET_DIRS[target] / f"{GENERIC_TUNING}.json"


def load_export_base(path: str | os.PathLike[str], chosen: ExportBases) -> dict[str, Any]:
    """A base :func:`export_bases` chose, loaded (:func:`load_tuning`); the generic one with the sensor's black level
    from the registry (on libcamera's 16-bit scale), so that a sensor without a stock file gets a base that works.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(simulate_references(make_camera("imx585", size=(384, 216)), seed=1)["white"])
    >>> chosen = export_bases(cal, targets=["pisp"])
    >>> chosen.generic, load_export_base(chosen.paths[0], chosen)["algorithms"][0]
    (True, {'rpi.black_level': {'black_level': 3200}})
    """
    from ..sensors import SENSORS

    tuning = load_tuning(path)
    entry = SENSORS.get(chosen.sensor or "")
    if chosen.generic and entry is not None:
        level = entry.black_level << (16 - entry.bit_depth)
        _set_algorithm(tuning["algorithms"], "rpi.black_level", {"black_level": level}, after="")
    return tuning


def export_bases(
    calibration: Calibration,
    *,
    base: str | os.PathLike[str] | None = None,
    targets: Sequence[str] = ("bcm2835", "pisp"),
    variant: str | None = None,
    sensor: str | None = None,
) -> ExportBases:
    """The tuning files ``picamcal export-tuning`` starts from: ``base``, else the sensor's stock files for ``targets``.

    The sensor is the calibration's, else ``sensor`` (checked with :func:`picamcal.sensors.given_sensor`: a near
    miss of a registry name gets "did you mean"); a ``sensor`` that names a stock variant (``imx708_wide``) picks
    that variant. With ``base``, ``sensor`` says which sensor the base is for (default: from its file name).

    Raises
    ------
    TuningError
        ``sensor`` is not the calibration's, nothing says the sensor, ``variant`` with ``base``, or no stock file
        fits (:func:`stock_tuning_bases`: the message lists the sensor's variants).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx708", size=(320, 180)), seed=1))
    >>> chosen = export_bases(cal, variant="wide")
    >>> [p.name for p in chosen.paths], chosen.stem
    (['imx708_wide.json', 'imx708_wide.json'], 'imx708_wide')
    """
    from ..sensors import given_sensor

    named = None
    if sensor is not None:
        named = given_sensor(sensor)
        text = "_".join(sensor.lower().replace("-", "_").split())
        suffix = text[len(named) + 1 :] if text.startswith(f"{named}_") else ""
        if suffix and suffix in stock_tuning_files(named):  # --sensor imx708_wide: the wide Camera Module 3
            if variant and variant.lower() != suffix:
                raise TuningError(f"--sensor {sensor} is the {suffix} variant, but --variant says {variant}")
            variant = suffix
    if base is not None:
        if variant:
            raise TuningError("--variant chooses one of Raspberry Pi's stock files: leave it out with --base")
        base_sensor = named or sensor_of_tuning_file(base)
        return ExportBases([Path(base)], base_sensor, calibration.sensor or base_sensor or Path(base).stem, None)
    if named and calibration.sensor and named != calibration.sensor:
        raise TuningError(
            f"the calibration is for the {calibration.sensor}, not the {named} --sensor names", calibration.path
        )
    chosen = calibration.sensor or named
    if chosen is None:
        raise TuningError(
            "the calibration does not say its sensor: name it with --sensor (or give a tuning file with --base)",
            calibration.path,
        )
    if not variant and not stock_tuning_files(chosen):
        paths = [generic_tuning_path(target) for target in targets]
        generic = (
            f"Raspberry Pi ships no tuning file for the {chosen}: started from libcamera's {GENERIC_TUNING}.json "
            f"(bundled with picamcal, its black level set to the {chosen}'s); give the sensor's own with --base"
        )
        return ExportBases(paths, chosen, chosen, generic, generic=True)
    paths, note = stock_tuning_bases(chosen, targets, variant)
    variant = (variant or "").lower().replace("-", "_")
    return ExportBases(paths, chosen, f"{chosen}_{variant}" if variant else chosen, note)


def load_calibration_to_export(path: str | os.PathLike[str], sensor: str | None = None) -> Calibration:
    """The calibration to export: a picamcal calibration, or the flat field of a lens shading table a user has (a
    legacy ``.npy``, an OpenFlexure ``microscope_settings.npz``, a C header, a libcamera tuning file), for ``sensor``
    where the file does not say (:func:`picamcal.export.tables.load_flat_field`); whoever gives an image is told to
    make a calibration first.

    Raises
    ------
    CalibrationFileError
        As ``load_flat_field``; for an image: "this is a raw image, not a calibration: make one ... with picamcal
        calibrate".

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> path = picamcal.write_dng("white.dng", simulate_references(make_camera("imx219", size=(320, 240)))["white"])
    >>> load_calibration_to_export("white.dng")
    Traceback (most recent call last):
    ...
    picamcal.errors.CalibrationFileError: white.dng: this is a raw image, not a calibration: make one from the \
reference images with picamcal calibrate, then export that .npz
    >>> np.save("lst.npy", np.full((4, 39, 52), 40, np.uint8))  # picamcal export-lst's table, for the IMX219
    >>> load_calibration_to_export("lst.npy").kind
    'flat'
    """
    from ..calibration.archive import ImageNotCalibrationError
    from .tables import load_flat_field

    try:
        return load_flat_field(path, sensor)
    except ImageNotCalibrationError as exc:
        raise CalibrationFileError(
            f"this is {exc.kind}, not a calibration: make one from the reference images with picamcal calibrate, "
            "then export that .npz",
            path,
        ) from None


def table_tuning(path: str | os.PathLike[str], sensor: str | None = None, target: str = "pisp") -> dict[str, Any]:
    """The tuning a lens shading table gives a camera: its flat field
    (:func:`picamcal.export.tables.load_flat_field`) exported into the sensor's stock tuning file for ``target``
    (:func:`export_tuning`); what ``apply-tuning`` applies for a legacy table.

    Examples
    --------
    >>> np.save("lst.npy", np.full((4, 39, 52), 40, np.uint8))
    >>> tuning = table_tuning("lst.npy")
    >>> tuning["target"], "colour_gains" in tuning["picamcal"]  # a table keeps no colour balance
    ('pisp', False)
    """
    from .tables import load_flat_field

    calibration = load_flat_field(path, sensor)
    chosen = export_bases(calibration, targets=[target])
    return export_tuning(calibration, load_export_base(chosen.paths[0], chosen), base_path=chosen.paths[0])


def neutral_tuning(stock: dict[str, Any]) -> dict[str, Any]:
    """A copy of a libcamera tuning with a static unity lens shading table, so nothing adapts the shading.

    What :class:`~picamcal.acquire.cameras.Picamera2Camera` opens the camera with to capture references:
    ``rpi.alsc`` gets ``n_iter`` 0, unity ``calibrations_Cr`` and ``calibrations_Cb`` tables and a unity
    ``luminance_lut`` (the target's grid, :data:`picamcal.sensors.LSC_GRIDS`), and loses ``corner_strength``;
    everything else is kept. Exposure and white balance are frozen by explicit controls instead.

    Parameters
    ----------
    stock : dict
        The sensor's stock tuning (``Picamera2.load_tuning_file("imx219.json")``); never modified.

    Returns
    -------
    dict

    Raises
    ------
    TuningError
        ``stock`` is not a tuning libcamera would load (:func:`~picamcal.export.tuning_rules.check_tuning`).

    Examples
    --------
    >>> stock = {"version": 2.0, "target": "bcm2835", "algorithms": [{"rpi.alsc": {"n_iter": 100}}]}
    >>> alsc = neutral_tuning(stock)["algorithms"][0]["rpi.alsc"]
    >>> alsc["n_iter"], len(alsc["luminance_lut"]), set(alsc["calibrations_Cr"][0]["table"])
    (0, 192, {1.0})
    """
    target = check_tuning(stock, "the stock tuning")
    columns, rows = LSC_GRIDS[target]
    unity = [1.0] * (columns * rows)
    tuning = copy.deepcopy(stock)
    algorithms = tuning["algorithms"]
    entry = next((a for a in algorithms if "rpi.alsc" in a), None)
    if entry is None:
        entry = {"rpi.alsc": {}}
        algorithms.append(entry)
    alsc = entry["rpi.alsc"]
    alsc.pop("corner_strength", None)
    alsc.update(
        n_iter=0,
        luminance_strength=1.0,
        luminance_lut=list(unity),
        calibrations_Cr=[{"ct": 4500, "table": list(unity)}],
        calibrations_Cb=[{"ct": 4500, "table": list(unity)}],
    )
    return tuning


def _ccm_from_calibration(calibration: Calibration) -> list[float]:
    """``Cx``, the centre's inverse colour response: white-balanced camera RGB to the illuminator's primaries.

    A flat-field calibration (white only) has no colour response: CalibrationFileError, one line with the fix.
    """
    cx = calibration.require_unmixing("--ccm (the colour matrix)").colour_response_inverse
    return [round(float(v), 5) for v in cx.ravel()]


def _set_algorithm(algorithms: list[dict[str, Any]], name: str, params: dict[str, Any], after: str) -> bool:
    """Replace algorithm ``name``'s parameters, or insert it after ``after`` (or at the end); True if added."""
    for entry in algorithms:
        if name in entry:
            entry[name] = params
            return False
    names = [next(iter(a)) for a in algorithms]
    position = names.index(after) + 1 if after in names else len(algorithms)
    algorithms.insert(position, {name: params})
    return True


def export_tuning(
    calibration: Calibration,
    base: dict[str, Any],
    *,
    ct: float = 4500,
    luminance_strength: float = 1.0,
    ccm: bool = False,
    clip_gains: bool = False,
    base_sensor: str | None = None,
    base_path: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """A copy of a tuning file with a static lens shading table (and optionally CCM) from the calibration.

    Every other algorithm and key stays as it was, in its order. In ``rpi.alsc``: ``n_iter`` 0 (no
    adaptation), ``luminance_strength``, ``luminance_lut``, and one ``calibrations_Cr`` and
    ``calibrations_Cb`` entry at colour temperature ``ct``; ``corner_strength`` (which would replace the
    luminance table) is removed. With ``ccm``, ``rpi.ccm`` gets one matrix at ``ct``: the calibration's
    ``Cx``, which maps white-balanced camera RGB to the illuminator's primaries (sRGB only as far as the
    LEDs' primaries are sRGB's).

    The table covers the full sensor, as libcamera's do: the calibration's cells are placed at its sensor mode's
    crop (:func:`fit_gain_tables`), so its own mode and every mode inside its crop come out flat; a calibration
    from a cropped mode extends the table beyond its crop by its edge values, with a warning naming the modes it
    extrapolates (:func:`mode_coverage`).

    A top-level ``"picamcal"`` entry, which libcamera ignores, records the colour gains that make the
    calibration's white neutral through this very file (:func:`neutral_colour_gains`: the tables of each
    target and of each sensor mode are normalised differently, so each needs its own) in the calibration's mode
    (``colour_gains``) and in every sensor mode (``colour_gains_by_mode``, keyed ``WIDTHxHEIGHT:BITS``), the
    calibration's geometry, the modes it covers and those it extrapolates, its file name and the version of
    picamcal.

    Parameters
    ----------
    calibration : Calibration
    base : dict
        The tuning file to start from (``load_tuning``); never modified.
    ct : float
        Colour temperature of the single table entry, kelvin.
    luminance_strength : float
        libcamera's ``luminance_strength``: 1 corrects the vignetting fully.
    ccm : bool
        Also write ``rpi.ccm``.
    clip_gains : bool
        Clip gains at the hardware limit (with a warning) instead of refusing.
    base_sensor : str, optional
        The sensor the base file is for (from its file name); refused if the calibration's differs.
    base_path : path-like, optional
        The base's file, named in the errors about it.

    Raises
    ------
    TuningError
        The base is not a usable tuning file or is for another sensor (naming ``base_path``), or a gain is out
        of the hardware's range (naming the calibration's file, see :func:`alsc_tables`).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> tuning = export_tuning(cal, load_tuning(stock_tuning_path("imx219", "pisp")), ccm=True)
    >>> alsc = next(a["rpi.alsc"] for a in tuning["algorithms"] if "rpi.alsc" in a)
    >>> alsc["n_iter"], len(alsc["luminance_lut"])  # a static 32 x 32 table on a Pi 5
    (0, 1024)
    >>> tuning["picamcal"]["colour_gains"]  # rpicam-still --awbgains 1.2333,0.9837 makes the white neutral
    [1.2333, 0.9837]
    """
    target = check_tuning(base, base_path)
    if isinstance(ct, bool) or not isinstance(ct, (int, float)) or not math.isfinite(ct) or ct < 1:
        # libcamera refuses a table whose ct is not above the previous one, starting from 0
        raise TuningError(f"colour temperature {ct!r} is not a positive number of kelvin: give the light's, e.g. 4500")
    if base_sensor and calibration.sensor and base_sensor != calibration.sensor:
        raise TuningError(
            f"the calibration is for the {calibration.sensor}, the base tuning file for the {base_sensor}", base_path
        )
    if not 0 <= luminance_strength <= 1:
        raise TuningError(f"luminance strength {luminance_strength} is outside 0..1")
    tables = alsc_tables(calibration, target, luminance_strength=luminance_strength, clip_gains=clip_gains)
    tuning = copy.deepcopy(base)
    algorithms = tuning["algorithms"]
    alsc: dict[str, Any] = next((copy.deepcopy(a["rpi.alsc"]) for a in algorithms if "rpi.alsc" in a), {})
    alsc.pop("corner_strength", None)
    alsc.update(
        {
            "n_iter": 0,
            "luminance_strength": luminance_strength,
            "calibrations_Cr": [{"ct": int(ct), "table": _rounded(tables["Cr"])}],
            "calibrations_Cb": [{"ct": int(ct), "table": _rounded(tables["Cb"])}],
            "luminance_lut": _rounded(tables["luminance_lut"]),
        }
    )
    if _set_algorithm(algorithms, "rpi.alsc", alsc, after="rpi.agc"):
        warnings.warn("the base tuning file had no rpi.alsc section; added one", PicamcalWarning, stacklevel=2)
    if ccm:
        section: dict[str, Any] = next((copy.deepcopy(a["rpi.ccm"]) for a in algorithms if "rpi.ccm" in a), {})
        section["ccms"] = [{"ct": int(ct), "ccm": _ccm_from_calibration(calibration)}]
        _set_algorithm(algorithms, "rpi.ccm", section, after="rpi.contrast")
    check_hardware_range(tuning)
    tuning.pop(RECORD_KEY, None)  # last, after the stock file's own keys
    coverage = mode_coverage(calibration)
    modes = sensor_mode_geometries(calibration)
    assert calibration.geometry is not None
    # A table keeps each channel's shape only, not the camera's colour balance: no gains can be said to make its
    # white neutral, and the camera's own white balance (or its frozen gains) is what applies.
    imported = IMPORTED_KEY in calibration.provenance
    gains: dict[str, Any] = {}
    if not imported:
        gains["colour_gains"] = list(neutral_colour_gains(calibration, tuning))
        gains["colour_gains_by_mode"] = {
            name: list(neutral_colour_gains(calibration, tuning, mode)) for name, mode in modes.items()
        }
    tuning[RECORD_KEY] = {
        **gains,
        "colour_gains_use": IMPORTED_GAINS_USE if imported else COLOUR_GAINS_USE,
        "calibration": calibration.path.name if calibration.path else None,
        "sensor": calibration.sensor,
        "geometry": calibration.geometry.to_record(),
        "modes_covered": coverage["covered"],
        "modes_extrapolated": coverage["extrapolated"],
        "software_version": __version__,
    }
    if coverage["extrapolated"]:
        x, y, w, h = calibration.geometry.crop
        warnings.warn(
            f"the calibration covers the {w}x{h} sensor area at ({x}, {y}) only: the table is measured for modes "
            f"{', '.join(coverage['covered']) or 'none'} and extrapolated for {', '.join(coverage['extrapolated'])} "
            "(calibrate in the full-resolution or a binned mode to cover every mode)",
            PicamcalWarning,
            stacklevel=2,
        )
    return tuning


#: What the recorded colour gains are for, in the exported file itself.
COLOUR_GAINS_USE = (
    "red and blue gains that make the calibration's white neutral through this file: rpicam-apps --awbgains R,B, "
    "Picamera2 ColourGains (R, B); libcamera ignores this entry"
)


#: What stands in the record's place of the colour gains for a table's flat field.
IMPORTED_GAINS_USE = (
    "from a lens shading table, which keeps no colour balance: set the colour gains from a white through this file "
    "(auto white balance, then freeze it), as with the table before"
)


def _rounded(table: np.ndarray) -> list[float]:
    return [round(float(v), 4) for v in table.ravel()]


def save_tuning(path: str | os.PathLike[str], tuning: dict[str, Any], overwrite: bool = False) -> Path:
    """Write a tuning file as JSON, atomically (temporary name, then rename), if libcamera and the ISP can use it.

    Raises
    ------
    TuningError
        A section breaks libcamera's rules (:func:`~picamcal.export.tuning_rules.check_tuning`), a gain or colour matrix
        coefficient is outside the hardware's range (:func:`~picamcal.export.tuning_rules.check_hardware_range`), or a
        value is not JSON (NaN, infinity); nothing is written.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> save_tuning("imx219_pisp.json", export_tuning(cal, load_tuning(stock_tuning_path("imx219", "pisp"))))
    PosixPath('imx219_pisp.json')
    """
    path = Path(path)
    check_hardware_range(tuning)
    try:
        text = json.dumps(tuning, indent=4, allow_nan=False) + "\n"
    except (TypeError, ValueError, RecursionError) as exc:
        raise TuningError(f"cannot be written as a tuning file ({exc})", path) from None
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_text(text)
    return path


def sensor_of_tuning_file(path: str | os.PathLike[str]) -> str | None:
    """The sensor a stock tuning file is for, from its name (``imx219.json``, ``imx219_noir.json``).

    Examples
    --------
    >>> sensor_of_tuning_file(stock_tuning_path("imx708", "pisp", "wide")), sensor_of_tuning_file("imx219_noir.json")
    ('imx708', 'imx219')
    >>> sensor_of_tuning_file("my_tuned_camera.json") is None  # not a name the registry knows
    True
    """
    return find_sensor_name(Path(path).stem)


def is_tuning_file(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is a libcamera tuning file: one ``overwrite`` may replace with another.

    Examples
    --------
    >>> is_tuning_file(stock_tuning_path("imx219", "pisp"))
    True
    """
    try:
        load_tuning(path)
    except TuningError:
        return False
    return True
