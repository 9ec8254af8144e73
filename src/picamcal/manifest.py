"""The manifest of an acquisition run: what ``picamcal acquire`` captured, with which settings.

:func:`picamcal.acquire.acquisition.acquire` writes ``manifest.json`` into the run's folder once the settings
are frozen and again after every frame; :func:`load_manifest` reads and checks it, and
:func:`picamcal.references.read_manifest` turns it into the reference files ``picamcal calibrate DIR`` uses.
This module holds the file's name, format and checks, so that reading a run needs nothing of the acquisition.

``manifest.json``::

    {"format": "picamcal-acquisition", "version": 1, "software_version": "...", "created": "...",
     "updated": "...",
     "camera": {"kind": "sim", "sensor": "imx219", "size": [320, 240], ...},   # Camera.describe()
     "illuminator": {"kind": "sim"},                                           # Illuminator.describe()
     "settings": {"exposure_time_us": 4082, "analogue_gain": 1.0, "colour_gains": [1.8, 1.3]},
     "auto_exposure": {"target_fraction": 0.8, "percentile": 99.9, "white_fraction": 0.801,
                       "clipped_fraction": 0.0, "iterations": 3},
     "settle_s": 0.5,
     "roles": ["white", "red", "green", "blue", "black", "target"],            # planned, in order
     "entries": [{"role": "white", "file": "white.dng", "sidecar": "white.json", "sha256": "...",
                  "time": "...", "light": [255, 255, 255], "extra": false}, ...],
     "complete": false}

Each frame has a sidecar ``ROLE.json`` (format :data:`FRAME_FORMAT`) holding its entry, the settings, the camera
and illuminator descriptions and the frame's metadata.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ._json import Fields, read_json
from .errors import PicamcalError

__all__ = [
    "FRAME_FORMAT",
    "ILLUMINATOR_LIGHTS",
    "MANIFEST_FORMAT",
    "MANIFEST_NAME",
    "MANIFEST_VERSION",
    "AcquisitionError",
    "load_manifest",
    "manifest_light",
]

#: The manifest's file name in the run's folder.
MANIFEST_NAME = "manifest.json"
#: The ``format`` of a manifest.
MANIFEST_FORMAT = "picamcal-acquisition"
#: The ``format`` of a frame's sidecar ``ROLE.json``.
FRAME_FORMAT = "picamcal-acquisition-frame"
#: The ``version`` of both.
MANIFEST_VERSION = 1
_MAX_MANIFEST_BYTES = 16 << 20
#: The light each kind of illuminator gives (the manifest's ``illuminator.kind`` -> a name of
#: :data:`picamcal.calibration.LIGHTS`): the jig's LEDs, driven over a serial port, from a Pi's pin, simulated or
#: the virtual camera's, or a screen (shown in a window or by the user, seen by a real or a simulated camera). A
#: ``manual`` illuminator is whatever the user set by hand: its light is not known.
ILLUMINATOR_LIGHTS = {"serial": "jig", "gpio": "jig", "sim": "jig", "virtual": "jig", "screen": "screen"}


class AcquisitionError(PicamcalError):
    """The acquisition cannot go on: exposure out of reach, a corrupt manifest, another run in the folder."""


def load_manifest(folder: str | os.PathLike[str]) -> dict[str, Any]:
    """Read and check the ``manifest.json`` of an acquisition folder.

    Every value picamcal uses is checked: the format and version; ``camera`` (``kind``, ``sensor``, a ``size``
    of two positive whole numbers) and ``illuminator`` (``kind``); ``settings`` (a positive exposure time in µs
    and analogue gain, two positive colour gains); ``roles`` (distinct names of letters, digits, ``-`` and ``_``);
    and ``entries`` (one per captured role, each a ``file`` that is a plain name in the folder and, where present,
    a ``sha256``, the ``light`` as three 0..255 levels).

    Raises
    ------
    AcquisitionError
        No manifest, one that is not a regular file, not UTF-8 JSON, or of another format or version, or any value
        of the wrong type, count or range; one line naming the file and the value.

    Examples
    --------
    A run of the simulated camera and light (:func:`picamcal.acquire.acquisition.acquire`):

    >>> from picamcal.acquire.acquisition import acquire
    >>> from picamcal.acquire.cameras import SimCamera
    >>> camera = SimCamera("imx219", size=(64, 48))
    >>> path = acquire(camera, camera.light, "run1", settle_s=0)
    >>> record = load_manifest("run1")
    >>> record["roles"], record["complete"]
    (['white', 'red', 'green', 'blue', 'black'], True)
    >>> sorted(record["settings"])
    ['analogue_gain', 'colour_gains', 'exposure_time_us']
    """
    path = Path(folder) / MANIFEST_NAME
    if not os.path.lexists(path):
        raise AcquisitionError("no acquisition manifest (written by picamcal acquire)", path)
    try:
        record = read_json(path, AcquisitionError, "JSON", max_bytes=_MAX_MANIFEST_BYTES)
    except AcquisitionError as exc:
        raise AcquisitionError(f"corrupt manifest ({exc.problem}); move it away", path) from None
    if not isinstance(record, dict) or record.get("format") != MANIFEST_FORMAT:
        raise AcquisitionError(f'not a picamcal acquisition manifest (no "format": "{MANIFEST_FORMAT}")', path)
    if type(record.get("version")) is not int or record["version"] != MANIFEST_VERSION:
        version = record.get("version")
        shown = repr(version)[:20] if isinstance(version, (int, float, type(None))) else type(version).__name__
        raise AcquisitionError(f"unsupported manifest version {shown}", path)
    _check_manifest(record, path)
    return record


def _check_manifest(record: dict[str, Any], path: Path) -> None:
    """The types, counts and ranges of what acquiring and reading a run use (see :func:`load_manifest`)."""
    fields = Fields(path, AcquisitionError, "a usable acquisition manifest", "move it away and acquire again")
    fields.mapping(record, "the manifest", ("camera", "illuminator", "settings", "roles", "entries"))
    camera = fields.mapping(record["camera"], "camera", ("kind", "size"))
    fields.text(camera["kind"], "camera.kind")
    if camera.get("sensor") is not None:
        fields.text(camera["sensor"], "camera.sensor")
    fields.numbers(camera["size"], "camera.size", 2, integer=True, positive=True)
    fields.text(fields.mapping(record["illuminator"], "illuminator", ("kind",))["kind"], "illuminator.kind")
    settings = fields.mapping(record["settings"], "settings", ("exposure_time_us", "analogue_gain", "colour_gains"))
    fields.number(settings["exposure_time_us"], "settings.exposure_time_us", positive=True)
    fields.number(settings["analogue_gain"], "settings.analogue_gain", positive=True)
    fields.numbers(settings["colour_gains"], "settings.colour_gains", 2, positive=True)
    if "settle_s" in record:
        fields.number(record["settle_s"], "settle_s", minimum=0)
    roles = [fields.text(r, f"roles[{i}]") for i, r in enumerate(fields.items(record["roles"], "roles"))]
    for role in roles:
        if not role or not role.isascii() or not all(c.isalnum() or c in "-_" for c in role):
            fields.fail("roles", f"holds {role[:40]!r}, not a name of letters, digits, '-' and '_'")
    if len(set(roles)) < len(roles):
        fields.fail("roles", "names a role twice")
    seen = set()
    for i, entry in enumerate(fields.items(record["entries"], "entries", maximum=len(roles))):
        where = f"entries[{i}]"
        fields.mapping(entry, where, ("role", "file"))
        role = fields.text(entry["role"], f"{where}.role", roles)
        name = fields.text(entry["file"], f"{where}.file")
        if name in ("", ".", "..") or Path(name).name != name or "\\" in name:
            fields.fail(f"{where}.file", f"must be a file name in the run's folder, not {name[:60]!r}")
        if role in seen:
            fields.fail("entries", f"list {role} twice")
        seen.add(role)
        if entry.get("sha256") is not None:
            fields.text(entry["sha256"], f"{where}.sha256")
        if "light" in entry:
            fields.numbers(entry["light"], f"{where}.light", 3, integer=True, minimum=0, maximum=255)


def manifest_light(record: Mapping[str, Any]) -> str | None:
    """The light of a run's references, from its illuminator (:data:`ILLUMINATOR_LIGHTS`), or None if not known.

    Examples
    --------
    >>> manifest_light({"illuminator": {"kind": "gpio"}}), manifest_light({"illuminator": {"kind": "manual"}})
    ('jig', None)
    """
    return ILLUMINATOR_LIGHTS.get(str((record.get("illuminator") or {}).get("kind")))
