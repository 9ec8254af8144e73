"""The reference images of a calibration run: their roles, and finding them in a folder by name or manifest."""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any, NoReturn

from .errors import CalibrationInputError, PicamcalError, PicamcalWarning, closest
from .manifest import MANIFEST_NAME, AcquisitionError, load_manifest, manifest_light
from .raw import HEADLESS_SUFFIXES, RAW_SUFFIXES, RawImage

__all__ = [
    "COLOURS",
    "COLOUR_NAME",
    "MAX_COLOUR_NAME",
    "ROLES",
    "check_same_settings",
    "colour_name",
    "colour_role",
    "find_references",
    "parse_colours",
    "read_manifest",
    "reference_light",
    "role_of",
]

#: The roles of the reference images, in the order they are captured: the white, the three colours, the black
#: (LED off). The one list of them: calibration, acquisition, simulator and command line all use it.
ROLES = ("white", "red", "green", "blue", "black")
#: The colour references, each lit by one primary of the illuminator.
COLOURS = ("red", "green", "blue")
#: The name of an extra colour reference (role ``colour_<name>``: an LED mixture, a screen colour): letters, digits
#: and ``-``.
COLOUR_NAME = re.compile(r"[A-Za-z0-9-]+")
_COLOUR_PREFIX = "colour_"
# An extra colour reference's file: ``colour_<name>``, a frame number ``_<n>`` after it, a prefix before it.
_COLOUR_FILE = re.compile(r"(?:^|.*[^a-z0-9])colour_([a-z0-9-]+)(?:_\d+)?")
# What an acquisition must have captured before it can be calibrated.
_REQUIRED = ("white", *COLOURS)
# Every raw file a reference can be: headless dumps too, as calibrate takes their sensor and size as options.
_REFERENCE_SUFFIXES = frozenset((*RAW_SUFFIXES, *HEADLESS_SUFFIXES))
_PAPER_STYLE = re.compile(r"r(\d+)_g(\d+)_b(\d+)", re.IGNORECASE)


def colour_role(name: str) -> str:
    """The role of the extra colour reference called ``name``: ``colour_<name>``, in lower case.

    Examples
    --------
    >>> colour_role("Cyan")
    'colour_cyan'
    """
    return _COLOUR_PREFIX + name.lower()


def colour_name(role: str) -> str | None:
    """The name of an extra colour reference's role (``colour_cyan`` -> ``cyan``), or None for any other role.

    Examples
    --------
    >>> colour_name("colour_amber"), colour_name("red"), colour_name("colour_")
    ('amber', None, None)
    """
    name = role[len(_COLOUR_PREFIX) :] if role.startswith(_COLOUR_PREFIX) else ""
    return name if COLOUR_NAME.fullmatch(name) else None


def role_of(name: str) -> str | None:
    """The reference role a file name stands for, or None.

    Names hold the role as a word (``white.dng``, ``run3_red.dng``, ``white_2.dng``, ``white2.dng``) or, as in the
    paper's code, the LED setting (``..._r255_g0_b0.dng`` is red, all equal and non-zero is white, all zero is
    black). An extra colour reference is ``colour_<name>`` (``colour_cyan.dng``, ``colour_cyan_2.dng``,
    ``run3_colour_amber.dng``); a name that holds ``colour`` otherwise stands for no role.

    Examples
    --------
    >>> role_of("capture_r0_g255_b0.dng"), role_of("White.DNG"), role_of("white2.raw"), role_of("target.dng")
    ('green', 'white', 'white', None)
    >>> role_of("colour_cyan_2.dng"), role_of("run3_Colour_LED-590.dng"), role_of("colour_white_x.dng")
    ('colour_cyan', 'colour_led-590', None)
    """
    stem = Path(name).stem.lower()
    colour = _COLOUR_FILE.fullmatch(stem)
    if colour:
        return colour_role(colour.group(1))
    match = _PAPER_STYLE.search(stem)
    if match:
        r, g, b = (int(v) for v in match.groups())
        if r == g == b:
            return "black" if r == 0 else "white"
        lit = [role for role, v in zip(COLOURS, (r, g, b), strict=True) if v > 0]
        return lit[0] if len(lit) == 1 else None
    found = _roles_named(stem)
    return found[0] if len(found) == 1 else None


def _roles_named(stem: str) -> list[str]:
    """The roles a file name's words name (``white_red`` names two, and so stands for none)."""
    words = set(re.split(r"[^a-z0-9]+", stem))
    if "colour" in words:
        return []
    # A frame number may follow the role without a separator (white2, as a camera app counts its shots).
    return [role for role in ROLES if any(word.rstrip("0123456789") == role for word in words)]


