"""A lens shading table as the flat field it describes: a ``flat`` :class:`~picamcal.calibration.Calibration`.

A table holds gains ``G_c(x)`` that the firmware or libcamera interpolates to each pixel; it corrects a white whose
response is ``W_c(x)`` proportional to ``1 / G_c(x)`` (paper: ``Cb LST = 1 / W``; only the shape of each channel
is kept, as the table normalises each to its smallest gain). So the calibration's per-site white is ``1 / G`` at the
bin centres of the full sensor, ``G`` interpolated as the hardware does: bilinearly between a legacy table's cell
centres (:func:`picamcal.export.legacy.cell_interpolation`), or from a tuning's ``rpi.alsc`` through libcamera's
resampling for the full sensor mode and the ISP's grid (:func:`picamcal.export.isp.lens_shading_gains_at`).
"""

from __future__ import annotations

from datetime import datetime, timezone

import numpy as np

from ..._version import __version__
from ...bayer import bin_centres, centre_region, sites_to_channels
from ...calibration import Calibration
from ...errors import CalibrationInputError
from ...geometry import SensorMode
from ...raw.model import site_channels
from ...records import sha256_file
from ...sensors import SENSORS, Sensor, given_sensor, or_list
from ..isp import lens_shading_gains_at
from ..legacy import cell_interpolation, legacy_gains, plane_sites, table_shape
from ..tuning_fit import IMPORTED_KEY
from .model import ShadingTable, TableFileError

#: Bin edge (sensor pixels) of a calibration made from a table: the paper's, as ``picamcal calibrate`` uses.
BIN_SIZE = 16
#: The white's level in the calibration, as a fraction of the sensor's range above black at its brightest bin
#: (its scale is arbitrary: the correction and the exports use the white's shape alone).
WHITE_FRACTION = 0.5


def legacy_sensors(shape: tuple[int, ...]) -> list[str]:
    """The colour sensors of the registry whose legacy table has this shape, those the legacy firmware drives first.

    Examples
    --------
    >>> legacy_sensors((4, 39, 52)), legacy_sensors((4, 48, 64))[:1]
    (['imx219'], ['imx477'])
    """
    matching = [s for s in SENSORS.values() if not s.monochrome and table_shape(s.width, s.height) == tuple(shape)]
    firmware = [s.name for s in matching if s.legacy_modes]
    return firmware or [s.name for s in matching]


def table_sensor(table: ShadingTable, sensor: str | None = None) -> Sensor:
    """The sensor a table is for: ``sensor`` (``--sensor``), which must agree with what the file says; else what the
    file says; else, for a legacy table, the one sensor whose table has its shape.

    Raises
    ------
    TableFileError
        Nothing says the sensor (the message names ``--sensor`` and the candidates), ``sensor`` disagrees with the
        file or with the table's shape, or the sensor is monochrome (no colour flat field to describe).

    Examples
    --------
    >>> from pathlib import Path
    >>> table = ShadingTable("npy", Path("lst.npy"), legacy=np.full((4, 39, 52), 32, np.uint8))
    >>> table_sensor(table).name
    'imx219'
    """
    named = given_sensor(sensor) if sensor is not None else None
    if named and table.sensor and named != table.sensor:
        raise TableFileError(f"the file is for the {table.sensor}, not the {named} --sensor names", table.path)
    chosen = named or table.sensor
    if chosen is not None and chosen not in SENSORS:
        raise TableFileError(
            f"picamcal knows nothing of the {chosen} (its size, Bayer order, black level), so cannot place the table "
            f"on it: name one picamcal knows with --sensor ({', '.join(list(SENSORS)[:4])}, ...)",
            table.path,
        )
    if table.legacy is not None:
        shape = table.legacy.shape
        candidates = legacy_sensors(shape)
        if not candidates:
            raise TableFileError(
                f"a table of shape {shape} fits no sensor picamcal knows: expected the table of a whole sensor of "
                "W x H pixels, (4, H // 64 + 1, W // 64 + 1), such as (4, 39, 52) for the IMX219",
                table.path,
            )
        if chosen is None:
            if len(candidates) != 1:
                raise TableFileError(
                    f"a legacy table of shape {shape} does not say its sensor: name it with --sensor "
                    f"({or_list(candidates)})",
                    table.path,
                )
            chosen = candidates[0]
        entry = SENSORS[chosen]
        expected = table_shape(entry.width, entry.height)
        if expected != shape:
            fits = f" (it fits the {or_list(candidates)})"
            raise TableFileError(
                f"a table of shape {shape} is not the {chosen}'s: its {entry.width}x{entry.height} sensor has tables "
                f"of shape {expected}{fits}",
                table.path,
            )
    elif chosen is None:
        raise TableFileError(
            "the tuning file does not say its sensor (its name is no sensor's): name it with --sensor", table.path
        )
    entry = SENSORS[chosen]
    if entry.monochrome or entry.default_pattern is None:
        raise TableFileError(f"the {chosen} is monochrome: picamcal calibrates colour sensors only", table.path)
    return entry


