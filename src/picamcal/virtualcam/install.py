"""Putting the virtual camera in place: in this Python process (:func:`install`), or for a command
(:func:`run_with_virtual_camera`, the ``picamcal virtual-camera`` command).

The virtual camera is a ``libcamera`` package in a directory of picamcal (``picamcal/virtualcam/shim``) that is on
no import path by default. It is put first on the path (``sys.path``, and ``PYTHONPATH`` for child processes)
only when asked, with the settings in environment variables (:mod:`picamcal.virtualcam.options`); nothing is
installed into site-packages, so a real libcamera (a Raspberry Pi's, often visible to a virtual environment) is
never shadowed unless asked: where one is importable, or a Raspberry Pi camera's video device exists, both refuse
unless forced.

Examples
--------
>>> shim_directory().name, (shim_directory() / "libcamera" / "__init__.py").is_file()
('shim', True)
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Mapping, Sequence
from glob import glob
from pathlib import Path
from typing import Any

from .frames import SCENES, Scene
from .ipa import TUNING_VARIABLE, IpaError, load_camera_tuning
from .modes import scaled_spec, sensor_spec
from .options import Options, VirtualCameraError

# What Raspberry Pi camera hardware calls its media and video devices (the unicam, rp1-cfe and ISP drivers).
_PI_CAMERA_DEVICES = ("unicam", "rp1-cfe", "pispbe", "bcm2835-isp")


def shim_directory() -> Path:
    """The directory that holds the virtual camera's ``libcamera`` package.

    Examples
    --------
    >>> (shim_directory() / "libcamera" / "__init__.py").is_file()
    True
    >>> environment(Options(), {})["PYTHONPATH"] == str(shim_directory())  # what a command gets first on its path
    True
    """
    return Path(__file__).resolve().parent / "shim"


def real_camera() -> str | None:
    """What shows a real camera here, or None: a ``libcamera`` module that is not the virtual camera's, or a
    Raspberry Pi camera's media or video device.

    Examples
    --------
    >>> real_camera() is None or "libcamera" in real_camera() or "device" in real_camera()
    True
    """
    if "libcamera" in sys.modules:
        module = sys.modules["libcamera"]
        origin = getattr(getattr(module, "__spec__", None), "origin", None) or getattr(module, "__file__", None)
    else:
        try:
            found = importlib.util.find_spec("libcamera")
        except (ImportError, ValueError):
            found = None
        origin = found.origin if found is not None else None
    if origin and shim_directory() not in Path(origin).resolve().parents:
        return f"a real libcamera is importable ({origin})"
    for path in sorted(glob("/sys/bus/media/devices/*/model") + glob("/sys/class/video4linux/*/name")):
        try:
            text = Path(path).read_text().strip()
        except OSError:
            continue
        if any(name in text for name in _PI_CAMERA_DEVICES):
            return f"this machine has a Raspberry Pi camera device ({text}, {Path(path).parent.name})"
    return None


def check(options: Options, environ: Mapping[str, str] | None = None) -> None:
    """What libcamera would refuse at start-up, as one clear line: an unknown or monochrome sensor, a sensor with no
    stock tuning file for the platform, a ``LIBCAMERA_RPI_TUNING_FILE`` that is unreadable or for the other
    platform, a scene image that cannot be read.

    Raises
    ------
    VirtualCameraError

    Examples
    --------
    >>> check(Options(sensor="imx219"), environ={})
    >>> check(Options(sensor="imx2l9"), environ={})
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: unknown sensor 'imx2l9'; did you mean imx219?
    """
    environ = os.environ if environ is None else environ
    spec = scaled_spec(sensor_spec(options.sensor), options.size)
    try:
        load_camera_tuning(spec, options.platform, environ)
    except IpaError as exc:
        given = environ.get(TUNING_VARIABLE)
        if given:
            raise VirtualCameraError(f"{TUNING_VARIABLE}={given}: {exc.problem}") from None
        raise VirtualCameraError(
            f"the {spec.name} has no stock tuning file for {options.platform}, so libcamera would not register it: "
            f"give one in {TUNING_VARIABLE}"
        ) from None
    if options.scene not in SCENES:
        Scene(options.scene)


def _refuse_real_camera(force: bool, how: str) -> None:
    if force:
        return
    reason = real_camera()
    if reason:
        raise VirtualCameraError(f"{reason}: the virtual camera would hide it; {how} to use the virtual camera anyway")


def install(
    platform: str = "pisp",
    sensor: str = "imx477",
    size: tuple[int, int] | None = None,
    seed: int = 0,
    scene: str = "white",
    brightness: float = 0.25,
    *,
    force: bool = False,
) -> Options:
    """Put the virtual camera in place for this process (and the processes it starts), before picamera2 is imported.

    Parameters
    ----------
    platform : {"pisp", "vc4"}
        A Raspberry Pi 5 or a Raspberry Pi 4.
    sensor : str
        A colour sensor of picamcal's registry.
    size : (int, int), optional
        A smaller simulated pixel array (faster); default the sensor's.
    seed : int
        Seed of the noise.
    scene : str
        ``white``, ``wheel`` or an image file.
    brightness : float
        Exposure fraction of the brightest white pixel at 10 ms and gain 1.
    force : bool
        Install even where a real camera is found (a real libcamera importable, a Raspberry Pi camera device).

    Returns
    -------
    Options
        The settings in force.

    Raises
    ------
    VirtualCameraError
        A real camera is here and ``force`` is not given; libcamera is already imported (install first); or a
        setting libcamera would refuse (:func:`check`).

    Examples
    --------
    In a script, before picamera2 is imported. The example writes the script and runs it in a Python of its own, as
    ``install`` changes its process's import path and environment:

    >>> from pathlib import Path
    >>> _ = Path("camera.py").write_text('''
    ... from picamcal.virtualcam import install
    ...
    ... install(platform="vc4", sensor="imx219", size=(640, 480))
    ... from picamera2 import Picamera2
    ...
    ... with Picamera2() as picam2:
    ...     picam2.start()
    ...     print(picam2.camera_properties["Model"], picam2.camera_configuration()["raw"]["format"])
    ... ''')
    >>> print(subprocess.run([sys.executable, "camera.py"], capture_output=True, text=True).stdout, end="")
    imx219 SBGGR10_CSI2P
    """
    options = Options(platform, sensor, size, seed, scene, brightness)
    check(options)
    module = sys.modules.get("libcamera")
    if module is not None and shim_directory() not in Path(getattr(module, "__file__", "/") or "/").resolve().parents:
        raise VirtualCameraError("libcamera is already imported: install the virtual camera before importing picamera2")
    _refuse_real_camera(force, "install(force=True)")
    os.environ.update(options.environment())
    shim = str(shim_directory())
    if shim not in sys.path:
        sys.path.insert(0, shim)
    paths = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and p != shim]
    os.environ["PYTHONPATH"] = os.pathsep.join([shim, *paths])
    return options


def environment(options: Options, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment a command runs in with the virtual camera: ``base`` (default ``os.environ``), the
    settings, and the shim directory first on ``PYTHONPATH``.

    Examples
    --------
    >>> env = environment(Options(sensor="imx219"), {"PYTHONPATH": "/somewhere"})
    >>> env["PYTHONPATH"] == f"{shim_directory()}{os.pathsep}/somewhere", env["PICAMCAL_VIRTUAL_CAMERA_SENSOR"]
    (True, 'imx219')
    """
    env = dict(os.environ if base is None else base)
    env.update(options.environment())
    shim = str(shim_directory())
    paths = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and p != shim]
    env["PYTHONPATH"] = os.pathsep.join([shim, *paths])
    return env


