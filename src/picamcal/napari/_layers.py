"""picamcal's values as napari layer data: plain functions, picamcal values in and ``(data, kwargs, type)`` out.

napari calls these ``LayerData`` tuples (npe2's reader contract); the reader, the sample data and the widgets all
build their layers here, so that a file, a sample and a widget's result look the same. Nothing here imports napari
or Qt: the tuples are plain data, and the functions run (and are tested) without a display.

A raw frame gives two layers (:func:`raw_layers`): its linear RGB (:func:`linear_rgb`: black subtracted, white
balanced as the file says, demosaiced by picamcal's own fused kernel, the one :func:`picamcal.correct` runs) and
its mosaic as the file holds it. A calibration gives its maps (:func:`calibration_layers`), the ones ``picamcal
report`` draws (:mod:`picamcal.analysis.figures`): flat-field gain per channel, the unmixing field's nine elements
and the noise penalty, each on the bin grid, placed over the image it corrects.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..calibration import Calibration
from ..ckernel import correct_c
from ..errors import KernelBuildError, PicamcalError
from ..geometry import SensorMode
from ..kernels import CorrectionFields, correct_numba, correct_numpy, make_taps, numba_available
from ..modes import Mode
from ..raw.model import CHANNELS, RawImage, raw_geometry, require_black_level, site_channels
from ..sensors import SENSORS

__all__ = [
    "DIVERGING_COLORMAP",
    "GAIN_COLORMAP",
    "METADATA_KEY",
    "NOISE_COLORMAP",
    "UNITS",
    "LayerData",
    "calibration_layers",
    "calibration_record",
    "check_stack_frame",
    "display_limits",
    "image_layer",
    "linear_fields",
    "linear_rgb",
    "pixel_size_um",
    "raw_layers",
    "raw_metadata",
    "stack_layers",
    "white_balance",
]

#: A napari layer as npe2 passes it: (data, keyword arguments of the layer, layer type).
LayerData = tuple[Any, dict[str, Any], str]
#: The key of picamcal's record in every layer's ``metadata``.
METADATA_KEY = "picamcal"
#: Colour maps of the calibration's maps: gains sequential (the report's ``viridis``), signed elements diverging
#: and centred on zero, the noise penalty ``inferno``.
GAIN_COLORMAP = "viridis"
DIVERGING_COLORMAP = "PiYG"
NOISE_COLORMAP = "inferno"
#: The unit of the layers' scale where the sensor's pixel pitch is known (napari 0.9's ``units``, read by pint).
UNITS = "micrometer"
#: The percentile of an image's values its contrast runs up to (from a subsample of about _SAMPLE pixels).
DISPLAY_PERCENTILE = 99.5
_SAMPLE = 1 << 16
#: The RawImage metadata copied into a layer's record when the file has it.
_FILE_KEYS = (
    "format",
    "exposure_time_s",
    "analogue_gain",
    "digital_gain",
    "iso",
    "colour_gains",
    "colour_temperature",
    "make",
    "model",
    "timestamp",
    "black_level_source",
    "sensor_source",
    "sensor_candidates",
    "declared_pattern",
    "declared_black_level",
    "frames",
    "frame",
)


def white_balance(raw: RawImage) -> tuple[tuple[float, float], str]:
    """The white balance gains (red, blue) the file records, and where they came from.

    The camera's frozen ``ColourGains`` (picamera2, the legacy JPEG+raw EXIF, picamcal's own records) when the file
    has them, else a DNG's ``AsShotNeutral`` (rpicam-still's: the camera's raw response to white, so the gains are
    green over red and green over blue), else none (1, 1).

    Examples
    --------
    >>> raw = RawImage(np.zeros((4, 4), np.uint16), "BGGR", 64, 1023, 10, "imx219", {"colour_gains": [2.0, 1.5]})
    >>> white_balance(raw)
    ((2.0, 1.5), "the file's colour gains")
    >>> dng = RawImage(np.zeros((4, 4), np.uint16), "BGGR", 64, 1023, 10, None, {"as_shot_neutral": [0.5, 1, 0.8]})
    >>> white_balance(dng)
    ((2.0, 1.25), "the DNG's AsShotNeutral")
    >>> white_balance(RawImage(np.zeros((4, 4), np.uint16), "BGGR", 64, 1023, 10))
    ((1.0, 1.0), 'none recorded (gains of 1)')
    """
    gains = _positive_numbers(raw.metadata.get("colour_gains"), 2)
    if gains is not None:
        return (gains[0], gains[1]), "the file's colour gains"
    neutral = _positive_numbers(raw.metadata.get("as_shot_neutral"), 3)
    if neutral is not None:
        return (neutral[1] / neutral[0], neutral[1] / neutral[2]), "the DNG's AsShotNeutral"
    return (1.0, 1.0), "none recorded (gains of 1)"


def _positive_numbers(value: Any, count: int) -> list[float] | None:
    if not isinstance(value, (list, tuple, np.ndarray)) or len(value) != count:
        return None
    try:
        numbers = [float(v) for v in value]
    except (TypeError, ValueError):
        return None
    return numbers if all(math.isfinite(v) and v > 0 for v in numbers) else None


def linear_fields(raw: RawImage) -> CorrectionFields:
    """The kernels' fields of a plain development: no flat field, no matrix; each site's gain the white balance of
    its channel over the site's range from black to white (:func:`white_balance`).

    The same fields :func:`picamcal.correct` gives its kernels in mode ``uncorrected``, with the file's white
    balance where a calibration's centre white would be.

    Raises
    ------
    RawFormatError
        The black level is unknown (a headless dump of a sensor picamcal does not know): the message says how to
        give it (:func:`picamcal.raw.model.require_black_level`).

    Examples
    --------
    >>> raw = RawImage(np.zeros((4, 4), np.uint16), "BGGR", 64, 1023, 10, "imx219", {"colour_gains": [2.0, 1.5]})
    >>> (linear_fields(raw).site_gains * 959).round(3).tolist()  # B G G R: 1.5, 1, 1, 2 over 1023 - 64
    [1.5, 1.0, 1.0, 2.0]
    """
    require_black_level(raw)
    (red, blue), _ = white_balance(raw)
    balance = np.array([red, 1.0, blue])
    channels = site_channels(raw.pattern)
    black = np.asarray(raw.black_level, dtype=np.float64)
    gains = balance[channels] / (raw.white_level - black)
    rows = make_taps(np.zeros(raw.height, np.int64), np.zeros((raw.height, 4)))
    cols = make_taps(np.zeros(raw.width, np.int64), np.zeros((raw.width, 4)))
    return CorrectionFields(
        black=black.astype(np.float32),
        channels=channels.astype(np.int64),
        site_gains=gains.astype(np.float32),
        white=None,
        white_rows=rows,
        matrices=None,
        matrix_rows=rows,
        matrix_cols=cols,
    )


def linear_rgb(raw: RawImage, out: np.ndarray | None = None) -> np.ndarray:
    """A raw frame's linear RGB: black subtracted, white balanced as the file says, demosaiced; (H, W, 3) float32.

    Each site is scaled to its range from black to white (1.0 is a green pixel at the white level), times its
    channel's white balance gain (:func:`white_balance`), then demosaiced with Malvar, He and Cutler (2004). It is
    :func:`picamcal.correct`'s own full-resolution pass (:mod:`picamcal.kernels`, the C kernel where it compiles,
    else numba's or numpy's, the same arithmetic) with the fields of :func:`linear_fields`: no flat field, no
    unmixing.

    Raises
    ------
    RawFormatError
        The black level is unknown (:func:`linear_fields`).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> rgb = linear_rgb(white)
    >>> rgb.shape, rgb.dtype
    ((240, 320, 3), dtype('float32'))
    >>> centre = rgb[100:140, 140:180].mean(axis=(0, 1))  # the white balance makes the white grey in the middle
    >>> bool(np.ptp(centre) < 0.05 * centre.mean())
    True
    """
    fields = linear_fields(raw)
    try:
        return correct_c(raw.bayer, fields, out)
    except KernelBuildError:
        pass  # no C compiler here: numba's or numpy's pass gives the same
    if numba_available():
        try:
            return correct_numba(raw.bayer, fields, out)
        except ImportError:
            pass  # numba is installed but does not import
    return correct_numpy(raw.bayer, fields, out)


def pixel_size_um(sensor: str | None, geometry: SensorMode | None) -> float | None:
    """The size of one image pixel on the sensor in micrometres: the sensor's pixel pitch times the mode's binning;
    None for a sensor outside picamcal's registry.

    Examples
    --------
    >>> from picamcal.geometry import registry_mode
    >>> pixel_size_um("imx219", registry_mode("imx219", 1640, 1232)), pixel_size_um("imx298", None)
    (2.24, None)
    """
    entry = SENSORS.get(sensor or "")
    if entry is None:
        return None
    return entry.pixel_pitch_um * (geometry.binning if geometry is not None else 1)


def raw_metadata(
    raw: RawImage, warnings: Sequence[str] = (), read_options: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The record a raw frame's layers carry under ``metadata["picamcal"]``: where it came from and what it is.

    ``path``, ``sensor``, ``pattern``, ``black_level``, ``white_level``, ``bit_depth``, the exposure and gains the
    file gives (``exposure_time_s``, ``analogue_gain``, ``iso``, ...), ``white_balance`` (its gains and source),
    ``warnings`` (the text of each warning read_raw gave), ``geometry`` (its sensor mode's record, or None where the
    file's geometry does not hold) and ``sensor_mode`` (in words), ``pixel_size_um``, ``read_options`` (the keyword
    arguments of :func:`picamcal.read_raw` it was read with, those a headless dump needs: read it again with them);
    and ``raw``, the RawImage itself (its mosaic is the raw layer's data, not a copy). Everything but ``raw`` is
    JSON-serialisable.

    Examples
    --------
    >>> raw = RawImage(np.zeros((480, 640), np.uint16), "BGGR", 64, 1023, 10, "imx219", {"path": "white.dng"})
    >>> record = raw_metadata(raw, ["white.dng: a warning"])
    >>> record["path"], record["black_level"], record["pixel_size_um"], record["warnings"]
    ('white.dng', [64.0, 64.0, 64.0, 64.0], 2.24, ['white.dng: a warning'])
    """
    try:
        geometry: SensorMode | None = raw_geometry(raw)
    except PicamcalError as exc:
        geometry, warnings = None, [*warnings, str(exc)]
    gains, source = white_balance(raw)
    record: dict[str, Any] = {
        "path": raw.metadata.get("path"),
        "sensor": raw.sensor,
        "pattern": raw.pattern,
        "black_level": [float(b) for b in raw.black_level],
        "white_level": int(raw.white_level),
        "bit_depth": int(raw.bit_depth),
        **{key: _plain(raw.metadata[key]) for key in _FILE_KEYS if key in raw.metadata},
        "white_balance": {"gains": list(gains), "source": source},
        "warnings": list(warnings),
        "geometry": None if geometry is None else geometry.to_record(),
        "sensor_mode": None if geometry is None else geometry.describe(),
        "pixel_size_um": pixel_size_um(raw.sensor, geometry),
        "read_options": _plain(dict(read_options or {})),
        "raw": raw,
    }
    return record


