"""What an output records of the settings that made it, and how a run compares them with its own.

Every image a batch writes carries, in picamcal's record (:func:`picamcal.output.provenance.read_record`), the
entry ``made_with``: everything of the batch that decides its bytes (the calibration's SHA-256, the mode, binned or
not, the output format and compression, the reading options as given, the sensor crop and mode, for processed
images the encoding and the SHA-256 of the white reference and tuning file, for sRGB outputs of raw images that of
the tuning file giving the colour matrix) and what the file itself decided (``used``: the Bayer order, black level
and white level the raw frame was corrected with). :func:`made_with` makes it, :func:`differences` says, in words,
how an existing output's differs from a run's: a run skips an output made with its own settings (done already) and
keeps one made with others, saying so, unless it overwrites.

What a frame's file decides (a black level it records) is compared where the run gives the setting itself: an
output made from a file's own black level 64 is the same as one made with ``--black-level 64``. Where the run
leaves it to the file and the output was made with a given one, they differ (the run cannot know the file's own
without reading it). An output of picamcal's without the record (an earlier version's) has unknown settings, which
never count as the same.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..records import sha256_file

#: The entry of an output's record (:func:`picamcal.output.provenance.read_record`) that holds :func:`made_with`.
MADE_WITH = "made_with"

#: How each setting is named in a message, in the order messages give them.
SETTING_NAMES = {
    "calibration_sha256": "calibration",
    "mode": "mode",
    "binned": "resolution",
    "processed": "inputs",
    "output_format": "format",
    "compression": "compression",
    "pattern": "Bayer pattern",
    "black_level": "black level",
    "raw_format": "raw format",
    "size": "raw size",
    "stride": "stride",
    "frame": "frame",
    "sensor": "sensor",
    "sensor_crop": "sensor crop",
    "sensor_mode": "sensor mode",
    "input_encoding": "input encoding",
    "white": "white reference",
    "tuning": "tuning file",
}
#: The reading options a raw frame's own file decides when the run does not give them (recorded in ``used``).
_FILE_DECIDES = ("pattern", "black_level")


def file_identity(path: str | os.PathLike[str] | None) -> dict[str, str] | None:
    """A reference file (white, tuning) as a record holds it: its name, for messages, and its SHA-256, which decides.

    Examples
    --------
    >>> _ = Path("tuning.json").write_text("{}")
    >>> file_identity("tuning.json")["name"], file_identity(None)
    ('tuning.json', None)
    """
    if path is None:
        return None
    return {"name": Path(path).name, "sha256": sha256_file(Path(path))}


def batch_settings(
    *,
    calibration: str | os.PathLike[str],
    calibration_sha256: str,
    mode: str,
    binned: bool,
    processed: bool,
    output_format: str,
    compression: str | None,
    read_options: Mapping[str, Any],
    geometry: Mapping[str, Any],
    input_encoding: str | None = None,
    white: Mapping[str, str] | None = None,
    tuning: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """The settings of a batch as its outputs record them (JSON values): :func:`made_with` without the file's part.

    ``white`` and ``tuning`` are :func:`file_identity` values; ``input_encoding`` counts for processed images only
    (an encoding ``tuning:FILE`` recorded by the file's name and content) and the tuning file for processed images
    and sRGB outputs only (elsewhere they change nothing).

    Examples
    --------
    >>> settings = batch_settings(calibration="cal.npz", calibration_sha256="ab12", mode="flat", binned=False,
    ...     processed=False, output_format="uint16-tiff", compression=None, read_options={"black_level": 64},
    ...     geometry={"sensor_crop": None, "sensor_mode": None})
    >>> settings["black_level"], settings["mode"]
    ([64.0, 64.0, 64.0, 64.0], 'flat')
    """
    colour_from_tuning = processed or output_format.startswith("srgb")
    settings: dict[str, Any] = {
        "calibration": Path(calibration).name,
        "calibration_sha256": calibration_sha256,
        "mode": str(mode),
        "binned": bool(binned),
        "processed": bool(processed),
        "output_format": output_format,
        "compression": compression,
        "input_encoding": _encoding(input_encoding) if processed else None,
        "white": dict(white) if white is not None and processed else None,
        "tuning": dict(tuning) if tuning is not None and colour_from_tuning else None,
    }
    for key in ("pattern", "black_level", "raw_format", "size", "stride", "frame", "sensor"):
        settings[key] = None if processed else _json(read_options.get(key))
    if settings["black_level"] is not None:
        settings["black_level"] = _four(settings["black_level"])
    for key in ("sensor_crop", "sensor_mode"):
        settings[key] = _json(geometry.get(key))
    return settings


def made_with(settings: Mapping[str, Any], raw: Any = None) -> dict[str, Any]:
    """The ``made_with`` entry of one output: the batch's settings (:func:`batch_settings`) and, for a raw frame,
    what its file decided (``used``: Bayer order, black level, white level).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> made_with({"mode": "flat"}, white)["used"]
    {'pattern': 'BGGR', 'black_level': [64.0, 64.0, 64.0, 64.0], 'white_level': 1023}
    """
    record = dict(settings)
    if raw is not None and hasattr(raw, "black_level"):
        record["used"] = {
            "pattern": str(raw.pattern),
            "black_level": _four(raw.black_level),
            "white_level": int(raw.white_level),
        }
    return record


def differences(recorded: Mapping[str, Any] | None, current: Mapping[str, Any]) -> list[str]:
    """How an output's recorded ``made_with`` differs from a run's settings (:func:`batch_settings`), in words:
    ``"black level 0, now 64"``; an empty list when it was made with the same ones.

    ``recorded`` None (an output of picamcal's without the record) differs in every way that can be told:
    ``"settings not recorded"``.

    Examples
    --------
    >>> now = {"mode": "centre", "black_level": [64.0] * 4, "pattern": None}
    >>> differences({"mode": "flat", "black_level": None, "used": {"black_level": [0.0] * 4}}, now)
    ['mode flat, now centre', 'black level 0, now 64']
    >>> differences({"mode": "centre", "black_level": None, "used": {"black_level": [64.0] * 4}}, now)
    []
    >>> differences(None, now)
    ['settings not recorded (an earlier picamcal wrote it)']
    """
    if not isinstance(recorded, Mapping):
        return ["settings not recorded (an earlier picamcal wrote it)"]
    used = recorded.get("used")
    if not isinstance(used, Mapping):
        used = {}
    found = []
    for key, name in SETTING_NAMES.items():
        new = current.get(key)
        old = recorded.get(key)
        if key in _FILE_DECIDES and new is not None and old is None and key in used:
            old = used[key]  # the file decided it then: the same if it decided what is given now
        if old == new or (key in ("white", "tuning") and _sha256(old) == _sha256(new) is not None):
            continue  # a reference file counts by its content, whatever its name
        found.append(_difference(key, name, old, new, recorded, current))
    return found


def _difference(
    key: str, name: str, old: Any, new: Any, recorded: Mapping[str, Any], current: Mapping[str, Any]
) -> str:
    if key == "calibration_sha256":
        before, now = recorded.get("calibration"), current.get("calibration")
        return f"calibration {before}, now {'another ' if before == now else ''}{now}"
    if key == "binned":
        return f"{'binned' if old else 'full resolution'}, now {'binned' if new else 'full resolution'}"
    if key == "processed":
        return f"{'processed' if old else 'raw'} images, now {'processed' if new else 'raw'}"
    if key in ("white", "tuning"):
        return f"{name} {_file(old)}, now {'another ' if _file(old) == _file(new) else ''}{_file(new)}"
    given = "the file's own" if key in _FILE_DECIDES else "none"
    return f"{name} {_shown(old, given)}, now {_shown(new, given)}"


def _sha256(identity: Any) -> str | None:
    return identity.get("sha256") if isinstance(identity, Mapping) else None


def _file(identity: Any) -> str:
    return identity.get("name", "?") if isinstance(identity, Mapping) else "none"


def _shown(value: Any, absent: str) -> str:
    """A setting's value as a message shows it: one number for a black level the same at every site."""
    if value is None:
        return absent
    if isinstance(value, list) and value and all(v == value[0] for v in value) and isinstance(value[0], float):
        value = value[0]
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    if isinstance(value, list):
        return ",".join(_shown(v, absent) for v in value)
    return str(value)


def summary(kept: Sequence[tuple[Any, Sequence[str]]], most: int = 3) -> str:
    """The differences of the outputs a run kept, in one parenthesis-ready phrase: the commonest first, at most
    ``most`` of them.

    Examples
    --------
    >>> summary([("a", ["black level 0, now 64"]), ("b", ["black level 0, now 64", "mode flat, now centre"])])
    'black level 0, now 64; mode flat, now centre'
    """
    counts: dict[str, int] = {}
    for _, found in kept:
        for text in found:
            counts[text] = counts.get(text, 0) + 1
    ordered = sorted(counts, key=lambda text: -counts[text])
    more = len(ordered) - most
    return "; ".join(ordered[:most]) + (f"; and {more} more" if more > 0 else "")


def _encoding(encoding: str | None) -> str | None:
    """An input encoding as recorded: ``tuning:FILE`` by the file's name and the start of its SHA-256, so that the
    same file named from another folder is the same encoding."""
    if encoding is None or not encoding.startswith("tuning:"):
        return encoding
    identity = file_identity(encoding.removeprefix("tuning:"))
    assert identity is not None
    return f"tuning:{identity['name']} ({identity['sha256'][:12]})"


def _four(value: Any) -> list[float | None]:
    """A black level, one value or one per Bayer site, as four floats."""
    values = [float(v) for v in (value if isinstance(value, (list, tuple)) else [value])]
    values = values * 4 if len(values) == 1 else values
    return [v if math.isfinite(v) else None for v in values]  # an unknown level: null


def _json(value: Any) -> Any:
    """A setting as JSON gives it back: tuples as lists."""
    if isinstance(value, tuple):
        return [_json(v) for v in value]
    return value


__all__ = ["MADE_WITH", "SETTING_NAMES", "batch_settings", "differences", "file_identity", "made_with", "summary"]