def run_with_virtual_camera(command: Sequence[str], options: Options, *, force: bool = False) -> int:
    """Run a command with the virtual camera in place; return its exit status (128 + N if killed by signal N).

    The command gets this process's standard input, output and error; Ctrl-C reaches it from the terminal (this
    process waits for it), and a SIGTERM sent here is passed on.

    Raises
    ------
    VirtualCameraError
        No command, a command that is not found, a real camera (unless ``force``), or a setting libcamera would
        refuse (:func:`check`).

    Examples
    --------
    What ``picamcal virtual-camera --sensor imx219 --size 320x240 -- python3 which_camera.py`` does, for a script
    that writes down the camera picamera2 finds:

    >>> _ = Path("which_camera.py").write_text('''
    ... from picamera2 import Picamera2
    ...
    ... with open("camera.txt", "w") as file:
    ...     file.write(Picamera2.global_camera_info()[0]["Model"])
    ... ''')
    >>> run_with_virtual_camera([sys.executable, "which_camera.py"], Options(sensor="imx219", size=(320, 240)))
    0
    >>> Path("camera.txt").read_text()
    'imx219'
    """
    if not command:
        raise VirtualCameraError(
            "give the command to run after --, as in: picamcal virtual-camera -- python3 script.py"
        )
    program = command[0]
    if shutil.which(program) is None:
        raise VirtualCameraError(f"{program}: command not found")
    check(options)
    _refuse_real_camera(force, "give --force")
    streams: dict[str, Any] = {}
    for name, stream in (("stdin", sys.stdin), ("stdout", sys.stdout), ("stderr", sys.stderr)):
        try:
            streams[name] = stream.fileno() if stream is not None else None
        except (AttributeError, OSError, ValueError):
            streams[name] = None
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    try:
        child = subprocess.Popen(list(command), env=environment(options), **streams)
    except OSError as exc:
        raise VirtualCameraError(f"{program}: cannot run it ({exc.strerror or exc})") from None
    previous_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
    previous_term = signal.signal(signal.SIGTERM, lambda signum, frame: child.send_signal(signum))
    try:
        code = child.wait()
    finally:
        signal.signal(signal.SIGINT, previous_int)
        signal.signal(signal.SIGTERM, previous_term)
    return code if code >= 0 else 128 - code


__all__ = [
    "check",
    "environment",
    "install",
    "real_camera",
    "run_with_virtual_camera",
    "shim_directory",
]
