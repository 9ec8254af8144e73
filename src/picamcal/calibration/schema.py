"""The calibration file's schema: the record's keys, the arrays' names and shapes, and the checks of both.

One definition, used where a calibration is made (:class:`picamcal.calibration.Calibration`) and where a file is
read (:mod:`picamcal.calibration.archive`), so that both refuse the same things with the same one-line messages.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .._json import Fields
from ..errors import PicamcalError, RawFormatError
from ..geometry import GEOMETRY_SOURCES
from ..limits import check_size
from ..raw.model import PATTERNS

SCHEMA = "picamcal-calibration"
SCHEMA_VERSION = 2
#: The versions this picamcal reads: version 1 has no ``geometry`` (it loads as the full sensor, source "unknown").
READABLE_VERSIONS = (1, 2)
#: The kinds of calibration: with colour unmixing, and a flat field from a white alone.
Kind = Literal["full", "flat"]
#: Values of the record's ``kind``.
KINDS: tuple[Kind, ...] = ("full", "flat")

#: Array name -> (trailing shape after (nby, nbx), meaning).
ARRAYS: dict[str, tuple[tuple[int, ...], str]] = {
    "site_responses": ((4,), "(4 references, nby, nbx, 4 sites): black-subtracted DN of white, red, green, blue"),
    "site_white": ((4,), "per 2x2 site white response in DN: the flat field the correction divides by"),
    "white": ((3,), "white response per channel (R, G, B) in DN, greens averaged: W in the paper"),
    "lens_shading": ((3,), "LST = max(W) / W per channel, 1 at the brightest bin (paper, Cb LST = 1 / W)"),
    "crosstalk": ((3, 3), "M: column l is the white-normalised response to primary l, scaled so M @ 1 = 1"),
    "unmixing": ((3, 3), "U = M_centre @ inv(M): unmixes to the colours of the sensor centre"),
    "pure_unmixing": ((3, 3), "inv(M) = Cx @ U: unmixes to pure primaries"),
    "condition_number": ((), "Frobenius condition number of M per bin"),
    "ill_conditioned": ((), "bins whose M could not be trusted; their matrices are filled from the nearest good bin"),
}
#: Array name -> (shape, meaning) of the arrays that are one value for the whole frame.
GLOBAL_ARRAYS: dict[str, tuple[tuple[int, ...], str]] = {
    "colour_balance": ((3,), "Cb = 1 / max(W) per channel"),
    "centre_response": ((3, 3), "M_centre: mean of M over the central ninth of the frame"),
    "colour_response_inverse": ((3, 3), "Cx = inv(M_centre)"),
}
#: The arrays of a ``flat`` calibration (``site_responses`` has one reference, the white).
FLAT_ARRAYS = ("site_responses", "site_white", "white", "lens_shading", "colour_balance")
#: The arrays only a ``full`` calibration has: the colour unmixing.
UNMIXING_ARRAYS = tuple(name for name in (*ARRAYS, *GLOBAL_ARRAYS) if name not in FLAT_ARRAYS)
#: The record's keys that are fields of :class:`Calibration` (the rest of the record is its ``provenance``).
RECORD_FIELDS = (
    "kind",
    "sensor",
    "pattern",
    "width",
    "height",
    "bin_size",
    "centre_region",
    "black_level",
    "black_level_source",
    "white_level",
    "bit_depth",
    "smoothing",
    "light",
    "geometry",
)
#: The lights a calibration's references can be taken under (:attr:`Calibration.light`), named as the workflows of
#: docs/accuracy.md (``picamcal/data/accuracy.json``) name them, with what each is. None (or no key): not recorded.
LIGHTS: dict[str, str] = {
    "jig": "the jig's LEDs",
    "screen": "a monitor's full-screen colours",
    "sheets": "printed sheets under one light",
}
#: A record key derived from the arrays (``ill_conditioned``): written for people reading the file, never read back.
DERIVED_KEYS = ("ill_conditioned_bins",)
#: The one field that is not real floating point: which bins were filled from their neighbours.
BOOL_ARRAYS = ("ill_conditioned",)
#: Responses to the white light and the gains derived from them: zero or negative would divide an image by
#: nothing, or flip its sign.
POSITIVE_ARRAYS = ("site_white", "white", "lens_shading", "colour_balance")
KIND_NAMES = {"f": "real floating point (float32 or float64)", "b": "bool", "U": "a unicode string (the record)"}


def dtype_name(dtype: np.dtype) -> str:
    return f"complex values ({dtype})" if dtype.kind == "c" else f"dtype {dtype}"


def expected_shapes(kind: str, nby: int, nbx: int) -> dict[str, tuple[int, ...]]:
    """Array name -> shape of a calibration of ``kind`` with ``nby x nbx`` bins."""
    expected = {name: (nby, nbx, *shape) for name, (shape, _) in ARRAYS.items()}
    expected.update({name: shape for name, (shape, _) in GLOBAL_ARRAYS.items()})
    expected["site_responses"] = (4 if kind == "full" else 1, nby, nbx, 4)
    return expected if kind == "full" else {name: expected[name] for name in FLAT_ARRAYS}


def check_record(meta: Any, path: Path | None, error: type[PicamcalError]) -> tuple[str, int, int]:
    """Check the record's keys and JSON types; return the kind and the number of bins (rows, columns)."""
    fields = Fields(path, error, "a usable calibration", "calibrate again")
    fields.mapping(meta, "the record", ("pattern", "width", "height", "bin_size", "centre_region", "inputs"))
    kind = meta.get("kind", "full")
    if not isinstance(kind, str) or kind not in KINDS:
        shown = repr(kind[:40]) if isinstance(kind, str) else type(kind).__name__
        raise error(f"unknown calibration kind {shown} (expected {' or '.join(KINDS)})", path)
    width = fields.number(meta["width"], "record 'width'", integer=True, positive=True)
    height = fields.number(meta["height"], "record 'height'", integer=True, positive=True)
    try:
        check_size(path or "calibration", width, height)
    except RawFormatError as exc:
        raise error(f"not a usable calibration: the record {exc.problem}", path) from None
    bin_size = fields.number(meta["bin_size"], "record 'bin_size'", integer=True, minimum=2)
    if bin_size % 2:
        fields.fail("record 'bin_size'", f"must be even, not {bin_size}")
    fields.text(meta["pattern"], "record 'pattern'", PATTERNS)
    nby, nbx = -(-height // bin_size), -(-width // bin_size)
    y0, y1, x0, x1 = fields.numbers(meta["centre_region"], "record 'centre_region'", 4, integer=True, minimum=0)
    if not (y0 < y1 <= nby and x0 < x1 <= nbx):
        fields.fail("record 'centre_region'", f"{[y0, y1, x0, x1]} is not a region of the {nby} x {nbx} bins")
    if meta.get("sensor") is not None:
        fields.text(meta["sensor"], "record 'sensor'")
    for key in ("software_version", "created", "black_level_source"):
        if key in meta:
            fields.text(meta[key], f"record {key!r}")
    if meta.get("light") is not None:
        fields.text(meta["light"], "record 'light'", tuple(LIGHTS))
    black = fields.numbers(meta.get("black_level", [0, 0, 0, 0]), "record 'black_level'", 4, minimum=0)
    if "white_level" in meta:
        fields.number(meta["white_level"], "record 'white_level'", minimum=max(black) + 1)
    if "bit_depth" in meta:
        fields.number(meta["bit_depth"], "record 'bit_depth'", integer=True, minimum=1, maximum=32)
    for key in ("smoothing", "ill_conditioned_bins"):
        if key in meta:
            fields.number(meta[key], f"record {key!r}", minimum=0)
    for i, entry in enumerate(fields.items(meta["inputs"], "record 'inputs'")):
        _check_input(fields, entry, f"record 'inputs'[{i}]")
    if "geometry" in meta:
        _check_geometry(fields, meta["geometry"], width, height)
    if "in_situ" in meta:
        fields.mapping(meta["in_situ"], "record 'in_situ'")
    if "noise_limit" in meta:
        _check_noise_limit(fields, meta["noise_limit"])
    return kind, nby, nbx


def _check_geometry(fields: Fields, geometry: Any, width: int, height: int) -> None:
    """The ``geometry`` record (:meth:`picamcal.geometry.SensorMode.to_record`): the sensor, the crop of the mode on
    it and its binning, which must give the calibration's image size."""
    what = "record 'geometry'"
    fields.mapping(geometry, what, ("sensor_size", "crop", "binning", "source"))
    sw, sh = fields.numbers(geometry["sensor_size"], f"{what}.sensor_size", 2, integer=True, positive=True)
    x, y, cw, ch = fields.numbers(geometry["crop"], f"{what}.crop", 4, integer=True, minimum=0)
    binning = fields.number(geometry["binning"], f"{what}.binning", integer=True, minimum=1, maximum=16)
    fields.text(geometry["source"], f"{what}.source", tuple(GEOMETRY_SOURCES))
    for key in ("hflip", "vflip"):
        if type(geometry.get(key, False)) is not bool:
            fields.fail(f"{what}.{key}", "must be true or false")
    if geometry.get("bit_depth") is not None:
        fields.number(geometry["bit_depth"], f"{what}.bit_depth", integer=True, minimum=1, maximum=32)
    if min(cw, ch) < 1 or x + cw > sw or y + ch > sh:
        fields.fail(f"{what}.crop", f"{[x, y, cw, ch]} is not an area of the {sw}x{sh} sensor")
    size = geometry.get("size")
    if size is not None:
        fields.numbers(size, f"{what}.size", 2, integer=True, positive=True)
    if (size is not None and list(size) != [width, height]) or (
        abs(cw / binning - width) > max(1, width / 100) or abs(ch / binning - height) > max(1, height / 100)
    ):
        fields.fail(what, f"a {cw}x{ch} crop binned {binning}x{binning} is not the calibration's {width}x{height}")


def _check_noise_limit(fields: Fields, limit: Any) -> None:
    """The ``noise_limit`` record of a calibration made with a bound on its noise penalty."""
    fields.mapping(limit, "record 'noise_limit'", ("max_noise_penalty",))
    fields.number(limit["max_noise_penalty"], "record 'noise_limit'.max_noise_penalty", minimum=1)
    for key in ("unbounded_max_penalty", "max_blend", "max_residual_crosstalk", "mean_residual_crosstalk"):
        if key in limit:
            fields.number(limit[key], f"record 'noise_limit'.{key}", minimum=0)
    for key in ("bins_over_bound", "limited_bins"):
        if key in limit:
            fields.number(limit[key], f"record 'noise_limit'.{key}", integer=True, minimum=0)
    if "worst_bin" in limit:
        fields.numbers(limit["worst_bin"], "record 'noise_limit'.worst_bin", 2, integer=True, minimum=0)


def _check_input(fields: Fields, entry: Any, where: str) -> None:
    """One ``inputs`` entry: the role, and the types of what reports and summaries show."""
    fields.mapping(entry, where, ("role",))
    fields.text(entry["role"], f"{where}.role")
    for key in ("name", "sha256", "format"):
        if key in entry and entry[key] is not None:
            fields.text(entry[key], f"{where}.{key}")
    numbers = ("clipped_fraction", "median_fraction", "p99_fraction", "temporal_noise_dn", "averaged_noise_dn")
    for key in (*numbers, "fit_residual"):
        if key in entry and entry[key] is not None:
            fields.number(entry[key], f"{where}.{key}")
    count = fields.number(entry.get("frame_count", 1), f"{where}.frame_count", integer=True, minimum=1)
    if count > 1:
        for key in ("temporal_noise_dn", "averaged_noise_dn"):
            fields.number(entry.get(key), f"{where}.{key}")
    for k, frame in enumerate(fields.items(entry.get("frames", []), f"{where}.frames")):
        fields.mapping(frame, f"{where}.frames[{k}]")
        if "name" in frame:
            fields.text(frame["name"], f"{where}.frames[{k}].name")


def validate_arrays(
    arrays: Mapping[str, Any], kind: str, nby: int, nbx: int, path: Path | None, error: type[PicamcalError]
) -> None:
    """Check a calibration's arrays against its record: every array of its kind and none of the other's, in the
    shapes the bins imply, real finite values, and a positive white (a calibration that passes corrects to finite
    images)."""
    expected = expected_shapes(kind, nby, nbx)
    for name, shape in expected.items():
        if name not in arrays:
            raise error(f"calibration lacks the array {name!r}", path)
        array = arrays[name]
        if not isinstance(array, np.ndarray):
            raise error(f"calibration array {name!r} is a {type(array).__name__}, not an array", path)
        wanted = "b" if name in BOOL_ARRAYS else "f"
        if array.dtype.kind != wanted or array.dtype.itemsize > 8:
            raise error(
                f"calibration array {name!r} has {dtype_name(array.dtype)}, expected {KIND_NAMES[wanted]}", path
            )
        if array.shape != shape:
            raise error(f"calibration array {name!r} has shape {array.shape}, expected {shape}", path)
        if wanted == "f" and not np.all(np.isfinite(array)):
            raise error(f"calibration array {name!r} holds non-finite values (NaN or infinity)", path)
        positive = array[0] if name == "site_responses" else array if name in POSITIVE_ARRAYS else None
        if positive is not None and not np.all(positive > 0):
            count = int(np.count_nonzero(~(positive > 0)))
            which = "the white's responses" if name == "site_responses" else "values"
            raise error(
                f"calibration array {name!r} holds {count} {which} <= 0: a white response or gain must be positive",
                path,
            )
    extra = sorted(set(arrays) - set(expected))
    if extra:
        raise error(f"a {kind} calibration holds {', '.join(map(repr, extra))}: inconsistent", path)
