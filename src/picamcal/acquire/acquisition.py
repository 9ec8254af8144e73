"""Acquiring a calibration run: auto-expose on white, freeze the settings, capture every illumination.

This follows the paper's section "Measurements" and FORMATS.md section 7. With the camera's pipeline neutral
(no adaptive lens shading), :func:`auto_expose` finds from the raw data the exposure that puts a high
percentile of the black-subtracted white at a target fraction of the range without clipping; exposure, gain and
white balance are then frozen and :func:`acquire` captures white, red, green, blue and black (LED off), then any
extra colours (``colour_NAME``, the illuminator set to that RGB: an LED mixture, a full-screen colour), then any
extra named images (a test target) with the same settings, prompting the user before each. Each frame is saved
as ``ROLE.dng`` with a ``ROLE.json`` sidecar, and ``manifest.json`` lists what has been captured after every
frame, so an interrupted run keeps its files and a re-run resumes where it stopped. :func:`read_manifest` gives
``picamcal calibrate`` the files.

The manifest's format, :data:`MANIFEST_NAME`, :class:`AcquisitionError` and :func:`load_manifest` live in
:mod:`picamcal.manifest`, and :func:`read_manifest` in :mod:`picamcal.references`, so that reading a run needs
nothing of the acquisition; they are re-exported here.
"""

from __future__ import annotations

import errno
import json
import math
import os
import time
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, cast

import numpy as np

from .._atomic import atomic_path
from .._version import __version__
from ..bayer import balance_gains
from ..calibrate import MAX_CLIPPED_FRACTION
from ..colour_wheel import wheel_layout, wheel_scene
from ..errors import OutputError, PicamcalError, PicamcalWarning
from ..manifest import FRAME_FORMAT, MANIFEST_FORMAT, MANIFEST_NAME, MANIFEST_VERSION, AcquisitionError, load_manifest
from ..raw.dng import write_dng
from ..raw.model import RawImage
from ..records import json_default, sha256_file
from ..references import colour_name, colour_role, parse_colours, read_manifest, role_of
from .base import Illuminator, IlluminatorError, check_rgb
from .cameras import Camera, SimCamera, open_camera
from .illuminators import REFERENCE_LIGHTS, SimIlluminator, open_illuminator

__all__ = [
    "MANIFEST_NAME",
    "AcquisitionError",
    "AcquisitionInterrupted",
    "Rig",
    "acquire",
    "auto_expose",
    "load_manifest",
    "open_rig",
    "read_manifest",
]

_START_EXPOSURE_US = 10_000.0
_MAX_ITERATIONS = 12
_SAMPLE_PIXELS = 2_000_000  # auto-exposure statistics on at most this many pixels (whole 2x2 blocks)


class AcquisitionInterrupted(AcquisitionError):
    """The user pressed Ctrl-C; what was captured is kept and listed in the manifest."""


