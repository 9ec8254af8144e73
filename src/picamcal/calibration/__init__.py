"""The Calibration value: every field the correction needs, saved and loaded as one ``.npz``.

File schema (version 1): a NumPy ``.npz`` (read with ``allow_pickle=False``) with the arrays of its
kind and ``metadata``, a 0-d unicode array holding a JSON record::

    {"schema": "picamcal-calibration", "schema_version": 1, "kind": "full", "software_version": "0.1.0",
     "created": "2026-11-21T10:00:00+00:00", "sensor": "imx219", "pattern": "BGGR",
     "width": 3280, "height": 2464, "bin_size": 16, "black_level": [64, 64, 64, 64],
     "black_level_source": "references", "white_level": 1023, "bit_depth": 10, "smoothing": 0.0,
     "light": "jig", "centre_region": [51, 102, 68, 136], "ill_conditioned_bins": 0,
     "inputs": [{"role": "white", "name": "white.dng", "sha256": "...", "format": "dng"}, ...]}

A calibration made with extra colour references lists them in ``inputs`` (role ``colour_<name>``; their
responses are not stored, ``site_responses`` keeps the white, red, green and blue); one made with a bound on its
noise penalty holds ``"noise_limit": {"max_noise_penalty": 2.5, ...}`` (:attr:`Calibration.noise_limit`). Both are
optional keys of version 1: files without them load as before, and the arrays are the same. So is ``light``, the
light the references were taken under (:data:`LIGHTS`: ``jig``, ``screen``, ``sheets``; null or absent: not
recorded).

Two kinds (``"kind"``; a file without the key is ``"full"``, as every file before flat ones existed):

``full``
    From white, red, green and blue references: the flat field and the colour-unmixing field, every
    array of :data:`ARRAYS` and :data:`GLOBAL_ARRAYS`; all correction modes.
``flat``
    From a white reference alone: the flat field and colour balance only (:data:`FLAT_ARRAYS`, with
    ``site_responses`` holding the white alone); modes ``uncorrected`` and ``flat``.

Shapes use ``nby x nbx`` bins of ``bin_size`` sensor pixels (the last row and column may be partial).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np

from .._atomic import atomic_path
from ..bayer import bin_centres
from ..errors import CalibrationFileError, CalibrationInputError
from ..geometry import SensorMode, assumed_geometry
from ..modes import Mode, parse_mode
from ..raw.model import RawImage
from .archive import read_archive
from .fitting import penalty_field, residual_crosstalk
from .schema import (
    ARRAYS,
    DERIVED_KEYS,
    FLAT_ARRAYS,
    GLOBAL_ARRAYS,
    KINDS,
    LIGHTS,
    RECORD_FIELDS,
    SCHEMA,
    SCHEMA_VERSION,
    UNMIXING_ARRAYS,
    Kind,
    check_record,
    validate_arrays,
)

__all__ = [
    "ARRAYS",
    "FLAT_ARRAYS",
    "GLOBAL_ARRAYS",
    "KINDS",
    "LIGHTS",
    "RECORD_FIELDS",
    "SCHEMA",
    "SCHEMA_VERSION",
    "UNMIXING_ARRAYS",
    "Calibration",
    "Kind",
    "Unmixing",
    "is_calibration_file",
    "load_calibration",
    "record_provenance",
]


class Unmixing(NamedTuple):
    """The colour-unmixing arrays of a ``full`` calibration (:meth:`Calibration.require_unmixing`), none missing."""

    crosstalk: np.ndarray
    unmixing: np.ndarray
    pure_unmixing: np.ndarray
    condition_number: np.ndarray
    ill_conditioned: np.ndarray
    centre_response: np.ndarray
    colour_response_inverse: np.ndarray


@dataclass(frozen=True, eq=False, repr=False, kw_only=True)
class Calibration:
    """A calibration of one sensor (and its optics): flat field and colour-unmixing field, with provenance.

    Build one with :func:`picamcal.calibrate` (or :func:`picamcal.calibrate_in_situ`); save it with :meth:`save`
    and read it with :func:`load_calibration` (or :meth:`load`). It is immutable: its fields cannot be assigned
    and its arrays are read-only, so it can be shared and cached by identity. A changed calibration is a new
    value, ``dataclasses.replace(cal, white=...)``, checked as any other.

    It is validated when made: the record's fields and their types, every array of its kind in the shape the
    record implies, real floating point (``ill_conditioned`` bool), finite, and a positive white (``white``,
    ``site_white``, ``lens_shading``, ``colour_balance`` and the white's ``site_responses``).

    Notation follows the paper (Bowman et al., section "Colour crosstalk"): for each bin ``b`` and channel
    ``p``, ``W_p(b)`` is the white response; dividing by it applies the lens shading table and the colour
    balance together, ``Cb_pp LST_p(b) = 1 / W_p(b)``; ``M(b)`` is the crosstalk matrix, ``U(b)`` the
    unmixing field (the identity at the centre) and ``Cx`` the colour response inverse, with
    ``inv(M(b)) = Cx U(b)``. ``nby x nbx`` are the bins (``ceil(height / bin_size)`` by
    ``ceil(width / bin_size)``). Matrices act on column vectors, ``out = U @ rgb``, rows are output channels.

    Attributes
    ----------
    kind : {"full", "flat"}
        ``full``: flat field and colour unmixing, every mode. ``flat``: the flat field from a white alone; its
        unmixing arrays are None and modes ``centre`` and ``pure`` raise :class:`CalibrationFileError`.
    pattern : str
        Bayer order of the references (``RGGB``, ``GBRG``, ``BGGR``, ``GRBG``).
    width, height : int
        Image size in sensor pixels.
    bin_size : int
        Bin edge in sensor pixels (even).
    centre_region : (y0, y1, x0, x1)
        Bin range of the central ninth (:func:`picamcal.bayer.centre_region`), where ``M_centre`` is measured.
    sensor : str or None
        Sensor name, when the references said.
    black_level : 4 floats
        Per-site black level (DN) the calibration stands for.
    black_level_source : str
        ``"dark frame"`` or ``"references"`` (given by their files, the registry or ``--black-level``); an image
        whose black level is unknown takes :attr:`black_level` either way
        (:func:`picamcal.correct.with_known_black_level`).
    white_level : float or None
        White level (DN) of the references.
    bit_depth : int or None
        Bits per pixel of the references.
    smoothing : float
        Standard deviation (bins) of the Gaussian applied to the binned responses.
    light : str or None
        The light the references were taken under, one of :data:`LIGHTS` (``jig``: the jig's LEDs, ``screen``: a
        monitor's full-screen colours, ``sheets``: printed sheets), as ``picamcal calibrate`` read it from an
        acquisition's manifest or was told (``--light``); None when not recorded. The report picks the expected
        accuracy of that workflow (:func:`picamcal.analysis.verdicts.expected_accuracy`).
    provenance : mapping
        The rest of the record, read-only: ``inputs`` (one entry per reference role: name, checksum, format,
        exposure; extra colour references as ``colour_<name>``, with every colour reference's ``fit_residual``
        when there are extras), ``created``, ``software_version``, ``black_frame``, with a bound on the noise
        penalty ``noise_limit`` (:attr:`noise_limit`) and, in situ, ``in_situ`` (docs/calibration-file.md).
    site_responses : ndarray of float32, shape (4, nby, nbx, 4), or (1, nby, nbx, 4) for ``flat``
        Black-subtracted DN of the white, red, green and blue references per Bayer site.
    site_white : ndarray of float32, shape (nby, nbx, 4)
        Per-site white response (DN): the flat field the correction divides by.
    white : ndarray of float32, shape (nby, nbx, 3)
        ``W``: white response per channel R, G, B (DN, greens averaged).
    lens_shading : ndarray of float32, shape (nby, nbx, 3)
        ``LST = max(W) / W``, 1 at the brightest bin.
    colour_balance : ndarray of float64, shape (3,)
        ``Cb = 1 / max(W)`` (per DN).
    crosstalk : ndarray of float32, shape (nby, nbx, 3, 3), or None
        ``M``: column l is the white-normalised response to primary l, ``M @ 1 = 1``.
    unmixing : ndarray of float32, shape (nby, nbx, 3, 3), or None
        ``U = M_centre @ inv(M)``: unmixes to the colours of the sensor centre (mode ``centre``).
    pure_unmixing : ndarray of float32, shape (nby, nbx, 3, 3), or None
        ``inv(M) = Cx @ U``: unmixes to pure primaries (mode ``pure``).
    condition_number : ndarray of float32, shape (nby, nbx), or None
        Frobenius condition number of ``M``.
    ill_conditioned : ndarray of bool, shape (nby, nbx), or None
        Bins whose ``M`` could not be trusted, filled from the nearest good bin.
    centre_response : ndarray of float64, shape (3, 3), or None
        ``M_centre``: the mean of ``M`` over :attr:`centre_region`.
    colour_response_inverse : ndarray of float64, shape (3, 3), or None
        ``Cx = inv(M_centre)``.
    path : Path or None
        The file it was loaded from, for messages; not a field of the value (``dataclasses.replace`` drops it).

    Raises
    ------
    CalibrationInputError
        Made in memory from fields that cannot correct an image (a zero, negative, NaN or complex white,
        shapes that disagree with the record); CalibrationFileError, naming the file, when loaded.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal = picamcal.calibrate(**refs)
    >>> cal.kind, cal.unmixing.shape, cal.centre_region
    ('full', (15, 20, 3, 3), (5, 10, 6, 13))
    >>> cal.white[0, 0, 0] = 1.0
    Traceback (most recent call last):
    ...
    ValueError: assignment destination is read-only
    >>> import dataclasses
    >>> brighter = dataclasses.replace(cal, white=cal.white * 2)  # a new value, checked as any other
    >>> picamcal.load_calibration(cal.save("cal.npz")).kind
    'full'
    """

    # The record: geometry and levels.
    kind: Kind
    pattern: str
    width: int
    height: int
    bin_size: int
    centre_region: tuple[int, int, int, int]
    sensor: str | None = None
    black_level: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    black_level_source: str = "references"
    white_level: float | None = None
    bit_depth: int | None = None
    smoothing: float = 0.0
    light: str | None = None
    geometry: SensorMode | None = None
    provenance: Mapping[str, Any] = field(default_factory=lambda: {"inputs": []})
    # The flat field (both kinds).
    site_responses: np.ndarray
    site_white: np.ndarray
    white: np.ndarray
    lens_shading: np.ndarray
    colour_balance: np.ndarray
    # The colour unmixing (``full`` only).
    crosstalk: np.ndarray | None = None
    unmixing: np.ndarray | None = None
    pure_unmixing: np.ndarray | None = None
    condition_number: np.ndarray | None = None
    ill_conditioned: np.ndarray | None = None
    centre_response: np.ndarray | None = None
    colour_response_inverse: np.ndarray | None = None
    path: Path | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        # A calibration that cannot correct an image (a zero, negative, NaN or complex white; shapes that disagree
        # with the record) is refused where it is made, so it can never be saved or used.
        if not isinstance(self.provenance, Mapping):
            raise CalibrationInputError(f"provenance must be a mapping, not {type(self.provenance).__name__}")
        clash = sorted(set(self.provenance) & {*RECORD_FIELDS, *DERIVED_KEYS, "schema", "schema_version"})
        if clash:
            raise CalibrationInputError(f"provenance holds {', '.join(map(repr, clash))}, a field of the calibration")
        if self.geometry is not None and not isinstance(self.geometry, SensorMode):
            raise CalibrationInputError(f"geometry must be a SensorMode, not {type(self.geometry).__name__}")
        record = self.to_record()
        kind, nby, nbx = check_record(record, None, CalibrationInputError)
        validate_arrays(self.to_arrays(), kind, nby, nbx, None, CalibrationInputError)
        # The checks passed the values as JSON would hold them; stored as the fields' own types, NumPy scalars
        # included, so that the record written is plain JSON.
        typed = {
            "width": int(self.width),
            "height": int(self.height),
            "bin_size": int(self.bin_size),
            "centre_region": tuple(int(v) for v in self.centre_region),
            "black_level": tuple(float(v) for v in self.black_level),
            "smoothing": float(self.smoothing),
            "white_level": _plain_number(self.white_level),
            "bit_depth": None if self.bit_depth is None else int(self.bit_depth),
            "provenance": _freeze(self.provenance),
            "geometry": self.geometry or assumed_geometry(self.sensor, self.width, self.height, self.bit_depth),
        }
        for name, value in typed.items():
            object.__setattr__(self, name, value)
        for name in (*ARRAYS, *GLOBAL_ARRAYS):
            array = getattr(self, name)
            if array is not None:
                object.__setattr__(self, name, _read_only(array))

    def __repr__(self) -> str:
        where = f", path={str(self.path)!r}" if self.path else ""
        return (
            f"Calibration(kind={self.kind!r}, sensor={self.sensor!r}, pattern={self.pattern!r}, "
            f"size={self.width}x{self.height}, bins={self.bins[0]}x{self.bins[1]} of {self.bin_size} px{where})"
        )

    def __reduce__(self) -> tuple[Any, ...]:
        # The read-only provenance (mappingproxy) does not pickle: a calibration pickles as its record and arrays.
        return _unpickle, (self.to_record(), dict(self.to_arrays()), self.path)

    # Record and arrays ------------------------------------------------------------------------------
    @classmethod
    def from_record(
        cls,
        record: Mapping[str, Any],
        arrays: Mapping[str, np.ndarray],
        path: str | os.PathLike[str] | None = None,
    ) -> Calibration:
        """A calibration from its JSON record (without ``schema`` and ``schema_version``) and its arrays by name.

        The inverse of :meth:`to_record` and :meth:`to_arrays`; what :func:`load_calibration` builds with.
        Keys the record may lack take their defaults (a file without ``kind`` is ``full``); ``ill_conditioned_bins``
        is derived from ``ill_conditioned`` and not read.

        Raises
        ------
        CalibrationInputError
            A record or arrays that fail the checks of :class:`Calibration`; CalibrationFileError naming ``path``
            when it is given.

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
        >>> flat = picamcal.calibrate(refs["white"], black=refs["black"])
        >>> same = Calibration.from_record(flat.to_record(), flat.to_arrays())
        >>> same.kind, same.provenance == flat.provenance
        ('flat', True)
        """
        error = CalibrationFileError if path is not None else CalibrationInputError
        path = None if path is None else Path(path)
        check_record(record, path, error)
        fields = {key: record[key] for key in RECORD_FIELDS if key in record}
        fields.setdefault("kind", "full")  # as every file written before flat calibrations existed
        for key in ("centre_region", "black_level"):
            if key in fields:
                fields[key] = tuple(fields[key])
        if "geometry" in fields:
            fields["geometry"] = SensorMode.from_record(fields["geometry"])
        else:  # a file from before the geometry was recorded
            fields["geometry"] = assumed_geometry(
                fields.get("sensor"), fields["width"], fields["height"], fields.get("bit_depth"), source="unknown"
            )
        unknown = sorted(set(arrays) - {*ARRAYS, *GLOBAL_ARRAYS})
        if unknown:
            raise error(f"calibration holds an unknown array {unknown[0]!r}", path)
        # Every array field is given, None where the arrays lack it, so that a missing one is the checks' message.
        fields.update({name: arrays.get(name) for name in (*ARRAYS, *GLOBAL_ARRAYS)})
        try:
            calibration = cls(**fields, provenance=record_provenance(record))
        except CalibrationInputError as exc:
            raise error(exc.problem, path) from None
        object.__setattr__(calibration, "path", path)
        return calibration

    def to_record(self) -> dict[str, Any]:
        """The JSON record of the file (without ``schema`` and ``schema_version``): plain dicts and lists, a copy.

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
        >>> record = picamcal.calibrate(**refs).to_record()
        >>> record["kind"], record["bin_size"], [i["role"] for i in record["inputs"]]
        ('full', 16, ['white', 'red', 'green', 'blue', 'black'])
        """
        record: dict[str, Any] = {key: getattr(self, key) for key in RECORD_FIELDS}
        for key in ("centre_region", "black_level"):
            if isinstance(record[key], (tuple, list, np.ndarray)):
                record[key] = list(record[key])
        for key in ("white_level", "bit_depth"):
            if record[key] is None:
                del record[key]
        geometry = self.geometry or assumed_geometry(self.sensor, self.width, self.height, self.bit_depth)
        record["geometry"] = geometry.to_record()
        record.update(_thaw(self.provenance))
        if self.ill_conditioned is not None:
            record["ill_conditioned_bins"] = int(np.count_nonzero(self.ill_conditioned))
        return record

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The arrays of its kind by name (:data:`ARRAYS`, :data:`GLOBAL_ARRAYS`), as saved in the file.

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
        >>> sorted(picamcal.calibrate(refs["white"]).to_arrays())  # a flat calibration's
        ['colour_balance', 'lens_shading', 'site_responses', 'site_white', 'white']
        """
        names = (*ARRAYS, *GLOBAL_ARRAYS)
        return {name: getattr(self, name) for name in names if getattr(self, name) is not None}

    # Kind -------------------------------------------------------------------------------------------
    @property
    def has_unmixing(self) -> bool:
        """True if the calibration has a colour-unmixing field (modes ``centre`` and ``pure``)."""
        return self.kind == "full"

    @property
    def modes(self) -> tuple[Mode, ...]:
        """The correction modes this calibration can do, in the order of :class:`~picamcal.modes.Mode`."""
        return tuple(mode for mode in Mode if self.has_unmixing or not mode.needs_unmixing)

    def require_unmixing(self, purpose: str) -> Unmixing:
        """The unmixing arrays; CalibrationFileError, one line naming the file and the fix, if there are none.

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
        >>> flat = picamcal.calibrate(refs["white"], black=refs["black"])
        >>> flat.require_unmixing("mode centre")
        Traceback (most recent call last):
        ...
        picamcal.errors.CalibrationFileError: a flat-field calibration (white only) has no colour unmixing for \
mode centre: calibrate with red, green and blue references too, or combine this white with a jig calibration: \
picamcal calibrate --white WHITE --unmixing-from JIG.npz
        """
        arrays = [getattr(self, name) for name in Unmixing._fields]
        if all(array is not None for array in arrays):
            return Unmixing(*arrays)
        record = next((i for i in self.inputs if i.get("role") == "white"), {})
        names = [str(f.get("name", "")) for f in record.get("frames", [record])]
        white = " ".join(names) if all(n and not n.startswith("<") and " " not in n for n in names) else "WHITE"
        raise CalibrationFileError(
            f"a flat-field calibration (white only) has no colour unmixing for {purpose}: calibrate with red, "
            "green and blue references too, or combine this white with a jig calibration: "
            f"picamcal calibrate --white {white} --unmixing-from JIG.npz",
            self.path,
        )

    def check_mode(self, mode: str | Mode) -> Mode:
        """The :class:`~picamcal.modes.Mode` named by ``mode``, if this calibration can do it.

        Raises
        ------
        ValueError
            An unknown mode (the old name ``balance`` is ``uncorrected``, with a warning).
        CalibrationFileError
            ``centre`` or ``pure`` on a flat calibration (:meth:`require_unmixing`).

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> flat = picamcal.calibrate(simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"])
        >>> flat.check_mode("flat"), [mode.value for mode in flat.modes]
        (<Mode.FLAT: 'flat'>, ['uncorrected', 'flat'])
        """
        parsed = parse_mode(mode)
        if parsed.needs_unmixing:
            try:
                self.require_unmixing(f"mode {parsed.value}")
            except CalibrationFileError as exc:  # and the mode this calibration does, under its option's name
                fix = f"{exc.problem}; or correct with --mode flat (its flat field)"
                raise CalibrationFileError(fix, exc.path) from None
        return parsed

    # Geometry ---------------------------------------------------------------------------------------
    @property
    def bins(self) -> tuple[int, int]:
        """Rows and columns of bins, ``(nby, nbx)``."""
        return -(-self.height // self.bin_size), -(-self.width // self.bin_size)

    @property
    def bin_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """(y, x) centres of the bins in sensor pixel coordinates."""
        return bin_centres(self.height, self.bin_size), bin_centres(self.width, self.bin_size)

    @property
    def centre_slices(self) -> tuple[slice, slice]:
        """Bin slices (rows, columns) of the central ninth of the frame."""
        y0, y1, x0, x1 = self.centre_region
        return slice(y0, y1), slice(x0, x1)

    @property
    def centre_white(self) -> np.ndarray:
        """Mean per-site white over the central ninth, shape (4,): the gains of mode ``uncorrected`` are its inverse."""
        ys, xs = self.centre_slices
        return self.site_white[ys, xs].reshape(-1, 4).mean(axis=0)

    # Provenance -------------------------------------------------------------------------------------
    @property
    def inputs(self) -> tuple[Mapping[str, Any], ...]:
        """One record per reference role (``role``, ``name``, ``sha256``, ``format``, exposure, frames)."""
        return tuple(self.provenance.get("inputs", ()))

    @property
    def ill_conditioned_bins(self) -> int:
        """How many bins' crosstalk matrices were filled from their neighbours (0 for a flat calibration)."""
        return 0 if self.ill_conditioned is None else int(np.count_nonzero(self.ill_conditioned))

    # Derived figures --------------------------------------------------------------------------------
    def matrices(self, mode: str | Mode) -> np.ndarray | None:
        """The per-bin 3x3 matrix field a correction mode applies after the flat field (None for none).

        Raises CalibrationFileError for ``centre`` and ``pure`` on a flat calibration (:meth:`check_mode`).
        """
        parsed = self.check_mode(mode)
        return {Mode.CENTRE: self.unmixing, Mode.PURE: self.pure_unmixing}.get(parsed)

    def noise_penalty(
        self, mode: str | Mode = Mode.CENTRE, channel_noise: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ) -> np.ndarray:
        """Per-bin factor by which a correction mode multiplies read noise, shape (nby, nbx, 3).

        Each output value is a linear combination ``c = sum_i a_i p_i`` of raw readings, so with
        independent read noise its noise grows as ``sqrt(sum_i a_i**2)`` (paper, section "Colour
        crosstalk"). Here ``a = U(b) diag(1 / W(b))`` (unmixing times the flat-field gain) and the
        result is relative to channel p's noise at the centre of the flat-fielded image:

            penalty_p(b) = W_p(centre) * sqrt(sum_q (U_pq(b) * sigma_q / W_q(b))**2) / sigma_p

        ``flat`` gives the vignetting penalty ``W_p(centre) / W_p(b)``; ``uncorrected`` gives 1.

        Parameters
        ----------
        mode : {"uncorrected", "flat", "centre", "pure"}
        channel_noise : 3 floats
            Relative read noise of the R, G, B inputs; equal by default, as in the paper. For binned
            images, where each green bin averages twice as many pixels, use ``(1, 2**-0.5, 1)``.

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
        >>> cal = picamcal.calibrate(**refs)
        >>> bool(cal.noise_penalty("centre").max() > cal.noise_penalty("flat").max() > 1)
        True
        """
        parsed = self.check_mode(mode)
        if parsed is Mode.UNCORRECTED:
            return np.ones(self.white.shape, dtype=np.float32)
        ys, xs = self.centre_slices
        w_centre = self.white[ys, xs].reshape(-1, 3).mean(axis=0, dtype=np.float64)  # float32 sums overflow
        matrices = self.matrices(parsed)
        if matrices is None:
            matrices = np.broadcast_to(np.eye(3), (*self.white.shape[:2], 3, 3))
        sigma = np.asarray(channel_noise, dtype=float)
        return penalty_field(matrices, self.white, w_centre, sigma).astype(np.float32)

    @property
    def noise_limit(self) -> Mapping[str, Any] | None:
        """The bound on the centre mode's noise penalty and its colour cost, or None for an unbounded calibration.

        Made by :func:`picamcal.calibrate` with ``max_noise_penalty``: ``max_noise_penalty`` (the bound),
        ``unbounded_max_penalty`` (the worst penalty without it), ``bins_over_bound`` (bins whose penalty was over
        it), ``limited_bins`` (bins blended towards the flat field, a few more than those, so that the field stays
        smooth), ``max_blend`` (the largest blend weight, 0 to 1), ``max_residual_crosstalk`` and
        ``mean_residual_crosstalk`` (over the bins, of the largest leak :meth:`residual_crosstalk` leaves in each)
        and ``worst_bin`` (its row and column).

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
        >>> picamcal.calibrate(**refs).noise_limit is None
        True
        >>> limit = picamcal.calibrate(**refs, max_noise_penalty=2.5).noise_limit
        >>> limit["max_noise_penalty"], limit["limited_bins"] > 0, limit["max_residual_crosstalk"] > 0.01
        (2.5, True, True)
        """
        return self.provenance.get("noise_limit")

    def residual_crosstalk(self) -> np.ndarray:
        """The crosstalk the centre mode leaves, per bin, shape (nby, nbx, 3, 3): ``Cx U(b) M(b) - I``.

        Zero (to float32 rounding) for the full unmixing; a noise-limited one (:attr:`noise_limit`) blended with
        weight ``lambda(b)`` towards the flat field leaves ``lambda(b) (Cx M(b) - I)``. Element ``(p, l)`` is the
        fraction of primary ``l`` that shows as primary ``p``, relative to the centre's colours: off the diagonal
        colour that leaks into another primary, on it saturation lost (negative) or gained
        (:func:`picamcal.calibration.fitting.residual_crosstalk`).

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
        >>> float(np.abs(picamcal.calibrate(**refs).residual_crosstalk()).max()) < 1e-5
        True
        """
        unmixing = self.require_unmixing("the residual crosstalk")
        return residual_crosstalk(
            unmixing.unmixing.astype(np.float64),
            unmixing.crosstalk.astype(np.float64),
            unmixing.colour_response_inverse,
        )

    def check_compatible(self, raw: RawImage, *, same_mode: bool = True) -> None:
        """Raise CalibrationFileError if ``raw`` is not from the sensor this calibration is for, or (``same_mode``)
        not of its size and pattern (a frame of another sensor mode is resampled to first:
        :func:`picamcal.calibration.resample.calibration_for_raw`)."""
        problems = []
        by_size = raw.metadata.get("sensor_source") == "size"  # taken from the frame's size: the calibration says
        if self.sensor and raw.sensor and raw.sensor != self.sensor and not by_size:
            problems.append(f"sensor {raw.sensor}, calibration is for {self.sensor}")
        if same_mode and (raw.width, raw.height) != (self.width, self.height):
            problems.append(f"size {raw.width}x{raw.height}, calibration is for {self.width}x{self.height}")
        elif same_mode and raw.pattern != self.pattern:
            problems.append(f"Bayer pattern {raw.pattern}, calibration is for {self.pattern}")
        if problems:
            raise CalibrationFileError("image does not match the calibration: " + "; ".join(problems), raw.source)

    # Files ------------------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike[str], overwrite: bool = True) -> Path:
        """Write the calibration to one ``.npz`` file (schema version :data:`SCHEMA_VERSION`), atomically.

        Written to a temporary name and renamed, so a reader never sees half a file; :meth:`load` reads it back
        with every field and the kind.

        Raises
        ------
        CalibrationInputError
            The provenance holds what JSON cannot (NaN, objects); nothing is written.
        OutputError
            The file exists and ``overwrite`` is False, or cannot be written.

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
        >>> picamcal.calibrate(**refs).save("cal.npz")
        PosixPath('cal.npz')
        """
        path = Path(path)
        try:
            text = json.dumps({"schema": SCHEMA, "schema_version": SCHEMA_VERSION, **self.to_record()}, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise CalibrationInputError(f"the calibration record is not JSON ({exc})", self.path) from None
        arrays: dict[str, Any] = {"metadata": np.array(text), **self.to_arrays()}
        with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
            # Uncompressed: the fields are noise-like floats that barely compress, and saving stays fast.
            np.savez(f, **arrays)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Calibration:
        """Read a calibration written by :meth:`save`: :func:`load_calibration`.

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> saved = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
        >>> Calibration.load(saved.save("cal.npz")).to_record() == saved.to_record()
        True
        """
        return load_calibration(path)


def record_provenance(record: Mapping[str, Any]) -> dict[str, Any]:
    """The keys of a record that are not fields of :class:`Calibration`: its inputs, times and versions.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> provenance = record_provenance(cal.to_record())
    >>> sorted(provenance), [entry["role"] for entry in provenance["inputs"]]
    (['black_frame', 'created', 'inputs', 'software_version'], ['white', 'red', 'green', 'blue', 'black'])
    """
    return {key: value for key, value in record.items() if key not in (*RECORD_FIELDS, *DERIVED_KEYS)}


def _unpickle(record: dict[str, Any], arrays: dict[str, np.ndarray], path: Path | None) -> Calibration:
    calibration = Calibration.from_record(record, arrays)
    object.__setattr__(calibration, "path", path)
    return calibration


def _plain_number(value: Any) -> Any:
    """A NumPy scalar as the Python number JSON writes; anything else as it is."""
    return value.item() if isinstance(value, np.generic) else value


def _read_only(array: np.ndarray) -> np.ndarray:
    """``array`` itself if nothing can write into its memory, else a read-only copy of it."""
    base: Any = array
    while isinstance(base, np.ndarray):
        if base.flags.writeable:
            array = array.copy()
            array.setflags(write=False)
            return array
        base = base.base
    return array


def _freeze(value: Any) -> Any:
    """A read-only copy of JSON-like data: mappings become mappingproxies, lists tuples."""
    if isinstance(value, Mapping):
        return MappingProxyType({key: _freeze(item) for key, item in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(_freeze(item) for item in value)
    return value


def _thaw(value: Any) -> Any:
    """Plain dicts and lists (what JSON writes) from :func:`_freeze`'s read-only data."""
    if isinstance(value, Mapping):
        return {key: _thaw(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_thaw(item) for item in value]
    return value


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    """Read a calibration written by :meth:`Calibration.save`, validating it before anything is allocated.

    In order: the file must be a regular file and a zip archive; every member's declared size, compression and
    ``.npy`` header (dtype and shape) are read without inflating it, and the record is checked (its JSON types,
    schema version, size, bins and pattern) so that each array's shape and dtype are known before its data is
    read; a member that inflates more than 32-fold is refused as a zip bomb. Then the values are checked as on
    creation (:class:`Calibration`): real floating point, finite, and a positive white.

    Raises
    ------
    CalibrationFileError
        Missing, not a regular file, corrupt, an image given in its place, of another schema or version, or with
        a record or arrays that are malformed or disagree; one line naming the file and the field.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1)).save("cal.npz")
    PosixPath('cal.npz')
    >>> cal = picamcal.load_calibration("cal.npz")
    >>> cal.sensor, cal.bin_size, cal.kind, cal.path.name
    ('imx219', 16, 'full', 'cal.npz')
    >>> picamcal.load_calibration("missing.npz")
    Traceback (most recent call last):
    ...
    picamcal.errors.CalibrationFileError: missing.npz: no such calibration file
    """
    path = Path(path)
    record, arrays = read_archive(path)
    return Calibration.from_record(record, arrays, path)


def is_calibration_file(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is a picamcal calibration that loads: a file ``overwrite`` may replace.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> picamcal.write_dng("white.dng", refs["white"])
    PosixPath('white.dng')
    >>> is_calibration_file(picamcal.calibrate(**refs).save("cal.npz")), is_calibration_file("white.dng")
    (True, False)
    """
    try:
        load_calibration(path)
    except CalibrationFileError:
        return False
    return True
