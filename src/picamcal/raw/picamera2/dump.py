"""picamera2 raw buffers dumped to files: the buffer as ``.npy`` and what picamera2 reported as a JSON sidecar."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..._atomic import atomic_path
from ..._json import MAX_JSON_BYTES
from ...errors import OutputError, RawFormatError, short
from ...limits import check_size, require_regular_file
from ..model import RawImage
from ..npy import load_npy, read_npy_file_header
from .buffer import buffer_array, check_layout, read_stream
from .convert import from_picamera2, to_picamera2
from .formats import max_stride
from .metadata import resolve_sensor

#: The sidecar's ``format`` and ``version``.
SIDECAR_FORMAT = "picamcal-picamera2"
SIDECAR_VERSION = 1


def write_raw_as_picamera2_npy(path: str | os.PathLike[str], raw: RawImage, overwrite: bool = True) -> Path:
    """Write ``raw`` as picamera2 would capture it (packed buffer), as ``.npy`` with its JSON sidecar.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> write_raw_as_picamera2_npy("white.npy", white)
    PosixPath('white.npy')
    >>> bool(np.array_equal(read_picamera2_npy("white.npy").bayer, white.bayer))
    True
    """
    array, config, metadata = to_picamera2(raw)
    return write_picamera2_npy(path, array, config, metadata, sensor=raw.sensor, overwrite=overwrite)


def write_picamera2_npy(
    path: str | os.PathLike[str],
    array: np.ndarray,
    config: Mapping[str, Any],
    metadata: Mapping[str, Any] | None = None,
    *,
    sensor: str | None = None,
    overwrite: bool = True,
) -> Path:
    """Dump a picamera2 raw buffer as captured to ``.npy`` with a JSON sidecar, both written atomically.

    The buffer goes to ``path`` (``np.save``; ``.npy`` is appended to a name without it), the rest to
    ``path.with_suffix(".json")``::

        {"format": "picamcal-picamera2", "version": 1,
         "config": {...},    # the configuration as given (tuples become lists, other objects strings)
         "metadata": {...},  # the request metadata, likewise
         "sensor": "imx708"} # the sensor name (from ``sensor`` or config["model"]) or null

    The configuration is checked against the buffer first, so that only readable dumps are written.

    Parameters
    ----------
    path : path-like
        The ``.npy`` file to write; the sidecar goes beside it.
    array, config, metadata, sensor
        As for :func:`from_picamera2`: the buffer as captured and what picamera2 reports about it.
    overwrite : bool
        Replace existing files (default); if false, an existing ``.npy`` or sidecar is an error.

    Returns
    -------
    Path
        The ``.npy`` file written.

    Raises
    ------
    RawFormatError
        The buffer does not fit its configuration (see :func:`from_picamera2`).
    OutputError
        A file exists already and ``overwrite`` is false, or the folder is not writable.

    Examples
    --------
    On the Pi: ``write_picamera2_npy("white.npy", picam2.capture_array("raw"), picam2.camera_configuration())``.
    Here, a buffer of 2 rows of 4 RAW10 pixels, padded to 32 bytes:

    >>> config = {"format": "SBGGR10_CSI2P", "size": (4, 2), "stride": 32}
    >>> write_picamera2_npy("frame", np.zeros((2, 32), np.uint8), config, {"ExposureTime": 20000}, sensor="imx219")
    PosixPath('frame.npy')
    >>> sorted(path.name for path in Path().iterdir())
    ['frame.json', 'frame.npy']
    """
    path = Path(path)
    if path.suffix != ".npy":
        path = path.with_name(path.name + ".npy")
    sidecar = path.with_suffix(".json")
    if metadata is not None and not isinstance(metadata, Mapping):
        raise RawFormatError(f"request metadata must be a dict, not {type(metadata).__name__}", path)
    check_layout(array, config, str(path))
    name, _ = resolve_sensor(sensor, config, metadata or {}, str(path), warn=False)
    record = {
        "format": SIDECAR_FORMAT,
        "version": SIDECAR_VERSION,
        "config": _jsonable(config),
        "metadata": _jsonable(metadata or {}),
        "sensor": name or sensor,
    }
    text = json.dumps(record, indent=1)
    if not overwrite:
        for target in (path, sidecar):
            if target.exists():
                raise OutputError("exists already (use --overwrite to replace it)", target)
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        np.save(f, buffer_array(array))
    with atomic_path(sidecar, overwrite=overwrite) as tmp:
        tmp.write_text(text + "\n", encoding="utf-8")
    return path


def read_picamera2_npy(path: str | os.PathLike[str], *, expected_shape: tuple[int, int] | None = None) -> RawImage:
    """Read a raw buffer dumped by :func:`write_picamera2_npy` (the ``.npy`` and its ``.json`` sidecar).

    Nothing is allocated before the sizes are checked: the ``.npy`` header's against the file's size, the frame size
    the sidecar declares against :func:`picamcal.limits.check_size` (and ``expected_shape``), and the buffer's
    bytes against what that frame can take (:func:`max_stride` per row). No pickles are loaded.

    Parameters
    ----------
    path : path-like
        The ``.npy`` file.
    expected_shape : (height, width), optional
        The Bayer size the caller needs (a calibration's): another size raises ``CalibrationFileError`` before the
        buffer is read.

    Returns
    -------
    RawImage
        As :func:`from_picamera2` makes it, with ``metadata["format"]`` ``"picamera2-npy"`` and ``path`` the file.

    Raises
    ------
    RawFormatError
        One line naming the file: missing or corrupt ``.npy``, missing or corrupt sidecar, a declared size over
        the pixel limit, or a buffer that does not fit its configuration.
    CalibrationFileError
        The sidecar's frame size is not ``expected_shape``.

    Examples
    --------
    >>> config = {"format": "SBGGR10_CSI2P", "size": (4, 2), "stride": 32}
    >>> _ = write_picamera2_npy("frame.npy", np.zeros((2, 32), np.uint8), config, sensor="imx219")
    >>> raw = read_picamera2_npy("frame.npy")
    >>> raw.metadata["format"], raw.pattern, raw.sensor, raw.black_level
    ('picamera2-npy', 'BGGR', 'imx219', (64.0, 64.0, 64.0, 64.0))
    """
    path = Path(path)
    header = read_npy_file_header(path)
    dtype, shape = header.dtype, header.shape
    if dtype.kind != "u" or dtype.itemsize not in (1, 2) or len(shape) not in (1, 2) or min(shape) < 1:
        raise RawFormatError(f"a {dtype} array of shape {shape}, not a raw buffer (2-D uint8)", path)
    header.require_data(path)
    record = _load_sidecar(path)
    spec, width, height, _, _ = read_stream(record["config"], str(path))
    check_size(path, width, height, expected_shape)
    most = height * max_stride(spec.row_bytes(width))
    if header.nbytes > most:
        raise RawFormatError(
            f"a buffer of {header.nbytes} bytes is larger than a {width}x{height} {spec.name} frame can be "
            f"(at most {most} bytes)",
            path,
        )
    array = load_npy(path, header)
    raw = from_picamera2(array, record["config"], record["metadata"], sensor=record["sensor"], source=path)
    raw.metadata["format"] = "picamera2-npy"
    return raw


def _jsonable(value: Any) -> Any:
    """A JSON-ready copy: mappings to dicts with string keys, sequences and arrays to lists, objects to strings."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def _load_sidecar(path: Path) -> dict[str, Any]:
    """The sidecar of the dump ``path``: its configuration, request metadata and sensor, each checked for type."""
    sidecar = path.with_suffix(".json")
    what = f"sidecar of {path.name}"
    try:
        if require_regular_file(sidecar) > MAX_JSON_BYTES:
            raise RawFormatError(f"{what} is larger than {MAX_JSON_BYTES >> 20} MB", sidecar)
        record = json.loads(sidecar.read_text(encoding="utf-8"))
    except RawFormatError:
        if not sidecar.exists():
            raise RawFormatError(
                f"no JSON sidecar {sidecar.name} beside it (written by write_picamera2_npy)", path
            ) from None
        raise
    except (OSError, ValueError, RecursionError) as exc:
        raise RawFormatError(f"corrupt {what} ({type(exc).__name__}: {short(str(exc))})", sidecar) from exc
    if not isinstance(record, dict) or record.get("format") != SIDECAR_FORMAT:
        raise RawFormatError(f'not a picamcal {what} (no "format": "{SIDECAR_FORMAT}")', sidecar)
    if record.get("version") != SIDECAR_VERSION:
        raise RawFormatError(f"unsupported {what} version {short(record.get('version'))}", sidecar)
    if not isinstance(record.get("config"), dict) or not isinstance(record.get("metadata", {}), dict):
        raise RawFormatError(f"corrupt {what}: 'config' and 'metadata' must be objects", sidecar)
    if not isinstance(record.get("sensor"), (str, type(None))):
        raise RawFormatError(f"corrupt {what}: 'sensor' must be a name or null", sidecar)
    return {"config": record["config"], "metadata": record.get("metadata") or {}, "sensor": record.get("sensor")}