def _white_statistics(raw: RawImage, percentile: float) -> tuple[float, float]:
    """The black-subtracted ``percentile`` as a fraction of the range, and the fraction of clipped pixels."""
    signal = raw.black_subtracted()
    step = max(1, math.isqrt(raw.bayer.size // _SAMPLE_PIXELS))
    if step > 1:  # every step-th 2x2 block: all four sites stay represented
        h, w = signal.shape
        signal = signal.reshape(h // 2, 2, w // 2, 2)[::step, :, ::step, :]
    usable = raw.white_level - float(np.mean(raw.black_level))
    fraction = float(np.percentile(signal, percentile)) / usable
    clipped = float(np.count_nonzero(raw.bayer >= raw.white_level)) / raw.bayer.size
    return fraction, clipped


def _colour_gains(raw: RawImage) -> tuple[float, float]:
    """Red and blue gains that make the centre of the white neutral (green / red, green / blue)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        red, blue = balance_gains(raw.black_subtracted(), raw.pattern)
    if not (np.isfinite(red) and np.isfinite(blue) and red > 0 and blue > 0):
        return 1.0, 1.0
    return round(red, 4), round(blue, 4)


def auto_expose(
    camera: Camera,
    *,
    target_fraction: float = 0.8,
    percentile: float = 99.9,
    tolerance: float = 0.03,
    max_exposure_s: float = 1.0,
) -> dict[str, Any]:
    """Find the exposure that puts the white's high percentile at a target fraction of the range, unclipped.

    The camera must be looking at the white light. The black-subtracted ``percentile`` of the raw frame is
    driven to ``target_fraction`` of ``white_level - black_level`` (within ``tolerance``, relative): the signal
    is linear, so each step scales the exposure by ``target / measured``; a clipped frame (more than
    :data:`picamcal.calibrate.MAX_CLIPPED_FRACTION` of its pixels at the white level) divides it by 4. The
    exposure time grows first, at the lowest gain; the gain only beyond ``max_exposure_s``. The camera is left
    at the settings found, with the colour gains that make the centre of the white neutral.

    Parameters
    ----------
    camera : Camera
        Configured (``configure_raw``) and under white light.
    target_fraction : float
        Where the percentile should land, in (0, 1).
    percentile : float
        The high percentile of all pixels (all colour channels together).
    tolerance : float
        Relative tolerance on the landing point.
    max_exposure_s : float
        Longest exposure time to use (or the camera's limit, if shorter).

    Returns
    -------
    dict
        ``exposure_time_us`` (int), ``analogue_gain``, ``colour_gains`` ([red, blue]), ``target_fraction``,
        ``percentile``, ``white_fraction`` (where the percentile landed), ``clipped_fraction`` and
        ``iterations`` (frames taken).

    Raises
    ------
    AcquisitionError
        The white clips even at the shortest exposure and lowest gain (dim the light), stays below half the
        target at the longest exposure and highest gain (brighten the light), or does not settle.

    Examples
    --------
    >>> camera = SimCamera("imx219", size=(320, 240))
    >>> camera.configure_raw()
    >>> camera.light.set_rgb(255, 255, 255)
    >>> found = auto_expose(camera)
    >>> abs(found["white_fraction"] - 0.8) <= 0.03 * 0.8, found["clipped_fraction"]
    (True, 0.0)
    """
    if not 0 < target_fraction < 1:
        raise AcquisitionError(f"the target fraction must be between 0 and 1, got {target_fraction}")
    if not 50 <= percentile <= 100:
        raise AcquisitionError(f"the percentile must be between 50 and 100, got {percentile}")
    limits = camera.limits()
    t_min, t_max = limits.exposure_time_us
    g_min, g_max = limits.analogue_gain
    t_min, t_max = math.ceil(t_min), math.floor(min(t_max, 1e6 * max_exposure_s))
    if t_max < t_min:
        raise AcquisitionError(f"the longest exposure {max_exposure_s} s is shorter than the camera's shortest")

    def split(product: float) -> tuple[int, float]:
        """Exposure time first, at the lowest gain; then the gain."""
        if product / g_min <= t_max:
            return min(t_max, max(t_min, round(product / g_min))), g_min
        return t_max, min(g_max, max(g_min, product / t_max))

    product = min(max(_START_EXPOSURE_US * g_min, t_min * g_min), t_max * g_max)
    for iteration in range(1, _MAX_ITERATIONS + 1):
        exposure_us, gain = split(product)
        camera.set_controls(exposure_us, gain)
        raw = camera.capture()
        fraction, clipped = _white_statistics(raw, percentile)
        shortest = exposure_us <= t_min and gain <= g_min
        longest = exposure_us >= t_max and gain >= g_max
        settings = f"{exposure_us} µs at gain {gain:.3g}"
        if clipped > MAX_CLIPPED_FRACTION:
            if shortest:
                raise AcquisitionError(
                    f"the white clips ({100 * clipped:.2f} % of the pixels at full scale) even at the shortest "
                    f"exposure and lowest gain ({settings}): dim the light or add a diffuser"
                )
            product = max(exposure_us * gain / 4, t_min * g_min)
            continue
        done = abs(fraction / target_fraction - 1) <= tolerance or (shortest and fraction > target_fraction)
        if not done and longest and fraction < target_fraction:
            if fraction < target_fraction / 2:
                raise AcquisitionError(
                    f"the white is too dark ({100 * fraction:.1f} % of full scale at the {percentile:g}th percentile) "
                    f"even at the longest exposure and highest gain ({settings}; {100 * target_fraction:.0f} % "
                    "wanted): brighten the light or bring it closer"
                )
            done = True
        if done:
            colour_gains = _colour_gains(raw)
            camera.set_controls(exposure_us, gain, colour_gains)
            return {
                "exposure_time_us": int(exposure_us),
                "analogue_gain": float(gain),
                "colour_gains": list(colour_gains),
                "target_fraction": target_fraction,
                "percentile": percentile,
                "white_fraction": round(fraction, 5),
                "clipped_fraction": clipped,
                "iterations": iteration,
            }
        # Hardly any signal says little about how far off it is: take a big step.
        scale = 64.0 if fraction <= 1e-3 else target_fraction / fraction
        product = min(max(exposure_us * gain * scale, t_min * g_min), t_max * g_max)
    raise AcquisitionError(
        f"the white did not settle at {100 * target_fraction:.0f} % of full scale in {_MAX_ITERATIONS} frames: "
        "is the light flickering or still warming up?"
    )


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _write_json(path: Path, record: Mapping[str, Any]) -> None:
    text = json.dumps(record, indent=2, default=json_default) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _check_extras(extras: Iterable[str]) -> list[str]:
    names: list[str] = []
    for name in extras:
        if not name or not all(c.isalnum() or c in "-_" for c in name) or not name.isascii():
            raise AcquisitionError(f"extra name {name!r} must be letters, digits, '-' or '_' (it names the file)")
        if name in REFERENCE_LIGHTS or name == Path(MANIFEST_NAME).stem or role_of(f"{name}.dng") is not None:
            raise AcquisitionError(
                f"extra name {name!r} would be taken for a reference or the manifest; choose another"
            )
        if name in names:
            raise AcquisitionError(f"extra name {name!r} is given twice")
        names.append(name)
    return names


def _colour_lights(
    record: Mapping[str, Any] | None, given: Mapping[str, tuple[int, int, int]], folder: Path
) -> dict[str, tuple[int, int, int]]:
    """The light of each extra colour's role ``colour_NAME``: those of the run being resumed, then the new ones.

    A colour given again must have the RGB it was planned with (its frames would not match otherwise).
    """
    lights: dict[str, tuple[int, int, int]] = {}
    planned = (record or {}).get("colours") or {}
    if not isinstance(planned, dict):
        raise AcquisitionError(f"the manifest's colours are not a mapping; move {MANIFEST_NAME} away", folder)
    for role, light in planned.items():
        try:
            lights[str(role)] = check_rgb(*light)
        except (TypeError, IlluminatorError):
            raise AcquisitionError(
                f"the manifest's colour {role} is not R, G, B; move {MANIFEST_NAME} away", folder
            ) from None
    for name, light in given.items():
        role = colour_role(name)
        if lights.get(role, light) != light:
            raise AcquisitionError(
                f"cannot resume this run: its colour {name} is {lights[role]}, not {light}; give --colour "
                f"{name}={','.join(map(str, lights[role]))} or use another --out for a new run",
                folder,
            )
        lights[role] = light
    return lights


def _rig_mismatch(record: Mapping[str, Any], camera: Camera, illuminator: Illuminator) -> str | None:
    """Why this camera and illuminator cannot continue the run of ``record``, or None."""
    before, now = record.get("camera") or {}, camera.describe()
    for key in ("kind", "sensor", "size"):
        if before.get(key) != now.get(key):
            return f"it was started with another camera ({key} {before.get(key)}, now {now.get(key)})"
    for key in ("sensor_mode", "crop"):  # recorded since sensor modes can be chosen
        if key in before and before[key] != now.get(key):
            return f"it was started in another sensor mode ({key} {before[key]}, now {now.get(key)})"
    light_before, light_now = (record.get("illuminator") or {}).get("kind"), illuminator.describe().get("kind")
    if light_before != light_now:
        return f"it was started with the {light_before} illuminator, not {light_now} (the colours would differ)"
    return None


def _kept_entries(record: dict[str, Any], folder: Path) -> list[dict[str, Any]]:
    """The manifest's entries whose files are still there unchanged; the others are captured again."""
    kept = []
    for entry in record["entries"]:
        path = folder / entry["file"]
        if path.is_file() and sha256_file(path) == entry.get("sha256"):
            kept.append(entry)
        else:
            warnings.warn(
                f"{path}: missing or changed since it was captured; capturing {entry['role']} again",
                PicamcalWarning,
                stacklevel=3,
            )
    return kept


def _save_frame(
    folder: Path, role: str, raw: RawImage, light: tuple[int, int, int], record: Mapping[str, Any]
) -> dict[str, Any]:
    """Write ``ROLE.dng`` and its ``ROLE.json`` sidecar (each atomically); return the manifest entry."""
    raw.metadata["role"] = role
    path = write_dng(folder / f"{role}.dng", raw)
    sidecar_name = f"{role}.json"
    entry = {
        "role": role,
        "file": path.name,
        "sidecar": sidecar_name,
        "sha256": sha256_file(path),
        "time": _now(),
        "light": list(light),
        "extra": role not in REFERENCE_LIGHTS and colour_name(role) is None,
    }
    sidecar = {
        "format": FRAME_FORMAT,
        "version": MANIFEST_VERSION,
        **entry,
        "settings": record["settings"],
        "camera": record["camera"],
        "illuminator": record["illuminator"],
        "metadata": {k: v for k, v in raw.metadata.items() if k != "path"},
    }
    _write_json(folder / sidecar_name, sidecar)
    return entry


def _new_record(
    camera: Camera,
    illuminator: Illuminator,
    found: Mapping[str, Any],
    plan: list[str],
    colours: Mapping[str, tuple[int, int, int]],
    settle_s: float,
) -> dict[str, Any]:
    """The manifest of a new run, its settings frozen by :func:`auto_expose`, nothing captured yet."""
    return {
        "format": MANIFEST_FORMAT,
        "version": MANIFEST_VERSION,
        "software_version": __version__,
        "created": _now(),
        "updated": _now(),
        "camera": camera.describe(),
        "illuminator": illuminator.describe(),
        "settings": {k: found[k] for k in ("exposure_time_us", "analogue_gain", "colour_gains")},
        "auto_exposure": {
            k: v for k, v in found.items() if k not in ("exposure_time_us", "analogue_gain", "colour_gains")
        },
        "settle_s": settle_s,
        "roles": plan,
        "colours": {role: list(light) for role, light in colours.items()},
        "entries": [],
        "complete": False,
    }


def _disk_full(exc: BaseException) -> bool:
    """True when the error, or one it was raised from or while handling, is a full disk or quota."""
    cause: BaseException | None = exc
    while cause is not None:
        if isinstance(cause, OSError) and cause.errno in (errno.ENOSPC, errno.EDQUOT):
            return True
        cause = cause.__cause__ or cause.__context__
    return False


def _resume_hint(record: Mapping[str, Any] | None, folder: Path) -> str:
    if record is None:
        return "nothing was captured"
    roles = [e["role"] for e in record["entries"]]
    kept = f"{', '.join(roles)} captured and kept (listed in" if roles else "the frozen settings are kept (in"
    return f"{kept} {folder / MANIFEST_NAME}): run the same command again to resume"


def acquire(
    camera: Camera,
    illuminator: Illuminator,
    out_dir: str | os.PathLike[str],
    *,
    colours: Mapping[str, tuple[int, int, int]] | None = None,
    extras: Iterable[str] = (),
    target_fraction: float = 0.8,
    percentile: float = 99.9,
    settle_s: float = 0.5,
    max_exposure_s: float = 1.0,
    prompt: Callable[[str], Any] = input,
    progress: Callable[[str, int, int], Any] | None = None,
) -> Path:
    """Capture a calibration run: auto-expose on white, freeze, then white, red, green, blue, black, colours, extras.

    The camera is configured (``configure_raw``), the light set to white, and :func:`auto_expose` finds and
    freezes the exposure, gain and colour gains. Then for each illumination (the five references, then each
    extra colour as the reference ``colour_NAME``) the light is set, the
    acquisition waits ``settle_s`` and captures one raw frame, saved as ``ROLE.dng`` and ``ROLE.json``; each
    extra (under white light) is preceded by ``prompt("Put the NAME in front of the camera and press Enter")``.
    ``manifest.json`` (see the module's description) is written once the settings are frozen and after every
    frame, each time atomically.

    A folder with a manifest is a run to resume: its frozen settings are used again (no auto-exposure), the
    frames listed and unchanged are kept, and only the missing ones are captured; the camera (kind, sensor,
    size, and the sensor mode and its crop where the run records them) and the illuminator kind must be those of
    the run, and a colour given again its RGB (the manifest's
    ``colours`` keeps the planned ones, so a re-run needs not repeat them).

    Parameters
    ----------
    camera : Camera
        Opened, not yet configured.
    illuminator : Illuminator
    out_dir : path-like
        The run's folder, created if missing.
    colours : mapping, optional
        Extra colours, name -> (R, G, B) 0-255 (:func:`picamcal.references.parse_colours`): each is captured as the
        reference ``colour_NAME`` (``colour_NAME.dng``) with the illuminator set to that RGB, after the five.
    extras : iterable of str
        Names of extra images (``target``): letters, digits, ``-`` and ``_``; not a reference's name.
    target_fraction, percentile, max_exposure_s
        As :func:`auto_expose`.
    settle_s : float
        Seconds to wait after setting the light, before capturing.
    prompt : callable
        Asks the user before each extra image and waits (``input``).
    progress : callable, optional
        Called ``progress(message, done, total)`` before auto-exposure and after every frame.

    Returns
    -------
    Path
        The manifest.

    Raises
    ------
    AcquisitionError
        The exposure cannot be reached (what to change is in the message), the folder holds another camera's
        run, or raw files without a manifest.
    AcquisitionInterrupted
        Ctrl-C; the message lists what is kept.
    OutputError
        A file cannot be written; a full disk says so.
    PicamcalError
        The camera or the light fails (``CameraError``, ``IlluminatorError``); once the settings are frozen the
        message ends with what was captured and kept, and how to resume.

    Examples
    --------
    >>> camera = SimCamera("imx219", size=(64, 48))
    >>> manifest = acquire(camera, camera.light, "run1", settle_s=0)
    >>> manifest.name, sorted(read_manifest("run1"))
    ('manifest.json', ['black', 'blue', 'green', 'red', 'white'])
    >>> _ = acquire(camera, camera.light, "run2", colours={"cyan": (0, 255, 255)}, settle_s=0)
    >>> record = load_manifest("run2")
    >>> record["roles"][-1], record["entries"][-1]["file"], record["entries"][-1]["light"]
    ('colour_cyan', 'colour_cyan.dng', [0, 255, 255])
    """
    extra_names = _check_extras(extras)
    given = parse_colours(f"{name}={r},{g},{b}" for name, (r, g, b) in (colours or {}).items())
    if settle_s < 0:
        raise AcquisitionError(f"the settling time must be >= 0 s, got {settle_s}")
    folder = Path(out_dir)
    manifest = folder / MANIFEST_NAME
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the folder: {exc.strerror or exc}", folder) from exc
    record = load_manifest(folder) if manifest.exists() else None
    colour_lights = _colour_lights(record, given, folder)
    lights = {**REFERENCE_LIGHTS, **colour_lights}
    plan = [*REFERENCE_LIGHTS, *colour_lights, *extra_names]
    if record is None:
        clash = [
            f"{role}{suffix}"
            for role in plan
            for suffix in (".dng", ".json")
            if (folder / role).with_suffix(suffix).exists()
        ]
        if clash:
            raise AcquisitionError(
                f"holds {', '.join(clash)} but no {MANIFEST_NAME}: use an empty folder for a new run", folder
            )
    else:
        why = _rig_mismatch(record, camera, illuminator)
        if why:
            raise AcquisitionError(f"cannot resume this run: {why}; use another --out for a new run", folder)
        record["entries"] = _kept_entries(record, folder)
        # A re-run captures what was planned before and any new colours and extras.
        plan = [*record["roles"], *(role for role in plan if role not in record["roles"])]
        record["roles"] = plan
        record["colours"] = {role: list(light) for role, light in colour_lights.items()}
    captured = {e["role"] for e in record["entries"]} if record else set()
    todo = [role for role in plan if role not in captured]
    report = progress or (lambda message, done, total: None)

    try:
        camera.configure_raw()
        if record is None:
            report("auto-exposing on white", 0, len(plan))
            illuminator.set_rgb(*REFERENCE_LIGHTS["white"])
            time.sleep(settle_s)
            found = auto_expose(
                camera, target_fraction=target_fraction, percentile=percentile, max_exposure_s=max_exposure_s
            )
            record = _new_record(camera, illuminator, found, plan, colour_lights, settle_s)
            _write_json(manifest, record)
        else:
            report(f"resuming: {len(captured)} of {len(plan)} captured", len(captured), len(plan))
            settings = record["settings"]
            camera.set_controls(
                settings["exposure_time_us"], settings["analogue_gain"], tuple(settings["colour_gains"])
            )
        for role in todo:
            light = lights.get(role, REFERENCE_LIGHTS["white"])
            illuminator.set_rgb(*light)
            if role not in lights:
                prompt(f"Put the {role} in front of the camera and press Enter")
            time.sleep(settle_s)
            entry = _save_frame(folder, role, camera.capture(), light, record)
            entries = [*record["entries"], entry]
            updated = {**record, "updated": _now(), "entries": entries}
            updated["complete"] = {e["role"] for e in entries} >= set(plan)
            _write_json(manifest, updated)
            record = updated  # only what the manifest on disk lists counts as kept
            report(f"captured {role}", len(entries), len(plan))
    except KeyboardInterrupt:
        raise AcquisitionInterrupted(f"interrupted; {_resume_hint(record, folder)}", folder) from None
    except PicamcalError as exc:
        if _disk_full(exc):
            raise OutputError(f"the disk is full: free some space; {_resume_hint(record, folder)}", folder) from exc
        if record is not None:
            hint = _resume_hint(record, folder)
            exc.problem = f"{exc.problem}; {hint}"
            exc.args = (f"{exc.args[0]}; {hint}", *exc.args[1:])
        raise
    return manifest


class _ShownToSim:
    """A screen the simulated camera looks at: each colour is shown on the screen and lights the simulated scene."""

    def __init__(self, screen: Illuminator, light: SimIlluminator) -> None:
        self._screen = screen
        self._light = light

    def set_rgb(self, red: int, green: int, blue: int) -> None:
        self._screen.set_rgb(red, green, blue)
        self._light.set_rgb(red, green, blue)

    def close(self) -> None:
        try:
            self._screen.close()
        finally:
            self._light.close()

    def describe(self) -> dict[str, Any]:
        return {**self._screen.describe(), "seen_by": "sim"}


@dataclass
class Rig:
    """A camera and an illuminator opened together, and who answers the prompts; closes both.

    Attributes
    ----------
    camera : Camera
    illuminator : Illuminator
    prompt : callable
        What :func:`acquire` should ask before each extra image: the user's ``input``, or for the simulator a
        simulated user who puts the colour-wheel target in front of the camera.
    """

    camera: Camera
    illuminator: Illuminator
    prompt: Callable[[str], Any]

    def close(self) -> None:
        """Turn the light off and release it, then the camera (both, even if the first fails)."""
        try:
            self.illuminator.close()
        finally:
            self.camera.close()

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None, traceback: Any) -> None:
        try:
            self.close()
        except PicamcalError:
            if kind is None:  # a failing close must not hide the error that ended the run
                raise


def open_rig(
    camera: str,
    illuminator: str,
    *,
    sensor: str = "imx219",
    size: tuple[int, int] | None = None,
    seed: int = 0,
    sensor_mode: str | None = None,
    colours: Mapping[str, tuple[int, int, int]] | None = None,
    prompt: Callable[[str], Any] = input,
) -> Rig:
    """Open the camera and illuminator named on the command line (``sim`` goes with ``sim`` or a screen only).

    The simulated camera with the ``screen`` illuminator sees what the screen shows: each colour goes to the
    screen (a window, or a prompt) and lights the simulated scene, so the screen illuminator runs end to end
    without a Pi.

    Parameters
    ----------
    camera : str
        ``picamera2[:N]`` or ``sim`` (:func:`~picamcal.acquire.cameras.open_camera`).
    illuminator : str
        ``serial[:PORT]``, ``gpio[:PIN]``, ``screen[:DISPLAY]``, ``screen:prompt``, ``manual`` or ``sim``
        (:func:`~picamcal.acquire.illuminators.open_illuminator`).
    sensor, size, seed
        Of the simulated camera.
    sensor_mode : str, optional
        Of a ``picamera2`` camera: its sensor mode ``WIDTHxHEIGHT[:BITS]`` (default the full-resolution one;
        :class:`~picamcal.acquire.cameras.Picamera2Camera`).
    colours : mapping, optional
        The run's extra colours, name -> (R, G, B), for the screen's prompts.
    prompt : callable
        Asks the user before each extra image (real cameras), and before each colour for the ``manual`` and the
        prompting ``screen`` illuminators.

    Raises
    ------
    PicamcalError
        ``sim`` mixed with real hardware, or a device that cannot be opened (the other is closed again).

    Examples
    --------
    >>> with open_rig("sim", "sim", size=(64, 48)) as rig:
    ...     rig.camera.describe()["kind"], rig.illuminator.describe()["kind"]
    ('sim', 'sim')
    >>> with open_rig("sim", "screen:prompt", size=(64, 48), prompt=lambda text: print(text) or "") as rig:
    ...     rig.illuminator.set_rgb(255, 0, 0)
    ...     rig.camera.light.rgb
    Show screen_red.png full-screen, then press Enter
    (255, 0, 0)
    You can close the full-screen image now.
    """
    sim_camera, sim_light = camera.strip().lower() == "sim", illuminator.strip().lower() == "sim"
    screen = illuminator.strip().lower().partition(":")[0] == "screen"
    if sim_camera != sim_light and not (sim_camera and screen):
        raise PicamcalError(
            "the sim camera sees only the sim illuminator or a screen: use --camera sim with --illuminator sim "
            "or screen"
            if sim_camera
            else "the sim illuminator lights only the sim camera: use --camera sim with --illuminator sim"
        )
    if sim_camera:
        simulated = cast(SimCamera, open_camera(camera, sensor=sensor, size=size, seed=seed, sensor_mode=sensor_mode))

        def place_target(message: str) -> str:
            simulated.place(wheel_scene(wheel_layout(*simulated.describe()["size"])))
            return ""

        if screen:
            shown = _ShownToSim(open_illuminator(illuminator, colours=colours, input_fn=prompt), simulated.light)
            return Rig(simulated, shown, place_target)
        return Rig(simulated, simulated.light, place_target)
    opened = open_camera(camera, sensor_mode=sensor_mode)
    try:
        return Rig(opened, open_illuminator(illuminator, colours=colours, input_fn=prompt), prompt)
    except BaseException:
        opened.close()
        raise
