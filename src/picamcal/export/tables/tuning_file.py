"""A libcamera tuning file's lens shading (``rpi.alsc``), read as the flat field it describes.

The file is read and checked as libcamera reads it (:func:`picamcal.export.tuning.load_tuning`); its ``rpi.alsc``
may hold a static table (``n_iter`` 0, as ``picamcal export-tuning`` and OpenFlexure write it) or tables at several
colour temperatures with a luminance table, as Raspberry Pi's stock files do. The sensor is the one the file's
``picamcal`` record names (``export-tuning`` writes it), else the one its name says (``imx219.json``,
``imx219_vc4.json``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..._json import read_libcamera_yaml
from ...errors import PicamcalError
from ...sensors import SENSORS, find_sensor_name
from ..isp import alsc_section, default_ct
from ..tuning_rules import RECORD_KEY, TuningError, check_tuning
from .model import TableFileError


def read_tuning_table(path: str | os.PathLike[str]) -> tuple[dict[str, Any], str | None, dict[str, Any]]:
    """The tuning (with an ``rpi.alsc`` section), the sensor the file names (or None), and what its ``rpi.alsc`` says
    (``target``, ``cts``: the colour temperatures of its tables, ``ct``: the one its static flat field is taken at,
    ``n_iter``, ``luminance_strength``).

    Raises
    ------
    TableFileError
        Not a tuning file libcamera would load (the reason from :func:`~picamcal.export.tuning.load_tuning`), no
        ``rpi.alsc`` section, or an ``rpi.alsc`` with no table picamcal can emulate (``corner_strength`` only).

    Examples
    --------
    >>> from picamcal.export.tuning import stock_tuning_path
    >>> tuning, sensor, said = read_tuning_table(stock_tuning_path("imx219", "bcm2835"))
    >>> sensor, said["target"], said["cts"][:2], said["ct"]
    ('imx219', 'bcm2835', [3000, 3850], 4500.0)
    """
    path = Path(path)
    try:  # as picamcal.export.tuning.load_tuning reads it (which reads tables through this module)
        tuning = read_libcamera_yaml(path, TuningError, "a libcamera tuning file")
        check_tuning(tuning, path)
    except TuningError as exc:
        raise TableFileError(exc.problem, path) from None
    try:
        alsc = alsc_section(tuning)
    except PicamcalError:
        raise TableFileError(
            "a tuning file with no rpi.alsc section: expected one with a lens shading table", path
        ) from None
    if "luminance_lut" not in alsc and "corner_strength" in alsc:
        raise TableFileError(
            "its rpi.alsc has a corner_strength instead of a luminance_lut: picamcal reads tables only", path
        )
    record = tuning.get(RECORD_KEY)
    named = record.get("sensor") if isinstance(record, dict) else None
    sensor = named if isinstance(named, str) and named in SENSORS else find_sensor_name(path.stem)
    cts = sorted({int(entry["ct"]) for key in ("calibrations_Cr", "calibrations_Cb") for entry in alsc.get(key, [])})
    said = {
        "target": tuning["target"],
        "cts": cts,
        "ct": default_ct(tuning),
        "n_iter": alsc.get("n_iter"),
        "luminance_strength": alsc.get("luminance_strength", 1.0),
    }
    return tuning, sensor, said