def _plain(value: Any) -> Any:
    """A metadata value as JSON takes it (numpy numbers and arrays to Python's, tuples to lists)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    return value


def _scale(size: float | None, leading: int = 0) -> dict[str, Any]:
    """The ``scale`` and ``units`` of a layer of pixels ``size`` micrometres wide (none for an unknown size)."""
    if size is None:
        return {}
    return {"scale": (1.0,) * leading + (size, size), "units": ("pixel",) * leading + (UNITS, UNITS)}


def display_limits(data: np.ndarray, low: float | None = 0.0, *, rgb: bool = False) -> tuple[float, float]:
    """Contrast limits for an image (its last two axes the rows and columns; with ``rgb`` the two before the
    channels): from ``low`` (default 0; None: the 0.5th percentile) to the :data:`DISPLAY_PERCENTILE` th percentile
    of its values, from a regular subsample of about 65 000 pixels of each frame (a few milliseconds at 12 MP).

    Examples
    --------
    >>> display_limits(np.linspace(0, 2, 1000).reshape(10, 100))
    (0.0, 1.99)
    """
    rows, cols = data.shape[-3:-1] if rgb else data.shape[-2:]
    step = max(1, math.isqrt(max(1, rows * cols // _SAMPLE)))
    view = data[..., ::step, ::step, :] if rgb else data[..., ::step, ::step]
    sample = np.ravel(view)
    if sample.dtype.kind == "f" and not np.isfinite(sample).all():
        sample = sample[np.isfinite(sample)]
    if sample.size == 0:
        return (0.0, 1.0)
    if low is None:
        bottom, top = (float(v) for v in np.percentile(sample, [100 - DISPLAY_PERCENTILE, DISPLAY_PERCENTILE]))
    else:
        bottom, top = float(low), float(np.percentile(sample, DISPLAY_PERCENTILE))
    if not top > bottom:
        top = bottom + max(abs(bottom) * 1e-3, 1e-6)
    return (round(bottom, 6), round(top, 6))


def image_layer(
    rgb: np.ndarray,
    name: str,
    metadata: Mapping[str, Any] | None = None,
    *,
    pixel_size: float | None = None,
    contrast_limits: tuple[float, float] | None = None,
    visible: bool = True,
) -> LayerData:
    """A linear RGB image, (H, W, 3) (or a stack of them, (N, H, W, 3)), as an RGB image layer.

    ``metadata`` is the layer's record, put under ``metadata["picamcal"]``; ``pixel_size`` (micrometres, e.g.
    ``record["pixel_size_um"]``) gives the layer its physical scale. Contrast runs from 0 to the image's
    :data:`DISPLAY_PERCENTILE` th percentile unless given.

    Examples
    --------
    >>> data, kwargs, kind = image_layer(np.ones((4, 6, 3), np.float32), "white (centre)", {"mode": "centre"})
    >>> kind, kwargs["rgb"], kwargs["name"], kwargs["metadata"]["picamcal"], kwargs["contrast_limits"]
    ('image', True, 'white (centre)', {'mode': 'centre'}, (0.0, 1.0))
    """
    kwargs: dict[str, Any] = {
        "name": name,
        "rgb": True,
        "metadata": {METADATA_KEY: dict(metadata or {})},
        "contrast_limits": contrast_limits or display_limits(rgb, rgb=True),
        "visible": visible,
        **_scale(pixel_size, np.ndim(rgb) - 3),
    }
    return (rgb, kwargs, "image")


def _mosaic_layer(bayer: np.ndarray, name: str, record: Mapping[str, Any]) -> LayerData:
    kwargs: dict[str, Any] = {
        "name": f"{name} (raw)",
        "colormap": "gray",
        "visible": False,
        "metadata": {METADATA_KEY: dict(record, kind="raw mosaic")},
        "contrast_limits": display_limits(bayer, low=None),
        **_scale(record.get("pixel_size_um"), bayer.ndim - 2),
    }
    return (bayer, kwargs, "image")


def raw_layers(
    raw: RawImage, name: str, *, warnings: Sequence[str] = (), read_options: Mapping[str, Any] | None = None
) -> list[LayerData]:
    """The two layers of a raw frame: its linear RGB (:func:`linear_rgb`), then its mosaic (hidden).

    Both carry :func:`raw_metadata` under ``metadata["picamcal"]`` (``kind`` ``"linear rgb"`` or ``"raw mosaic"``)
    and, where the sensor is known, the physical pixel size as their ``scale`` (micrometres, :func:`pixel_size_um`).
    The mosaic is ``raw.bayer`` itself, uint16 as :func:`picamcal.read_raw` gives it, named ``"<name> (raw)"``.

    Parameters
    ----------
    raw : RawImage
    name : str
        The RGB layer's name (the file's stem, as napari names layers).
    warnings : sequence of str
        The text of the warnings reading it gave, kept in the record.
    read_options : mapping, optional
        The keyword arguments of :func:`picamcal.read_raw` it was read with, kept in the record.

    Raises
    ------
    RawFormatError
        The black level is unknown (:func:`linear_fields`).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> (rgb, rgb_kwargs, _), (mosaic, raw_kwargs, _) = raw_layers(white, "white")
    >>> rgb.shape, rgb_kwargs["rgb"], raw_kwargs["name"], mosaic is white.bayer, raw_kwargs["visible"]
    ((240, 320, 3), True, 'white (raw)', True, False)
    >>> record = rgb_kwargs["metadata"]["picamcal"]
    >>> record["sensor"], record["pattern"], record["kind"], rgb_kwargs["units"]
    ('imx219', 'BGGR', 'linear rgb', ('micrometer', 'micrometer'))
    """
    rgb = linear_rgb(raw)
    record = raw_metadata(raw, warnings, read_options)
    return [
        image_layer(rgb, name, dict(record, kind="linear rgb"), pixel_size=record["pixel_size_um"]),
        _mosaic_layer(raw.bayer, name, record),
    ]


def stack_layers(
    raws: Sequence[RawImage],
    name: str,
    *,
    warnings: Sequence[str] = (),
    read_options: Mapping[str, Any] | None = None,
) -> list[LayerData]:
    """A stack of same-sized raw frames as two layers: their linear RGB (N, H, W, 3) and their mosaics (N, H, W).

    The record is the first frame's (:func:`raw_metadata`) with ``paths``, every frame's file, and ``frames``, the
    records of each (without their RawImage).

    Raises
    ------
    PicamcalError
        No frames, or frames of different sizes (naming the first odd one).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> (rgb, kwargs, _), (mosaics, _, _) = stack_layers([refs["white"], refs["red"]], "run")
    >>> rgb.shape, mosaics.shape, kwargs["scale"]
    ((2, 240, 320, 3), (2, 240, 320), (1.0, 1.12, 1.12))
    """
    if not raws:
        raise PicamcalError("no raw frames to stack")
    for raw in raws[1:]:
        check_stack_frame(raw, raws[0])
    first = raws[0]
    rgb = np.empty((len(raws), first.height, first.width, 3), dtype=np.float32)
    for k, raw in enumerate(raws):
        linear_rgb(raw, out=rgb[k])
    mosaics = np.stack([raw.bayer for raw in raws])
    records = [raw_metadata(raw) for raw in raws]
    record = dict(raw_metadata(first, warnings, read_options))
    record.update(
        paths=[r["path"] for r in records],
        frames=[{k: v for k, v in r.items() if k != "raw"} for r in records],
        raw=None,
    )
    return [
        image_layer(rgb, name, dict(record, kind="linear rgb"), pixel_size=record["pixel_size_um"]),
        _mosaic_layer(mosaics, name, record),
    ]


def check_stack_frame(raw: RawImage, first: RawImage) -> None:
    """Raise unless ``raw`` is of the size of ``first``, the first frame of its stack, with the line a batch's zarr
    stack gives a frame of another size (:func:`picamcal.output.ome_zarr.write_frame`).

    Examples
    --------
    >>> first = RawImage(np.zeros((4, 6), np.uint16), "BGGR", 64, 1023, 10, None, {"path": "a.dng"})
    >>> check_stack_frame(RawImage(np.zeros((4, 8), np.uint16), "BGGR", 64, 1023, 10, None, {"path": "b.dng"}), first)
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: b.dng: is 8x4, the stack's frames are 6x4
    """
    if raw.bayer.shape != first.bayer.shape:
        raise PicamcalError(
            f"is {raw.width}x{raw.height}, the stack's frames are {first.width}x{first.height}", raw.source
        )


# Calibrations ---------------------------------------------------------------------------------------------------


def _bin_grid(calibration: Calibration) -> dict[str, Any]:
    """``scale`` and ``translate`` that put a calibration's bins over the image it corrects: bin k covers the pixels
    from k * bin_size, so its centre is at pixel k * bin_size + (bin_size - 1) / 2; in micrometres where the
    calibration's sensor is known, as the image's layers are."""
    size = pixel_size_um(calibration.sensor, calibration.geometry) or 1.0
    known = calibration.sensor in SENSORS
    step = calibration.bin_size * size
    offset = (calibration.bin_size - 1) / 2 * size
    grid: dict[str, Any] = {"scale": (step, step), "translate": (offset, offset)}
    if known:
        grid["units"] = (UNITS, UNITS)
    return grid


def calibration_record(calibration: Calibration) -> dict[str, Any]:
    """What a calibration's map layers carry under ``metadata["picamcal"]``: its file, sensor, kind and size, and the
    Calibration itself under ``calibration``.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"])
    >>> record = calibration_record(cal)
    >>> record["kind"], record["modes"], record["bins"]
    ('flat', ['uncorrected', 'flat'], [15, 20])
    >>> print(record["note"])
    a flat-field calibration (a white alone): no unmixing field or noise penalty
    """
    path = getattr(calibration, "path", None)
    record: dict[str, Any] = {
        "path": None if path is None else os.fspath(path),
        "sensor": calibration.sensor,
        "kind": calibration.kind,
        "pattern": calibration.pattern,
        "width": calibration.width,
        "height": calibration.height,
        "bin_size": calibration.bin_size,
        "bins": list(calibration.bins),
        "modes": [str(mode) for mode in calibration.modes],
        "geometry": None if calibration.geometry is None else calibration.geometry.to_record(),
        "calibration": calibration,
    }
    if not calibration.has_unmixing:
        record["note"] = "a flat-field calibration (a white alone): no unmixing field or noise penalty"
    return record


def _map_layer(
    values: np.ndarray,
    name: str,
    what: str,
    colormap: str,
    limits: tuple[float, float],
    record: Mapping[str, Any],
    grid: Mapping[str, Any],
    visible: bool = False,
) -> LayerData:
    """One map, named ``"<name> <what>"``, its record's ``map`` saying ``what``."""
    kwargs: dict[str, Any] = {
        "name": f"{name} {what}",
        "colormap": colormap,
        "contrast_limits": limits,
        "visible": visible,
        "metadata": {METADATA_KEY: dict(record, map=what)},
        **grid,
    }
    return (np.ascontiguousarray(values, dtype=np.float32), kwargs, "image")