def _natural(path: Path) -> tuple[list, str]:
    """Sort key that orders ``white_2`` before ``white_10``, and ``white`` before ``white2`` (the stem first)."""
    stem = [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.stem.lower())]
    return stem, path.suffix.lower()


def read_manifest(folder: str | os.PathLike[str], *, extras: bool = False) -> dict[str, Path]:
    """The captured files of an acquisition (``picamcal acquire``), role -> path, for ``picamcal calibrate DIR``.

    Parameters
    ----------
    folder : path-like
        A folder written by :func:`picamcal.acquire.acquisition.acquire`, with its ``manifest.json``
        (:func:`picamcal.manifest.load_manifest`).
    extras : bool
        Also return the extra images (test targets); by default only the references (:data:`ROLES` and extra
        colour references, ``colour_<name>``).

    Returns
    -------
    dict of str to Path
        ``white``, ``red``, ``green``, ``blue``, any ``colour_<name>`` and (when captured) ``black``, in capture
        order.

    Raises
    ------
    AcquisitionError
        No or a corrupt manifest, a required reference not captured yet, or a listed file missing.

    Examples
    --------
    A run of the simulated camera and light:

    >>> from picamcal.acquire.acquisition import acquire
    >>> from picamcal.acquire.cameras import SimCamera
    >>> camera = SimCamera("imx219", size=(64, 48))
    >>> _ = acquire(camera, camera.light, "run1", extras=["target"], prompt=print, settle_s=0)
    Put the target in front of the camera and press Enter
    >>> {role: path.name for role, path in read_manifest("run1").items()}
    {'white': 'white.dng', 'red': 'red.dng', 'green': 'green.dng', 'blue': 'blue.dng', 'black': 'black.dng'}
    >>> read_manifest("run1", extras=True)["target"].name
    'target.dng'
    """
    folder = Path(folder)
    record = load_manifest(folder)
    files = {
        e["role"]: folder / e["file"]
        for e in record["entries"]
        if extras or e["role"] in ROLES or colour_name(e["role"])
    }
    missing = [role for role in _REQUIRED if role not in files]
    if missing:
        raise AcquisitionError(
            f"the acquisition is incomplete (no {', '.join(missing)} yet): run picamcal acquire again with the same "
            "--out to finish it",
            folder,
        )
    for path in files.values():
        if not path.is_file():
            raise AcquisitionError("listed in the manifest but missing", path)
    return files


def _not_a_folder(path: Path) -> NoReturn:
    """Raise the error for a path given as the folder of references that is none: a calibration, a file, nothing."""
    if path.is_file():
        from .calibration import is_calibration_file  # only here: a calibration is read only to be recognised

        if is_calibration_file(path):  # by its content, as load_calibration reads it, whatever its name
            raise CalibrationInputError(
                f"{path} is a picamcal calibration, not a folder of reference images: give the folder of references "
                "or --white (a jig calibration to combine with a white goes to --unmixing-from)"
            )
        raise CalibrationInputError(
            "a file, not a folder of reference images: give its folder, or the file as --white (--red, --green, "
            "--blue, --black)",
            path,
        )
    raise CalibrationInputError("no such folder of reference images", path)