def table_gains(table: ShadingTable, sensor: Sensor, bin_size: int = BIN_SIZE) -> np.ndarray:
    """The gains (nby, nbx, 4) a table applies at each Bayer site's bin centres of the full sensor, sites row-major
    in the sensor's 2 x 2 block.

    Examples
    --------
    >>> from pathlib import Path
    >>> table = ShadingTable("npy", Path("lst.npy"), legacy=np.full((4, 39, 52), 64, np.uint8))
    >>> gains = table_gains(table, SENSORS["imx219"])
    >>> gains.shape, round(float(gains.min()), 3), round(float(gains.max()), 3)  # 64 is a gain of 2 everywhere
    ((154, 205, 4), 2.0, 2.0)
    """
    width, height = sensor.size
    pattern = sensor.default_pattern
    assert pattern is not None
    nby, nbx = -(-height // bin_size), -(-width // bin_size)
    gains = np.empty((nby, nbx, 4))
    if table.legacy is not None:
        _, rows, cols = table.legacy.shape
        for plane, site in zip(legacy_gains(table.legacy, table.rounding), plane_sites(pattern), strict=True):
            sy, sx = divmod(site, 2)
            ay = cell_interpolation(rows, bin_centres(height, bin_size, sy))
            ax = cell_interpolation(cols, bin_centres(width, bin_size, sx))
            gains[..., site] = ay @ plane @ ax.T
        return gains
    assert table.tuning is not None
    mode = SensorMode.full(width, height, bit_depth=sensor.bit_depth, source="registry")
    channels = site_channels(pattern)
    for site in range(4):
        sy, sx = divmod(site, 2)
        rows, cols = bin_centres(height, bin_size, sy), bin_centres(width, bin_size, sx)
        at = lens_shading_gains_at(table.tuning, mode, rows, cols)
        gains[..., site] = at[channels[site]]
    return gains


def table_calibration(table: ShadingTable, sensor: str | None = None, *, bin_size: int = BIN_SIZE) -> Calibration:
    """The flat field a lens shading table describes, as a ``flat`` calibration of the full sensor.

    Per site, the white is ``W(b) = k min(G) / G(b)`` (paper: ``Cb LST = 1 / W``) with ``G`` the table's gains at
    the bin centres as the hardware interpolates them (:func:`table_gains`) and ``k`` :data:`WHITE_FRACTION` of the
    sensor's range; the geometry is the whole sensor of the registry, the black and white levels the sensor's. The
    provenance's ``inputs`` name the file, its kind and checksum (role ``lens_shading_table``).

    Parameters
    ----------
    table : ShadingTable
        From :func:`picamcal.export.tables.read_shading_table`.
    sensor : str, optional
        The sensor (``--sensor``), where the file does not say it (:func:`table_sensor`).
    bin_size : int
        The calibration's bin edge in sensor pixels.

    Raises
    ------
    TableFileError
        The sensor is not known or disagrees with the table (:func:`table_sensor`), or a gain is not positive.

    Examples
    --------
    >>> from picamcal.export.tables import read_shading_table
    >>> from picamcal.export.tuning import stock_tuning_path
    >>> flat = table_calibration(read_shading_table(stock_tuning_path("imx219", "pisp")))
    >>> flat.kind, flat.sensor, (flat.width, flat.height), flat.inputs[0]["format"]
    ('flat', 'imx219', (3280, 2464), 'libcamera tuning file')
    >>> bool(flat.lens_shading[0, 0, 1] > 2 * flat.lens_shading[77, 102, 1])  # the stock lens' corners
    True
    """
    entry = table_sensor(table, sensor)
    gains = table_gains(table, entry, bin_size)
    if not np.all(np.isfinite(gains)) or not np.all(gains > 0):
        raise TableFileError("the table's gains are not all positive: it describes no flat field", table.path)
    black = float(entry.black_level)
    site_white = WHITE_FRACTION * (entry.white_level - black) * gains.min() / gains
    pattern = entry.default_pattern
    assert pattern is not None
    channel_white = sites_to_channels(site_white, pattern)
    peak = channel_white.reshape(-1, 3).max(axis=0)
    nby, nbx = site_white.shape[:2]
    width, height = entry.size
    provenance = {
        "software_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "black_frame": False,
        "inputs": [
            {
                "role": "lens_shading_table",
                "name": table.path.name,
                "sha256": sha256_file(table.path),
                "format": table.format,
            }
        ],
        IMPORTED_KEY: {"kind": table.kind, **{k: v for k, v in table.details.items() if v is not None}},
    }
    try:
        calibration = Calibration(
            kind="flat",
            pattern=pattern,
            width=width,
            height=height,
            bin_size=bin_size,
            centre_region=centre_region(nby, nbx),
            sensor=entry.name,
            black_level=(black,) * 4,
            black_level_source="references",
            white_level=float(entry.white_level),
            bit_depth=entry.bit_depth,
            geometry=SensorMode.full(width, height, bit_depth=entry.bit_depth, source="registry"),
            provenance=provenance,
            site_responses=site_white[None].astype(np.float32),
            site_white=site_white.astype(np.float32),
            white=channel_white.astype(np.float32),
            lens_shading=(peak / channel_white).astype(np.float32),
            colour_balance=(1.0 / peak).astype(np.float64),
        )
    except CalibrationInputError as exc:
        raise TableFileError(exc.problem, table.path) from None
    object.__setattr__(calibration, "path", table.path)  # messages about it name the user's file
    return calibration


__all__ = ["BIN_SIZE", "legacy_sensors", "table_calibration", "table_gains", "table_sensor"]
