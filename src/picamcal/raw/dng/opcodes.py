"""The flat field as DNG GainMap opcodes (OpcodeList2): encoded for the writer, decoded for reading back.

A raw editor that follows the DNG specification multiplies the mosaic, after subtracting the black level and
before demosaicing, by the gains of the GainMap opcodes in OpcodeList2 (DNG 1.4, chapter 7 "Opcode List
Processing", opcode ID 9 GainMap). picamcal writes four of them, one per site of the 2x2 Bayer block, in the
layout phone cameras use (Android's ``DngCreator``) and that darktable applies (``rawprepare``, 3.8 and later;
RawTherapee after 5.9 with "flat field from metadata"; docs/dng.md lists the editors):

- the area: Top = the site's row in the 2x2 block (0 or 1), Left = its column, Bottom = the image height, Right =
  its width (darktable takes the site from ``Top & 1`` and ``Left & 1``, and needs Bottom and Right to be the
  image's size); Plane 0, Planes 1, RowPitch 2, ColPitch 2: every second pixel of every second row from there;
- the map: MapPointsV x MapPointsH gains (at least 2 x 2), MapSpacingV/H and MapOriginV/H in relative
  coordinates (0 at the top or left edge of the image, 1 at the bottom or right), MapPlanes 1, the same grid for
  all four sites; between its points the map is interpolated bilinearly, beyond them its edge values are kept;
- every number big-endian whatever the file's byte order (the specification: opcode lists are always
  big-endian): LONG for the integers, DOUBLE for spacing and origin, FLOAT for the gains.

Sources: the DNG specification 1.4 (opcode list layout and GainMap parameters), darktable's ``rawprepare`` and
``dng_opcode.c`` (which maps it accepts and how it interpolates), Android's ``DngUtils`` (the flags).

Each opcode starts with its ID (9), the DNG version it needs (1.3.0.0, where GainMap was introduced), flags
(1 optional, 2 may be skipped for a preview: the mosaic is still right without the map, as phones mark theirs)
and the length of its parameters (76 bytes, then 4 per gain); the list starts with the number of opcodes.

picamcal's gains are ``g_s(p) = k W_s(centre) / W_s(p)`` for site ``s`` at point ``p``, with ``W`` the
calibration's white response (the paper's flat field, ``Cb LST = 1 / W``) and ``W_s(centre)`` its mean over the
central ninth of the frame: every site is corrected to what it gives at the centre, so the centre's colour (the
AsShotNeutral) stays, and ``k`` makes the smallest gain exactly 1 (gains of 1 or more, as Android's lens shading
maps and libcamera's tables have them). A gain above :data:`MAX_GAIN` is refused: see its note.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from ...bayer import bin_centres
from ...errors import CalibrationFileError, RawFormatError
from ...interpolate import interpolation_matrix
from ...limits import require_regular_file
from ..model import RawImage
from .tags import OPCODE_LIST2, UNDEFINED
from .tiff import TiffFile

#: Opcode ID of GainMap (DNG 1.4, chapter 7).
GAIN_MAP_ID = 9
#: The DNG version an opcode needs, written before its flags: GainMap came with DNG 1.3.
_GAIN_MAP_VERSION = (1, 3, 0, 0)
#: Flags: optional (1) and skippable for previews (2); the mosaic is right without the map.
_FLAGS = 3
#: The fixed parameters of a GainMap before its gains: 4 + 4 + 2 LONGs, 4 DOUBLEs, 1 LONG (76 bytes).
_PARAMETERS = struct.Struct(">4I4I2I4dI")
_OPCODE_HEAD = struct.Struct(">I4BII")

#: The largest gain written. A float32 holds far more, but a gain of 16 already lifts a corner by 4 stops, its noise
#: with it, and libcamera's own lens shading tables stop at 16 (Pi 4) or 8 (Pi 5); a flat field needing more is a
#: sign of the wrong calibration or of optics that lose the corners, and the editors would show mostly noise there.
MAX_GAIN = 16.0
#: Map points along an axis at most: a point every half bin, but no more than this (a smooth field needs no more,
#: and the tag stays small: 4 x 65 x 65 float32 gains are 68 kB).
MAX_POINTS = 65


class FlatField(Protocol):
    """What a flat field gives a gain map: a :class:`picamcal.Calibration` is one.

    The raw layer cannot import the calibration (a higher layer): this names only what the writer reads.
    """

    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def bin_size(self) -> int: ...
    @property
    def site_white(self) -> np.ndarray: ...
    @property
    def centre_white(self) -> np.ndarray: ...
    @property
    def path(self) -> Path | None: ...
    def check_compatible(self, raw: RawImage) -> None: ...


@dataclass(frozen=True, eq=False)
class GainMap:
    """The gains of four GainMap opcodes, one per site of the 2x2 Bayer block, on one grid.

    Attributes
    ----------
    gains : ndarray of float32, shape (4, points_v, points_h)
        The gain at each map point, sites row-major in the Bayer block (site ``2 * row + column``).
    size : (width, height)
        The image the map is for, in pixels (the opcodes' Right and Bottom).
    origin : (v, h)
        Relative position of the first map point (0 the top or left edge of the image, 1 the bottom or right).
    spacing : (v, h)
        Relative distance between map points.

    Raises
    ------
    CalibrationFileError
        Gains that are not finite, or outside 1 to :data:`MAX_GAIN`; a grid of fewer than 2 x 2 points, or a
        spacing that is not positive.

    Examples
    --------
    >>> gm = GainMap(np.ones((4, 2, 3), np.float32), (640, 480), (0.0, 0.0), (1.0, 0.5))
    >>> gm.points, decode_opcode_list(encode_gain_map(gm))[3].area
    ((2, 3), (1, 1, 480, 640))
    """

    gains: np.ndarray
    size: tuple[int, int]
    origin: tuple[float, float]
    spacing: tuple[float, float]

    def __post_init__(self) -> None:
        gains = np.asarray(self.gains, dtype=np.float32)
        if gains.ndim != 3 or gains.shape[0] != 4 or min(gains.shape[1:]) < 2:
            raise CalibrationFileError(f"a gain map is 4 grids of at least 2 x 2 gains, not of shape {gains.shape}")
        if not np.all(np.isfinite(gains)):
            raise CalibrationFileError("the gain map has gains that are not finite")
        if not all(np.isfinite(self.spacing)) or min(self.spacing) <= 0 or not all(np.isfinite(self.origin)):
            raise CalibrationFileError(f"a gain map's spacing must be positive, not {self.spacing}")
        largest, smallest = float(gains.max()), float(gains.min())
        if largest > MAX_GAIN:
            raise CalibrationFileError(
                f"the flat field needs a gain of {largest:.4g} (site {_worst_site(gains)}, {np.log2(largest):.1f} "
                f"stops), over the {MAX_GAIN:g} picamcal writes into a DNG GainMap: check the calibration, or let "
                "picamcal correct the frame instead (--output-format linear-dng)"
            )
        if smallest < 1.0:
            raise CalibrationFileError(f"a gain map's gains are 1 to {MAX_GAIN:g}, not as low as {smallest:.4g}")
        gains = gains.copy()
        gains.flags.writeable = False
        object.__setattr__(self, "gains", gains)
        object.__setattr__(self, "size", (int(self.size[0]), int(self.size[1])))
        object.__setattr__(self, "origin", (float(self.origin[0]), float(self.origin[1])))
        object.__setattr__(self, "spacing", (float(self.spacing[0]), float(self.spacing[1])))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GainMap):
            return NotImplemented
        same = (self.size, self.origin, self.spacing) == (other.size, other.origin, other.spacing)
        return same and np.array_equal(self.gains, other.gains)

    __hash__ = None  # type: ignore[assignment]  # equal maps compare their arrays; not a dictionary key

    @property
    def points(self) -> tuple[int, int]:
        """(MapPointsV, MapPointsH)."""
        return self.gains.shape[1], self.gains.shape[2]


def _worst_site(gains: np.ndarray) -> str:
    """Where the largest gain is, ``"(row, column) of the 2x2 block"``, for a message."""
    site = int(np.argmax(gains.reshape(4, -1).max(axis=1)))
    return f"({site // 2}, {site % 2}) of the 2x2 Bayer block"


def flat_field_gain_map(flat: FlatField) -> GainMap:
    """The gain map that flattens a calibration's white: ``k W_s(centre) / W_s(p)``, smallest gain 1.

    The white response of each site is evaluated at the map points with the spline the correction itself uses
    (:func:`picamcal.interpolate.interpolation_matrix` through the per-site bin centres), the points spread
    evenly from edge to edge (origin 0, spacing ``1 / (points - 1)``), a point every half bin, at most
    :data:`MAX_POINTS` along an axis. A pixel's relative coordinate is that of its centre, ``(row + 0.5) /
    height`` (the pixel-centred convention darktable's current sources cite from the specification; darktable 4.2
    takes ``row / height``, half a pixel away, which a field smooth over tens of pixels does not notice).

    Parameters
    ----------
    flat : Calibration
        Anything with the calibration's flat field (:class:`FlatField`).

    Returns
    -------
    GainMap

    Raises
    ------
    CalibrationFileError
        A gain above :data:`MAX_GAIN` would be needed (naming the calibration's file when it has one), or the
        white extrapolates to zero or less at the edge of the frame.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> gm = flat_field_gain_map(cal)
    >>> gm.points, float(gm.gains.min()), bool(1.2 < gm.gains.max() < 3)
    ((31, 41), 1.0, True)
    """
    nby, nbx = flat.site_white.shape[:2]
    nv, nh = min(2 * nby + 1, MAX_POINTS), min(2 * nbx + 1, MAX_POINTS)
    rel_v, rel_h = np.linspace(0.0, 1.0, nv), np.linspace(0.0, 1.0, nh)
    # A map point at relative r stands for the pixel whose centre is there: row r * height - 0.5.
    rows, cols = rel_v * flat.height - 0.5, rel_h * flat.width - 0.5
    white = np.empty((4, nv, nh))
    for site in range(4):
        sy, sx = divmod(site, 2)
        ay = interpolation_matrix(bin_centres(flat.height, flat.bin_size, sy), rows)
        ax = interpolation_matrix(bin_centres(flat.width, flat.bin_size, sx), cols)
        white[site] = ay @ flat.site_white[..., site].astype(np.float64) @ ax.T
    if not np.all(white > 0):
        raise CalibrationFileError(
            "the flat field's white falls to zero or below at the edge of the frame: recalibrate", flat.path
        )
    relative = np.asarray(flat.centre_white, dtype=np.float64)[:, None, None] / white
    try:
        return GainMap(
            (relative / relative.min()).astype(np.float32),
            (flat.width, flat.height),
            (0.0, 0.0),
            (1.0 / (nv - 1), 1.0 / (nh - 1)),
        )
    except CalibrationFileError as exc:
        raise CalibrationFileError(exc.problem, flat.path) from None


def encode_gain_map(gain_map: GainMap) -> bytes:
    """The OpcodeList2 value: the four GainMap opcodes, big-endian (DNG 1.4, chapter 7).

    Examples
    --------
    >>> data = encode_gain_map(GainMap(np.ones((4, 2, 2)), (64, 48), (0.0, 0.0), (1.0, 1.0)))
    >>> len(data), data[:8].hex()
    (436, '0000000400000009')
    """
    width, height = gain_map.size
    (nv, nh), (ov, oh), (sv, sh) = gain_map.points, gain_map.origin, gain_map.spacing
    parts = [struct.pack(">I", 4)]
    for site in range(4):
        top, left = divmod(site, 2)
        gains = gain_map.gains[site].astype(">f4").tobytes()
        parameters = _PARAMETERS.pack(top, left, height, width, 0, 1, 2, 2, nv, nh, sv, sh, ov, oh, 1) + gains
        parts.append(_OPCODE_HEAD.pack(GAIN_MAP_ID, *_GAIN_MAP_VERSION, _FLAGS, len(parameters)))
        parts.append(parameters)
    return b"".join(parts)


@dataclass(frozen=True)
class GainMapOpcode:
    """One GainMap opcode as a file has it, every field of the specification."""

    flags: int
    area: tuple[int, int, int, int]
    plane: int
    planes: int
    pitch: tuple[int, int]
    points: tuple[int, int]
    spacing: tuple[float, float]
    origin: tuple[float, float]
    map_planes: int
    gains: np.ndarray


def decode_opcode_list(data: bytes, path: str | os.PathLike[str] | None = None) -> list[GainMapOpcode]:
    """The GainMap opcodes of an opcode list (other opcodes are skipped), every length checked.

    Raises
    ------
    RawFormatError
        The list is truncated, or an opcode's length disagrees with its map's size.

    Examples
    --------
    >>> gm = GainMap(np.full((4, 2, 2), 1.5), (64, 48), (0.0, 0.0), (1.0, 1.0))
    >>> ops = decode_opcode_list(encode_gain_map(gm))
    >>> [op.area[:2] for op in ops], ops[0].pitch, ops[0].gains.tolist()
    ([(0, 0), (0, 1), (1, 0), (1, 1)], (2, 2), [[1.5, 1.5], [1.5, 1.5]])
    """

    def corrupt(problem: str) -> RawFormatError:
        return RawFormatError(f"corrupt DNG OpcodeList: {problem}", path)

    if len(data) < 4:
        raise corrupt("shorter than its count")
    (count,) = struct.unpack_from(">I", data)
    at, found = 4, []
    for n in range(count):
        if at + _OPCODE_HEAD.size > len(data):
            raise corrupt(f"opcode {n + 1} of {count} lies beyond the end of the list")
        opcode, *_, flags, length = _OPCODE_HEAD.unpack_from(data, at)
        at += _OPCODE_HEAD.size
        if at + length > len(data):
            raise corrupt(f"opcode {n + 1} declares {length} bytes of parameters, past the end of the list")
        if opcode == GAIN_MAP_ID:
            found.append(_gain_map_opcode(flags, data[at : at + length], corrupt))
        at += length
    return found


def _gain_map_opcode(flags: int, parameters: bytes, corrupt: Callable[[str], RawFormatError]) -> GainMapOpcode:
    if len(parameters) < _PARAMETERS.size:
        raise corrupt(f"a GainMap has {len(parameters)} bytes of parameters, fewer than {_PARAMETERS.size}")
    top, left, bottom, right, plane, planes, row_pitch, col_pitch, nv, nh, sv, sh, ov, oh, map_planes = (
        _PARAMETERS.unpack_from(parameters)
    )
    expected = _PARAMETERS.size + 4 * nv * nh * map_planes
    if len(parameters) != expected:
        raise corrupt(f"a {nv} x {nh} x {map_planes} GainMap needs {expected} bytes, not {len(parameters)}")
    gains = np.frombuffer(parameters, ">f4", offset=_PARAMETERS.size).astype(np.float32)
    return GainMapOpcode(
        flags,
        (top, left, bottom, right),
        plane,
        planes,
        (row_pitch, col_pitch),
        (nv, nh),
        (sv, sh),
        (ov, oh),
        map_planes,
        gains.reshape(nv, nh, map_planes).squeeze(axis=2) if map_planes == 1 else gains.reshape(nv, nh, map_planes),
    )


def gain_map_of(opcodes: Sequence[GainMapOpcode], path: str | os.PathLike[str] | None = None) -> GainMap:
    """The :class:`GainMap` of four opcodes in picamcal's layout (one per Bayer site, one grid, full frame).

    Raises
    ------
    RawFormatError
        The opcodes are not four maps of that layout (another writer's maps: per colour plane, per area, ...).
    """
    by_site = {2 * (op.area[0] & 1) + (op.area[1] & 1): op for op in opcodes}
    first = opcodes[0] if opcodes else None
    if (
        first is None
        or len(opcodes) != 4
        or len(by_site) != 4
        or any(
            (op.area[:2], op.area[2:], op.plane, op.planes, op.pitch, op.map_planes)
            != (divmod(site, 2), first.area[2:], 0, 1, (2, 2), 1)
            or (op.points, op.spacing, op.origin) != (first.points, first.spacing, first.origin)
            for site, op in by_site.items()
        )
    ):
        raise RawFormatError("its GainMaps are not four Bayer-site maps on one grid over the whole frame", path)
    height, width = first.area[2:]
    try:
        return GainMap(np.stack([by_site[s].gains for s in range(4)]), (width, height), first.origin, first.spacing)
    except CalibrationFileError as exc:
        raise RawFormatError(exc.problem, path) from None


def read_gain_map(path: str | os.PathLike[str]) -> GainMap | None:
    """The gain map of a DNG that picamcal wrote (IFD 0's OpcodeList2), or None if it has none.

    Raises
    ------
    RawFormatError
        Not a TIFF/DNG, a corrupt OpcodeList2, or GainMaps in another layout than picamcal's.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal = picamcal.calibrate(**refs)
    >>> from picamcal.raw import write_dng
    >>> _ = write_dng("white.dng", refs["white"], gain_map=cal)
    >>> read_gain_map("white.dng") == flat_field_gain_map(cal)
    True
    """
    path = Path(path)
    size = require_regular_file(path, RawFormatError)
    with open(path, "rb") as f:
        tiff = TiffFile(f, size, path)
        ifd0 = tiff.ifd(tiff.first_ifd, "IFD 0")
        values = tiff.tag(ifd0, OPCODE_LIST2, (UNDEFINED,))
    if values is None:
        return None
    return gain_map_of(decode_opcode_list(bytes(values), path), path)