def _span(low: float, high: float) -> tuple[float, float]:
    """(low, high) as contrast limits, widened a little where the map is flat."""
    low, high = float(low), float(high)
    return (low, high) if high > low else (low, low + max(abs(low) * 1e-3, 1e-6))


def calibration_layers(calibration: Calibration, name: str) -> list[LayerData]:
    """A calibration as its maps, the ones ``picamcal report`` draws, on its bins placed over the image.

    In order (the last on top, the only one shown at first):

    - ``"<name> flat-field gain R"`` (G, B): the flat field per channel, ``LST = max(W) / W`` (1 at the brightest
      bin), colour map ``viridis``, the three on one scale from 1 to the largest gain (as the report's
      :func:`~picamcal.analysis.figures.lens_shading_maps`);
    - for a full calibration, ``"<name> unmixing U[R,G]"`` (the nine elements of the centre mode's unmixing field
      ``U``, row the output channel, column the input): the diagonal on one sequential scale (its range), the
      off-diagonal elements on one diverging scale centred on 0 (``PiYG``, symmetric about zero), as
      :func:`~picamcal.analysis.figures.unmixing_grid`;
    - ``"<name> noise penalty"``: the factor by which the correction multiplies read noise relative to the sensor
      centre, the worst channel in each bin (:meth:`~picamcal.calibration.Calibration.noise_penalty`, mode
      ``centre``), colour map ``inferno`` from 1 (no penalty) to its largest; a flat-field calibration has no
      unmixing, so neither this map nor the unmixing field, and its record's ``note`` says so.

    Each layer's record (``metadata["picamcal"]``) is :func:`calibration_record` with ``map`` naming the map.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> layers = calibration_layers(cal, "cal")
    >>> [kwargs["name"] for _, kwargs, _ in layers][::4]
    ['cal flat-field gain R', 'cal unmixing U[R,G]', 'cal unmixing U[G,B]', 'cal noise penalty']
    >>> data, kwargs, kind = layers[-1]
    >>> data.shape, kwargs["colormap"], kwargs["contrast_limits"][0], kwargs["visible"], kwargs["scale"]
    ((15, 20), 'inferno', 1.0, True, (17.92, 17.92))
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> flat = calibration_layers(picamcal.calibrate(white), "flat")
    >>> [kwargs["name"] for _, kwargs, _ in flat], flat[0][1]["metadata"]["picamcal"]["kind"]
    (['flat flat-field gain R', 'flat flat-field gain G', 'flat flat-field gain B'], 'flat')
    """
    record = calibration_record(calibration)
    grid = _bin_grid(calibration)
    gains = calibration.lens_shading
    gain_limits = _span(1.0, max(float(gains.max()), 1.0))
    layers = [
        _map_layer(gains[..., c], name, f"flat-field gain {c_name}", GAIN_COLORMAP, gain_limits, record, grid)
        for c, c_name in enumerate(CHANNELS)
    ]
    if not calibration.has_unmixing:
        layers[-1][1]["visible"] = True
        return layers
    unmixing = calibration.matrices(Mode.CENTRE)
    assert unmixing is not None
    diagonal = np.stack([unmixing[..., k, k] for k in range(3)])
    off = np.stack([unmixing[..., p, q] for p in range(3) for q in range(3) if p != q])
    diagonal_limits = _span(diagonal.min(), diagonal.max())
    reach = max(float(np.abs(off).max()), 1e-6)
    for p in range(3):
        for q in range(3):
            element = f"U[{CHANNELS[p]},{CHANNELS[q]}]"
            colormap, limits = (GAIN_COLORMAP, diagonal_limits) if p == q else (DIVERGING_COLORMAP, (-reach, reach))
            layers.append(_map_layer(unmixing[..., p, q], name, f"unmixing {element}", colormap, limits, record, grid))
    penalty = calibration.noise_penalty(Mode.CENTRE).max(axis=-1)
    penalty_limits = _span(1.0, max(float(penalty.max()), 1.0))
    layers.append(
        _map_layer(penalty, name, "noise penalty", NOISE_COLORMAP, penalty_limits, record, grid, visible=True)
    )
    return layers