def find_references(folder: str | Path, *, in_situ: bool = False) -> dict[str, Path | list[Path]]:
    """Map each role to its file (or files) in a folder.

    The white is required and the black optional. Red, green and blue come all three (a full calibration) or
    not at all (a flat-field calibration from the white alone); with ``in_situ`` (the colours come from a
    jig calibration) they are not looked for, nor are extra colour references (``colour_<name>.dng``, roles
    ``colour_<name>``, :func:`role_of`). Several files of one role (``white_1.dng``, ``white_2.dng``,
    ...) are frames to average: that role maps to a list of them, in natural name order. A folder written
    by ``picamcal acquire`` is read through its ``manifest.json``, which names each file's role.

    Raises
    ------
    CalibrationInputError
        The folder is missing (a file given instead is named as such: a picamcal calibration, recognised by its
        content, or another file) or cannot be listed, has no white, or has some but not all of red, green and
        blue.
    AcquisitionError
        The folder holds a ``manifest.json`` that is not a usable one (:func:`read_manifest`).

    Examples
    --------
    Only the names are looked at (empty files will do here):

    >>> from pathlib import Path
    >>> for name in ("white.dng", "red.dng", "green.dng", "blue.dng", "notes.txt"):
    ...     _ = Path(name).write_bytes(b"")
    >>> {role: path.name for role, path in find_references(".").items()}
    {'blue': 'blue.dng', 'green': 'green.dng', 'red': 'red.dng', 'white': 'white.dng'}
    >>> _ = Path("white_2.dng").write_bytes(b"")
    >>> [path.name for path in find_references(".")["white"]]
    ['white.dng', 'white_2.dng']
    >>> _ = Path("colour_cyan.dng").write_bytes(b"")
    >>> find_references(".")["colour_cyan"].name
    'colour_cyan.dng'

    A name that names two references is passed over with a warning (:class:`~picamcal.errors.PicamcalWarning`):
    ``white_red.dng`` is neither the white nor the red.
    """
    folder = Path(folder)
    if not folder.is_dir():
        _not_a_folder(folder)
    if not in_situ and (folder / MANIFEST_NAME).is_file():
        return dict(read_manifest(folder))
    try:
        entries = sorted(folder.iterdir(), key=_natural)
    except OSError as exc:
        raise CalibrationInputError(f"cannot list the folder: {exc.strerror or exc}", folder) from None
    found: dict[str, list[Path]] = {}
    for path in entries:
        # is_file follows links and is False for a FIFO, a device or a symlink loop: those are left out
        role = role_of(path.name) if path.suffix.lower() in _REFERENCE_SUFFIXES and path.is_file() else None
        if role and not (in_situ and (role in COLOURS or colour_name(role))):
            found.setdefault(role, []).append(path)
        elif role is None and path.suffix.lower() in _REFERENCE_SUFFIXES:
            named = _roles_named(path.stem.lower())
            if len(named) > 1:  # not silently: the user meant it as one of them
                warnings.warn(
                    f"{path.name} names {' and '.join(named)}: passed over (name a file for one reference)",
                    PicamcalWarning,
                    stacklevel=2,
                )
    if "white" not in found:
        what = "white" if found else "white, red, green, blue or black"
        raise CalibrationInputError(
            f"no {what} reference found (a white alone is enough, for a flat field: files named e.g. white.dng, "
            "white_1.dng or *_r255_g255_b255.dng)",
            folder,
        )
    missing = [role for role in COLOURS if role not in found]
    extra = next((role for role in found if colour_name(role)), None)
    if len(missing) == 3 and extra:
        raise CalibrationInputError(
            f"{found[extra][0].name} is an extra colour reference, but there is no red, green or blue: extra "
            "colours refine the unmixing of the three primaries' references, give those too",
            folder,
        )
    if len(missing) in (1, 2):
        raise CalibrationInputError(
            f"no {', '.join(missing)} reference found: give red, green and blue references together, or none "
            "of them for a flat-field calibration (white only)",
            folder,
        )
    return {role: paths[0] if len(paths) == 1 else paths for role, paths in found.items()}


def check_same_settings(frame: RawImage, first: RawImage, role: str) -> None:
    """Raise unless ``frame`` was taken with the settings of ``first``, the first frame of the reference ``role``.

    Several frames of one reference are averaged (:func:`picamcal.calibrate`), which is the mean of one scene only
    when they share their settings: the same black level, and where both files record them, exposure times and
    analogue gains within 1 % (the files' rounding of them).

    Raises
    ------
    CalibrationInputError
        Naming ``frame``'s file and the setting that differs.

    Examples
    --------
    >>> from picamcal.raw import RawImage
    >>> first = RawImage(np.zeros((4, 4), np.uint16), "RGGB", 64, 1023, 10, None, {"exposure_time_s": 0.01})
    >>> check_same_settings(first, first, "white")
    >>> later = RawImage(first.bayer, "RGGB", 64, 1023, 10, None, {"exposure_time_s": 0.02, "path": "white2.dng"})
    >>> check_same_settings(later, first, "white")
    Traceback (most recent call last):
    ...
    picamcal.errors.CalibrationInputError: white2.dng: exposure time (s) 0.02 differs from the first white frame's \
0.01: frames of one reference are averaged, so they must come from the same settings
    """
    levels = [list(raw.black_level) for raw in (frame, first)]
    same = all(a == b or (math.isnan(a) and math.isnan(b)) for a, b in zip(*levels, strict=True))  # NaN: unknown
    differences = [] if same else [("black level", *map(str, levels))]
    for key, what in (("exposure_time_s", "exposure time (s)"), ("analogue_gain", "analogue gain")):
        pair: list[Any] = [raw.metadata.get(key) for raw in (frame, first)]
        if all(isinstance(v, (int, float)) and v > 0 for v in pair) and not math.isclose(*pair, rel_tol=0.01):
            differences.append((what, f"{pair[0]:g}", f"{pair[1]:g}"))
    if differences:
        what, value, wanted = differences[0]
        raise CalibrationInputError(
            f"{what} {value} differs from the first {role} frame's {wanted}: frames of one reference are averaged, so "
            "they must come from the same settings",
            frame.source,
        )


