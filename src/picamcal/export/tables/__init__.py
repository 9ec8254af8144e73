"""The lens shading calibrations users already have, read as the flat field they describe.

One module per kind of file, each the only one that knows its layout:

- :mod:`~picamcal.export.tables.npy`: a legacy firmware table saved with ``numpy.save`` (``picamcal export-lst``);
- :mod:`~picamcal.export.tables.openflexure`: the OpenFlexure Microscope's ``microscope_settings.npz`` and its
  ``lens_shading_table``;
- :mod:`~picamcal.export.tables.c_header`: a legacy table as a C header (``ls_table.h``, ArduCAM's
  ``ls_table_1160x800.h``);
- :mod:`~picamcal.export.tables.tuning_file`: a libcamera tuning file's ``rpi.alsc``.

:func:`read_shading_table` tells them apart by their content (and a C header by its name); :func:`load_flat_field`
gives any of them, or a picamcal calibration, as a :class:`~picamcal.calibration.Calibration`
(:func:`~picamcal.export.tables.flat_field.table_calibration`), which every command that takes a calibration uses.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ...calibration import Calibration
from ...limits import require_regular_file
from ..legacy import UNITY
from .c_header import MAX_HEADER_BYTES, is_header_file, read_header_table
from .flat_field import legacy_sensors, table_calibration, table_gains, table_sensor
from .model import FORMATS, ShadingTable, TableFileError
from .npy import NPY_MAGIC, read_npy_table
from .openflexure import is_openflexure_npz, npz_keys, read_openflexure_table
from .tuning_file import read_tuning_table

__all__ = [
    "ShadingTable",
    "TableFileError",
    "describe_table",
    "inspect_table",
    "is_shading_table",
    "load_flat_field",
    "read_shading_table",
    "refuse_table",
    "table_calibration",
    "table_gains",
    "table_sensor",
]

_ZIP = b"PK\x03\x04"


def _known_shapes() -> list[tuple[int, int]]:
    """(rows, columns) of the legacy tables of the registry's colour sensors, the legacy firmware's first."""
    from ...sensors import SENSORS
    from ..legacy import table_shape

    shapes: list[tuple[int, int]] = []
    for entry in sorted(SENSORS.values(), key=lambda s: not s.legacy_modes):
        _, rows, cols = table_shape(entry.width, entry.height)
        if not entry.monochrome and (rows, cols) not in shapes:
            shapes.append((rows, cols))
    return shapes


def read_shading_table(path: str | os.PathLike[str]) -> ShadingTable:
    """Read a lens shading table a user has: a legacy ``.npy``, an OpenFlexure ``.npz``, a C header or a libcamera
    tuning file, told apart by content (a C header by its suffix,
    :data:`~picamcal.export.tables.c_header.HEADER_SUFFIXES`).

    Raises
    ------
    TableFileError
        Not one of these, or one that is broken (each reader's checks); one line naming the file and what was
        expected. A picamcal calibration is none of these: :func:`load_flat_field` takes both.

    Examples
    --------
    >>> np.savez("microscope_settings.npz", lens_shading_table=np.full((4, 39, 52), 40, np.uint8))
    >>> table = read_shading_table("microscope_settings.npz")
    >>> table.kind, table.legacy.shape, table.format
    ('openflexure', (4, 39, 52), 'OpenFlexure lens shading table (microscope_settings.npz)')
    """
    path = Path(path)
    if not os.path.lexists(path):
        raise TableFileError("no such file", path)
    require_regular_file(path, TableFileError)
    with open(path, "rb") as f:
        head = f.read(8)
    if head.startswith(NPY_MAGIC):
        return ShadingTable("npy", path, legacy=read_npy_table(path))
    if head.startswith(_ZIP):
        # OpenFlexure's server truncates its gains (``gains.astype(np.uint8)``), as 6by9's tool divides integers.
        return ShadingTable("openflexure", path, legacy=read_openflexure_table(path), rounding="floor")
    if is_header_file(path):
        table, said = read_header_table(path, _known_shapes())
        return ShadingTable("c-header", path, legacy=table, details=said, rounding="floor")
    if head.lstrip()[:1] in (b"{", b"#") or path.suffix.lower() in (".json", ".yaml", ".yml"):
        tuning, sensor, said = read_tuning_table(path)
        return ShadingTable("tuning", path, tuning=tuning, sensor=sensor, details=said)
    raise TableFileError(
        "not a lens shading calibration: expected a picamcal calibration (.npz), a legacy table (.npy, an "
        "OpenFlexure microscope_settings.npz, a C header) or a libcamera tuning file (.json)",
        path,
    )


def is_shading_table(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is a lens shading table :func:`read_shading_table` reads.

    Examples
    --------
    >>> np.save("lst.npy", np.full((4, 39, 52), 40, np.uint8))
    >>> is_shading_table("lst.npy"), is_shading_table("missing.npy")
    (True, False)
    """
    try:
        read_shading_table(path)
    except TableFileError:
        return False
    return True


def looks_like_table(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is, by its first bytes or name, of a kind :func:`read_shading_table` reads, whether or not it
    reads: an ``.npy`` of planes (a 3-dimensional array, the fewest first), an ``.npz`` with a ``lens_shading_table``,
    a C header.

    Examples
    --------
    >>> np.save("lst.npy", np.zeros((4, 39, 52), np.uint8))  # zeros: a table, broken
    >>> looks_like_table("lst.npy"), looks_like_table("missing.npz")
    (True, False)
    """
    path = Path(path)
    if not path.is_file():
        return False
    if is_header_file(path):
        return True
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return False
    if head.startswith(_ZIP):
        return is_openflexure_npz(path)
    if head.startswith(NPY_MAGIC):
        try:
            shape = np.load(path, mmap_mode="r", allow_pickle=False).shape
        except Exception:  # numpy's header parser raises many types: not a table
            return False
        return len(shape) == 3 and shape[0] < min(shape[1:])  # planes first: a table (an image's would be last)
    return False


def load_flat_field(path: str | os.PathLike[str], sensor: str | None = None) -> Calibration:
    """A picamcal calibration, or the flat field any lens shading table describes as a ``flat`` calibration.

    What ``export-tuning``, ``export-lst``, ``correct`` and ``apply-tuning`` take as a calibration: a picamcal
    ``.npz`` as :func:`picamcal.load_calibration` reads it; else a table (:func:`read_shading_table`) as
    :func:`~picamcal.export.tables.flat_field.table_calibration` makes it, for ``sensor`` where the file does not say.

    Raises
    ------
    CalibrationFileError
        A calibration that does not load; TableFileError (one) for a table that does not, or one naming neither.

    Examples
    --------
    >>> np.savez("microscope_settings.npz", lens_shading_table=np.full((4, 39, 52), 40, np.uint8), iso=np.array(100))
    >>> flat = load_flat_field("microscope_settings.npz", sensor="imx219")
    >>> flat.kind, flat.sensor, flat.path.name
    ('flat', 'imx219', 'microscope_settings.npz')
    """
    from ...calibration import load_calibration
    from ...errors import CalibrationFileError

    path = Path(path)
    if looks_like_table(path) or _looks_like_tuning(path):
        return table_calibration(read_shading_table(path), sensor)
    try:
        return load_calibration(path)
    except CalibrationFileError as exc:
        keys = npz_keys(path) if type(exc) is CalibrationFileError and path.is_file() else None
        if keys is not None and "metadata" not in keys:
            shown = ", ".join(keys[:6]) + (" ..." if len(keys) > 6 else "") if keys else "nothing"
            raise TableFileError(
                f"an .npz that is neither a calibration nor a lens shading table (it holds {shown}): expected a "
                "picamcal calibration or an OpenFlexure microscope_settings.npz with its lens_shading_table",
                path,
            ) from None
        raise


def _looks_like_tuning(path: Path) -> bool:
    """A JSON or YAML file by its name or first character: a tuning file, or a broken one."""
    if path.suffix.lower() in (".json", ".yaml", ".yml"):
        return True
    if not path.is_file():  # a FIFO would block the read; what is not a regular file is refused as a calibration
        return False
    try:
        with open(path, "rb") as f:
            return f.read(64).lstrip()[:1] == b"{"
    except OSError:
        return False


def describe_table(table: ShadingTable) -> dict[str, Any]:
    """What ``picamcal inspect`` says of a table: its format, grid, sensor and mode where known, gains and unity.

    Examples
    --------
    >>> np.save("lst.npy", np.full((4, 39, 52), 40, np.uint8))
    >>> record = describe_table(read_shading_table("lst.npy"))
    >>> record["grid"], record["sensor"], record["gains"], record["unity"]
    ('52 x 39 cells of 64 px, planes R, Gr, Gb, B', 'imx219', [1.25, 1.25], '32 in u3.5')
    """
    record: dict[str, Any] = {"format": table.format, "kind": table.kind}
    if table.legacy is not None:
        _, rows, cols = table.legacy.shape
        candidates = legacy_sensors(table.legacy.shape)
        record.update(
            grid=f"{cols} x {rows} cells of 64 px, planes R, Gr, Gb, B",
            sensor=table.sensor or (candidates[0] if len(candidates) == 1 else None),
            sensor_candidates=candidates,
            gains=[round(int(table.legacy.min()) / UNITY, 4), round(int(table.legacy.max()) / UNITY, 4)],
            unity=f"{UNITY} in u3.5",
            sensor_mode="the full sensor (legacy tables cover it whatever the mode)",
        )
        if "ref_transform" in table.details:
            record["ref_transform"] = table.details["ref_transform"]
        return record
    from ...sensors import LSC_GRIDS

    details = dict(table.details)
    cols, rows = LSC_GRIDS[details["target"]]
    record.update(
        grid=f"{cols} x {rows} ({'Pi 5' if details['target'] == 'pisp' else 'Pi 4 and earlier'}, {details['target']})",
        sensor=table.sensor,
        unity="1.0",
        sensor_mode="the full sensor (libcamera resamples the table to each mode)",
        colour_temperatures=details["cts"],
        ct=details["ct"],
        adaptive=bool(details.get("n_iter")),
    )
    if table.sensor is not None:
        try:
            gains = table_gains(table, table_sensor(table), bin_size=64)
        except TableFileError:
            gains = None
        if gains is not None:
            record["gains"] = [round(float(gains.min()), 4), round(float(gains.max()), 4)]
    return record


def inspect_table(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """What ``picamcal inspect`` lists for a lens shading table: None for a file that is no table (a tuning file
    without ``rpi.alsc`` is none); else the record of :func:`describe_table` with ``"format"`` a line saying it all
    and ``"readable"`` True, or, for one that looks like a table but does not read, ``"readable"`` False and the
    ``"error"``.

    Examples
    --------
    >>> np.savez("microscope_settings.npz", lens_shading_table=np.full((4, 39, 52), 40, np.uint8))
    >>> inspect_table("microscope_settings.npz")["format"]
    'OpenFlexure lens shading table (microscope_settings.npz): 52 x 39 cells of 64 px, planes R, Gr, Gb, B; imx219; \
gains 1.25 to 1.25 (unity: 32 in u3.5)'
    >>> np.save("broken.npy", np.zeros((4, 39, 52), np.uint8))
    >>> inspect_table("broken.npy")["error"]
    'the table holds 8112 zeros (gain 0; 32 is 1.0): not a lens shading table'
    """
    path = Path(path)
    if not (looks_like_table(path) or _has_alsc(path)):
        return None
    if is_header_file(path) and not _has_braces(path):  # C source of something else, in a folder listed
        return None
    try:
        record = describe_table(read_shading_table(path))
    except TableFileError as exc:
        return {"format": "-", "readable": False, "error": exc.problem}
    gains = record.get("gains")
    about = [record["grid"], record.get("sensor") or _unsaid(record)]
    if gains:
        about.append(f"gains {gains[0]:.2f} to {gains[1]:.2f} (unity: {record['unity']})")
    cts = record.get("colour_temperatures")
    if cts and len(cts) > 1:
        about.append(f"tables at {', '.join(map(str, cts))} K, taken at {record['ct']:g} K")
    if record.get("adaptive"):
        about.append("adaptive (n_iter > 0): its tables are the start")
    return {**record, "format": f"{record['format']}: {'; '.join(about)}", "readable": True}


def _has_braces(path: Path) -> bool:
    """Whether a C source holds a brace initialiser's ``= {`` at all (a table's header does)."""
    try:
        with open(path, "rb") as f:
            return re.search(rb"=\s*\{", f.read(MAX_HEADER_BYTES)) is not None
    except OSError:
        return False


def _unsaid(record: dict[str, Any]) -> str:
    """What stands for the sensor of a table that does not say it."""
    if record["kind"] == "tuning":
        return "sensor not said (give --sensor)"
    candidates = record["sensor_candidates"]
    if not candidates:
        return "a size no sensor picamcal knows has"
    return f"sensor not said ({' or '.join(candidates)}: give --sensor)"


def _has_alsc(path: Path) -> bool:
    """A JSON or YAML file that names libcamera's ``rpi.alsc``: a tuning file with a lens shading table, or a broken
    one (read as such, it says why)."""
    if not _looks_like_tuning(path):
        return False
    try:
        with open(path, "rb") as f:
            return b"rpi.alsc" in f.read(16 << 20)
    except OSError:
        return False


def refuse_table(path: str | os.PathLike[str], needs: str) -> None:
    """Raise TableFileError if ``path`` is a lens shading table, where a command ``needs`` a picamcal calibration:
    the message says what the file is and what takes it (``export-tuning``).

    Examples
    --------
    >>> np.save("lst.npy", np.full((4, 39, 52), 40, np.uint8))
    >>> refuse_table("lst.npy", "the report")
    Traceback (most recent call last):
    ...
    picamcal.export.tables.model.TableFileError: lst.npy: this is a legacy lens shading table (.npy, picamcal \
export-lst), not a calibration: the report needs one from the reference images (picamcal calibrate); the table's \
flat field goes into the camera with picamcal export-tuning lst.npy
    """
    path = Path(path)
    if not (looks_like_table(path) or _has_alsc(path)):
        return
    kind = FORMATS["tuning"] if _has_alsc(path) else _table_format(path)
    article = "an" if kind[0] in "aeiouAEIOU" else "a"
    raise TableFileError(
        f"this is {article} {kind}, not a calibration: {needs} needs one from the reference images (picamcal "
        f"calibrate); the table's flat field goes into the camera with picamcal export-tuning {path.name}",
        path,
    )


def _table_format(path: Path) -> str:
    if is_header_file(path):
        return FORMATS["c-header"]
    return FORMATS["openflexure"] if _is_zip(path) else FORMATS["npy"]


def _is_zip(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(4) == _ZIP
    except OSError:
        return False