def reference_light(folder: str | os.PathLike[str] | None, light: str | None = None) -> str | None:
    """The light a calibration's references were taken under (:data:`picamcal.calibration.LIGHTS`), or None.

    ``light`` when given; else, for the folder of an acquisition (``picamcal acquire``), the light of the illuminator
    its manifest names (:func:`picamcal.manifest.manifest_light`); else None: not known.

    Raises
    ------
    CalibrationInputError
        ``light`` is not one of the lights (with "did you mean"), or another than the acquisition's.
    AcquisitionError
        The folder holds a ``manifest.json`` that is not a usable one (:func:`picamcal.manifest.load_manifest`).

    Examples
    --------
    >>> from picamcal.acquire.acquisition import acquire
    >>> from picamcal.acquire.cameras import SimCamera
    >>> camera = SimCamera("imx219", size=(64, 48))
    >>> _ = acquire(camera, camera.light, "run1", settle_s=0)
    >>> reference_light("run1"), reference_light(None, "Screen"), reference_light(None)
    ('jig', 'screen', None)
    """
    from .calibration import LIGHTS  # the calibration's schema, read only when a light is asked for

    given = None
    if light is not None:
        given = light.lower() if isinstance(light, str) else ""
        if given not in LIGHTS:
            near = closest(str(light), LIGHTS)
            raise CalibrationInputError(
                f"unknown light {str(light)[:40]!r} (expected {', '.join(LIGHTS)})"
                + (f"; did you mean {near}?" if near else "")
            )
    manifest = None if folder is None else Path(folder) / MANIFEST_NAME
    if manifest is None or not manifest.is_file():
        return given
    record = load_manifest(manifest.parent)
    recorded = manifest_light(record)
    if given is not None and recorded is not None and given != recorded:
        kind = record["illuminator"]["kind"]
        raise CalibrationInputError(
            f"the acquisition's illuminator was {kind}, which gives {LIGHTS[recorded]} ({recorded}), not {given}: "
            "leave the light out, it is read from this manifest",
            manifest,
        )
    return given or recorded


#: The longest name of an extra colour, in characters: it names files.
MAX_COLOUR_NAME = 40


def parse_colours(specs: Iterable[str]) -> dict[str, tuple[int, int, int]]:
    """Extra colours given as ``NAME=R,G,B`` (``--colour``), name -> (R, G, B) in 0-255, in the order given.

    Each becomes the reference ``colour_NAME`` (:func:`picamcal.references.colour_role`, in lower case): a
    full-screen ``screen_colour_NAME.png``, or the illuminator set to that RGB in ``picamcal acquire``.

    Parameters
    ----------
    specs : iterable of str
        ``NAME=R,G,B``: a name of letters, digits and ``-`` (at most 40), not a reference's name
        (:data:`picamcal.references.ROLES`), and three whole numbers 0-255.

    Raises
    ------
    PicamcalError
        One line naming the faulty specification: not ``NAME=R,G,B``, a value outside 0-255, a name of other
        characters, a reference's name, or a name given twice (names differing only in case count as the same:
        they would be the same file on some file systems).

    Examples
    --------
    >>> parse_colours(["cyan=0,255,255", "amber=255,191,0"])
    {'cyan': (0, 255, 255), 'amber': (255, 191, 0)}
    >>> parse_colours(["red=255,0,0"])
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: 'red=255,0,0': red is a reference already (white, red, green, blue, black); \
name the extra colour otherwise
    """
    colours: dict[str, tuple[int, int, int]] = {}
    for spec in specs:
        name, equals, values = spec.partition("=")
        name = name.strip()
        numbers = [v.strip() for v in values.split(",")]
        if not equals or len(numbers) != 3:
            raise PicamcalError(f"{spec!r} is not NAME=R,G,B (e.g. cyan=0,255,255)")
        if not COLOUR_NAME.fullmatch(name) or len(name) > MAX_COLOUR_NAME:
            raise PicamcalError(
                f"{spec!r}: the name must be 1 to {MAX_COLOUR_NAME} letters, digits or '-' (it names the file)"
            )
        if name.lower() in ROLES:
            raise PicamcalError(
                f"{spec!r}: {name} is a reference already ({', '.join(ROLES)}); name the extra colour otherwise"
            )
        if not all(v.isascii() and v.isdigit() and int(v) <= 255 for v in numbers):
            raise PicamcalError(f"{spec!r}: R, G and B must be whole numbers from 0 to 255")
        if name.lower() in (given.lower() for given in colours):
            raise PicamcalError(f"{spec!r}: the colour {name} is given twice")
        r, g, b = (int(v) for v in numbers)
        colours[name] = (r, g, b)
    return colours
