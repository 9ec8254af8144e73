"""The Calibration value: every field the correction needs, saved and loaded as one ``.npz``.

File schema (version 1): a NumPy ``.npz`` (read with ``allow_pickle=False``) with the arrays of its
kind and ``metadata``, a 0-d unicode array holding a JSON record::

    {"schema": "picamcal-calibration", "schema_version": 1, "kind": "full", "software_version": "0.1.0",
     "created": "2026-11-21T10:00:00+00:00", "sensor": "imx219", "pattern": "BGGR",
     "width": 3280, "height": 2464, "bin_size": 16, "black_level": [64, 64, 64, 64],
     "black_level_source": "references", "white_level": 1023, "bit_depth": 10, "smoothing": 0.0,
     "centre_region": [51, 103, 68, 137], "ill_conditioned_bins": 0,
     "inputs": [{"role": "white", "name": "white.dng", "sha256": "...", "format": "dng"}, ...]}

Two kinds (``"kind"``; a file without the key is ``"full"``, as every file before flat ones existed):

``full``
    From white, red, green and blue references: the flat field and the colour-unmixing field, every
    array of :data:`ARRAYS` and :data:`GLOBAL_ARRAYS`; all correction modes.
``flat``
    From a white reference alone: the flat field and colour balance only (:data:`FLAT_ARRAYS`, with
    ``site_responses`` holding the white alone); modes ``balance`` and ``flat``.

Shapes use ``nby x nbx`` bins of ``bin_size`` sensor pixels (the last row and column may be partial).
"""

from __future__ import annotations

import ast
import json
import math
import os
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import atomic_path
from ._json import Fields, parse_json
from .bayer import bin_centres
from .errors import CalibrationFileError, CalibrationInputError, PicamcalError, RawFormatError
from .limits import check_size, require_regular_file
from .raw.model import PATTERNS, RawImage

SCHEMA = "picamcal-calibration"
SCHEMA_VERSION = 1
MODES = ("balance", "flat", "centre", "pure")
#: The modes that apply the colour-unmixing field, which only a ``full`` calibration has.
UNMIXING_MODES = ("centre", "pure")
#: Values of ``meta["kind"]``: a calibration with colour unmixing, and a flat field from a white alone.
KINDS = ("full", "flat")

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
GLOBAL_ARRAYS = {
    "colour_balance": ((3,), "Cb = 1 / max(W) per channel"),
    "centre_response": ((3, 3), "M_centre: mean of M over the central ninth of the frame"),
    "colour_response_inverse": ((3, 3), "Cx = inv(M_centre)"),
}
#: The arrays of a ``flat`` calibration (``site_responses`` has one reference, the white).
FLAT_ARRAYS = ("site_responses", "site_white", "white", "lens_shading", "colour_balance")
#: The one field that is not real floating point: which bins were filled from their neighbours.
_BOOL_ARRAYS = ("ill_conditioned",)
#: Responses to the white light and the gains derived from them: zero or negative would divide an image by
#: nothing, or flip its sign.
_POSITIVE_ARRAYS = ("site_white", "white", "lens_shading", "colour_balance")
_KIND_NAMES = {"f": "real floating point (float32 or float64)", "b": "bool", "U": "a unicode string (the record)"}
#: A record is a few kB; this leaves room for thousands of averaged frames.
_MAX_RECORD_CHARS = 1 << 20
#: picamcal writes calibrations uncompressed, and measured fields barely compress; a compressed member may
#: inflate at most this much (a zip bomb inflates a thousandfold), or to :data:`_INFLATION_FLOOR` bytes.
_MAX_INFLATION = 32
_INFLATION_FLOOR = 1 << 20
_NPY_MAGIC = b"\x93NUMPY"
#: numpy's own limit on a ``.npy`` header (``max_header_size``).
_MAX_NPY_HEADER = 10_000


@dataclass
class Calibration:
    """A calibration of one sensor (and its optics): flat field and colour-unmixing field, with provenance.

    Build one with :func:`picamcal.calibrate`; save it with :meth:`save` and read it with
    :func:`load_calibration`. Arrays are described in :data:`ARRAYS`; ``meta`` is the JSON record.
    A ``flat`` calibration (from a white alone, :attr:`kind`) holds only :data:`FLAT_ARRAYS`.

    It is validated when made (and again when saved): the record's keys and types, every array of its kind in
    the shape the record implies, real floating point (``ill_conditioned`` bool), finite, and a positive white
    (``white``, ``site_white``, ``lens_shading``, ``colour_balance`` and the white's ``site_responses``).

    Attributes
    ----------
    arrays : dict of str to ndarray
    meta : dict
    path : Path or None
        The file it was loaded from (:func:`load_calibration`), for messages; not saved.

    Raises
    ------
    CalibrationInputError
        Made in memory from fields that cannot correct an image (a zero, negative, NaN or complex white,
        shapes that disagree with the record); CalibrationFileError, naming the file, when loaded.

    Examples
    --------
    >>> cal = picamcal.calibrate("white.dng", "red.dng", "green.dng", "blue.dng")  # doctest: +SKIP
    >>> cal.unmixing.shape  # doctest: +SKIP
    (154, 205, 3, 3)
    >>> cal.save("cal.npz")  # doctest: +SKIP
    """

    arrays: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)
    path: Path | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        # A calibration that cannot correct an image (a zero, negative, NaN or complex white; shapes that disagree
        # with the record) is refused where it is made, so it can never be saved or used.
        self._check()

    def _check(self) -> None:
        _validate(self.arrays, self.meta, self.path, CalibrationFileError if self.path else CalibrationInputError)

    def __getattr__(self, name: str) -> Any:
        arrays = self.__dict__.get("arrays", {})
        if name in arrays:
            return arrays[name]
        if name in ARRAYS or name in GLOBAL_ARRAYS:
            raise AttributeError(f"a {self.kind} calibration has no {name!r} (it has no colour unmixing)")
        raise AttributeError(name)

    # Kind ---------------------------------------------------------------------------------------
    @property
    def kind(self) -> str:
        """``"full"`` (flat field and colour unmixing) or ``"flat"`` (flat field from a white alone)."""
        return str(self.meta.get("kind", "full"))

    @property
    def has_unmixing(self) -> bool:
        """True if the calibration has a colour-unmixing field (modes ``centre`` and ``pure``)."""
        return self.kind == "full"

    @property
    def modes(self) -> tuple[str, ...]:
        """The correction modes this calibration can do, in the order of :data:`MODES`."""
        return MODES if self.has_unmixing else tuple(m for m in MODES if m not in UNMIXING_MODES)

    def require_unmixing(self, purpose: str) -> None:
        """Raise CalibrationFileError, one line naming the file and the fix, if there is no unmixing for ``purpose``.

        Examples
        --------
        >>> flat_cal.require_unmixing("mode centre")  # doctest: +SKIP
        Traceback (most recent call last):
        picamcal.errors.CalibrationFileError: cal.npz: a flat-field calibration (white only) has no colour ...
        """
        if self.has_unmixing:
            return
        record = next((i for i in self.meta.get("inputs", []) if i.get("role") == "white"), {})
        names = [str(f.get("name", "")) for f in record.get("frames", [record])]
        white = " ".join(names) if all(n and not n.startswith("<") and " " not in n for n in names) else "WHITE"
        raise CalibrationFileError(
            f"a flat-field calibration (white only) has no colour unmixing for {purpose}: calibrate with red, "
            "green and blue references too, or combine this white with a jig calibration: "
            f"picamcal calibrate --white {white} --unmixing-from JIG.npz",
            self.path,
        )

    def check_mode(self, mode: str) -> None:
        """Raise ValueError for an unknown mode, CalibrationFileError for an unmixing mode without unmixing."""
        if mode not in MODES:
            raise ValueError(f"unknown mode {mode!r}: choose one of {', '.join(MODES)}")
        if mode in UNMIXING_MODES:
            self.require_unmixing(f"mode {mode}")

    # Geometry -----------------------------------------------------------------------------------
    @property
    def sensor(self) -> str | None:
        """Sensor name, when the references said."""
        return self.meta.get("sensor")

    @property
    def pattern(self) -> str:
        """Bayer pattern of the reference images."""
        return str(self.meta["pattern"])

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return int(self.meta["width"])

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return int(self.meta["height"])

    @property
    def bin_size(self) -> int:
        """Bin edge length in sensor pixels."""
        return int(self.meta["bin_size"])

    @property
    def bin_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """(y, x) centres of the bins in sensor pixel coordinates."""
        return bin_centres(self.height, self.bin_size), bin_centres(self.width, self.bin_size)

    @property
    def centre_slices(self) -> tuple[slice, slice]:
        """Bin slices (rows, columns) of the central ninth of the frame."""
        y0, y1, x0, x1 = self.meta["centre_region"]
        return slice(y0, y1), slice(x0, x1)

    def centre_white(self) -> np.ndarray:
        """Mean per-site white over the central ninth, shape (4,)."""
        ys, xs = self.centre_slices
        return self.site_white[ys, xs].reshape(-1, 4).mean(axis=0)

    # Derived figures ----------------------------------------------------------------------------
    def matrices(self, mode: str) -> np.ndarray | None:
        """The per-bin 3x3 matrix field a correction mode applies after the flat field (None for none).

        Raises CalibrationFileError for ``centre`` and ``pure`` on a flat calibration (:meth:`check_mode`).
        """
        self.check_mode(mode)
        return {"centre": self.arrays.get("unmixing"), "pure": self.arrays.get("pure_unmixing")}.get(mode)

    def noise_penalty(
        self, mode: str = "centre", channel_noise: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ) -> np.ndarray:
        """Per-bin factor by which a correction mode multiplies read noise, shape (nby, nbx, 3).

        Each output value is a linear combination ``c = sum_i a_i p_i`` of raw readings, so with
        independent read noise its noise grows as ``sqrt(sum_i a_i**2)`` (paper, section "Colour
        crosstalk"). Here ``a = U(b) diag(1 / W(b))`` (unmixing times the flat-field gain) and the
        result is relative to channel p's noise at the centre of the flat-fielded image:

            penalty_p(b) = W_p(centre) * sqrt(sum_q (U_pq(b) * sigma_q / W_q(b))**2) / sigma_p

        ``flat`` gives the vignetting penalty ``W_p(centre) / W_p(b)``; ``balance`` gives 1.

        Parameters
        ----------
        mode : {"balance", "flat", "centre", "pure"}
        channel_noise : 3 floats
            Relative read noise of the R, G, B inputs; equal by default, as in the paper. For binned
            images, where each green bin averages twice as many pixels, use ``(1, 2**-0.5, 1)``.

        Examples
        --------
        >>> float(cal.noise_penalty("centre").max())  # doctest: +SKIP
        2.7
        """
        sigma = np.asarray(channel_noise, dtype=float)
        ys, xs = self.centre_slices
        w_centre = self.white[ys, xs].reshape(-1, 3).mean(axis=0)
        if mode == "balance":
            return np.ones(self.white.shape, dtype=np.float32)
        matrices = self.matrices(mode)
        if matrices is None:
            matrices = np.broadcast_to(np.eye(3), (*self.white.shape[:2], 3, 3))
        coefficients = matrices * (sigma / self.white)[..., None, :]
        return (w_centre / sigma * np.sqrt((coefficients**2).sum(axis=-1))).astype(np.float32)

    def check_compatible(self, raw: RawImage) -> None:
        """Raise CalibrationFileError if ``raw`` is not from the sensor, size and pattern this calibration is for."""
        problems = []
        if self.sensor and raw.sensor and raw.sensor != self.sensor:
            problems.append(f"sensor {raw.sensor}, calibration is for {self.sensor}")
        if (raw.width, raw.height) != (self.width, self.height):
            problems.append(f"size {raw.width}x{raw.height}, calibration is for {self.width}x{self.height}")
        elif raw.pattern != self.pattern:
            problems.append(f"Bayer pattern {raw.pattern}, calibration is for {self.pattern}")
        if problems:
            raise CalibrationFileError("image does not match the calibration: " + "; ".join(problems), raw.source)

    # Files --------------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike[str], overwrite: bool = True) -> Path:
        """Write the calibration to one ``.npz`` file, atomically (temporary name, then rename).

        Raises
        ------
        CalibrationInputError
            The fields were changed since it was made into ones that fail its checks (see :class:`Calibration`),
            or the record holds what JSON cannot (NaN); nothing is written.

        Examples
        --------
        >>> cal.save("cal.npz")  # doctest: +SKIP
        """
        path = Path(path)
        self._check()
        try:
            text = json.dumps({"schema": SCHEMA, "schema_version": SCHEMA_VERSION, **self.meta}, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise CalibrationInputError(f"the calibration record is not JSON ({exc})", self.path) from None
        with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
            # Uncompressed: the fields are noise-like floats that barely compress, and saving stays fast.
            np.savez(f, metadata=np.array(text), **self.arrays)
        return path


#: First bytes of the files people give by mistake where a calibration belongs -> what they are.
_IMAGE_SIGNATURES = {
    b"II*\x00": "an image",  # TIFF, little-endian (a DNG is a raw image: see _not_a_calibration)
    b"MM\x00*": "an image",  # TIFF, big-endian
    b"\x93NUMPY": "a raw image",  # a .npy array (picamera2's raw dumps)
    b"\xff\xd8": "an image",  # JPEG (with or without the legacy firmware's raw block)
    b"\x89PNG\r\n\x1a\n": "an image",
}
_ZIP = b"PK\x03\x04"


def _not_a_calibration(path: Path) -> None:
    """Raise the one-line error for a file that is plainly not a calibration, from its first bytes."""
    from .raw.npz import is_raw_npz

    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as exc:
        raise CalibrationFileError(f"cannot read the calibration file ({exc.strerror or exc})", path) from None
    what = next((kind for magic, kind in _IMAGE_SIGNATURES.items() if head.startswith(magic)), None)
    if what is not None and head[:2] in (b"II", b"MM") and path.suffix.lower() == ".dng":
        what = "a raw image"
    elif what is None and head.startswith(_ZIP) and is_raw_npz(path):
        what = "a raw image"
    elif what is None and not head.startswith(_ZIP) and path.suffix.lower() == ".raw":
        what = "a raw image"  # a headless dump has no signature, only its name
    if what is not None:
        raise CalibrationFileError(
            f"this is {what}, not a calibration (the calibration comes first: picamcal correct CALIBRATION IMAGE...)",
            path,
        )
    if not head.startswith(_ZIP):
        raise CalibrationFileError("not a picamcal calibration file (not an .npz archive)", path)


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
    >>> cal = picamcal.load_calibration("cal.npz")  # doctest: +SKIP
    >>> cal.sensor, cal.bin_size, cal.kind  # doctest: +SKIP
    ('imx219', 16, 'full')
    """
    path = Path(path)
    if not os.path.lexists(path):
        raise CalibrationFileError("no such calibration file", path)
    require_regular_file(path, CalibrationFileError)
    _not_a_calibration(path)
    try:
        with zipfile.ZipFile(path) as archive:
            members = _members(archive, path)
            if "metadata" not in members:
                raise CalibrationFileError("not a picamcal calibration file (an .npz without its record)", path)
            record = _read_record(archive, members.pop("metadata"), path)
            kind, nby, nbx = _check_record(record, path, CalibrationFileError)
            expected = _expected_shapes(kind, nby, nbx)
            extra = sorted(set(members) & (set(ARRAYS) | set(GLOBAL_ARRAYS)) - set(expected))
            if extra:
                raise CalibrationFileError(
                    f"a {kind} calibration holds {', '.join(map(repr, extra))}: inconsistent", path
                )
            arrays = {}
            for name, shape in expected.items():
                if name not in members:
                    raise CalibrationFileError(f"calibration lacks the array {name!r}", path)
                dtypes = "b" if name in _BOOL_ARRAYS else "f"
                arrays[name] = _read_member(archive, members[name], name, dtypes, shape, path)
    except (OSError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, NotImplementedError) as exc:
        raise CalibrationFileError(f"not a readable picamcal calibration ({type(exc).__name__}: {exc})", path) from None
    return Calibration(arrays, record, path)


def _members(archive: zipfile.ZipFile, path: Path) -> dict[str, zipfile.ZipInfo]:
    """The archive's ``.npy`` members by array name, each checked for encryption and a zip bomb's inflation."""
    members: dict[str, zipfile.ZipInfo] = {}
    for info in archive.infolist():
        name = info.filename.removesuffix(".npy")
        if name in members:
            raise CalibrationFileError(f"the archive holds {info.filename!r} twice: corrupt", path)
        if info.flag_bits & 0x1:
            raise CalibrationFileError(f"its {info.filename!r} is encrypted: not a picamcal calibration", path)
        if info.compress_type != zipfile.ZIP_STORED and info.file_size > max(
            _INFLATION_FLOOR, _MAX_INFLATION * info.compress_size
        ):
            raise CalibrationFileError(
                f"the archive's {info.filename!r} would inflate from {info.compress_size / 1e6:.1f} MB to "
                f"{info.file_size / 1e6:.0f} MB: refused as a zip bomb (picamcal writes calibrations uncompressed)",
                path,
            )
        members[name] = info
    return members


def _read_record(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path) -> dict[str, Any]:
    """The JSON record of the ``metadata`` member, checked for its schema and version."""
    text = str(_read_member(archive, info, "metadata", "U", (), path)[()])
    try:
        record = parse_json(text, CalibrationFileError, "JSON", path)
    except CalibrationFileError as exc:
        raise CalibrationFileError(f"not a picamcal calibration file (its record is {exc.problem})", path) from None
    if not isinstance(record, dict) or record.get("schema") != SCHEMA:
        raise CalibrationFileError("not a picamcal calibration file", path)
    version = record.get("schema_version")
    if type(version) is not int or version != SCHEMA_VERSION:
        shown = repr(version) if isinstance(version, (int, float, type(None))) else type(version).__name__
        raise CalibrationFileError(
            f"calibration schema version {shown} is not supported (this picamcal reads version {SCHEMA_VERSION})",
            path,
        )
    del record["schema"], record["schema_version"]
    return record


def _read_member(
    archive: zipfile.ZipFile, info: zipfile.ZipInfo, name: str, kinds: str, shape: tuple[int, ...], path: Path
) -> np.ndarray:
    """One ``.npy`` member: its header checked against the dtype kinds and shape expected, then its data read.

    The header and the member's declared size must agree with ``shape`` before a byte of data is read, so a
    forged header or size costs nothing.
    """
    with archive.open(info) as stream:
        dtype, fortran, declared, offset = _npy_header(stream, name, path)
        if dtype.kind not in kinds or (dtype.kind == "f" and dtype.itemsize > 8):
            if dtype.hasobject:
                raise CalibrationFileError("not a picamcal calibration file (it holds Python objects)", path)
            raise CalibrationFileError(
                f"calibration array {name!r} has {_dtype_name(dtype)}, expected {_KIND_NAMES[kinds]}", path
            )
        if name == "metadata" and dtype.itemsize > 4 * _MAX_RECORD_CHARS:
            raise CalibrationFileError(f"the calibration record is over {_MAX_RECORD_CHARS} characters: corrupt", path)
        if declared != shape:
            raise CalibrationFileError(f"calibration array {name!r} has shape {declared}, expected {shape}", path)
        nbytes = dtype.itemsize * math.prod(shape)
        if info.file_size != offset + nbytes:
            raise CalibrationFileError(
                f"calibration array {name!r} declares {info.file_size} bytes, its header {offset + nbytes}: corrupt",
                path,
            )
        data = stream.read(nbytes)
    if len(data) != nbytes:
        raise CalibrationFileError(f"calibration array {name!r} is cut short", path)
    array = np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")
    return array.astype(dtype.newbyteorder("="), order="C")


def _npy_header(stream: Any, name: str, path: Path) -> tuple[np.dtype, bool, tuple[int, ...], int]:
    """(dtype, fortran order, shape, data offset) of a ``.npy`` stream, parsed without numpy's header reader.

    numpy's own raises errors of many types (tokenize.TokenError for a header cut mid-way) and allocates whatever
    the shape says; here every problem is a CalibrationFileError and nothing is allocated.
    """

    def corrupt(problem: str) -> CalibrationFileError:
        return CalibrationFileError(f"calibration array {name!r} {problem}: corrupt", path)

    prefix = stream.read(8)
    if len(prefix) < 8 or not prefix.startswith(_NPY_MAGIC):
        raise corrupt("is not a .npy array")
    size_bytes = {1: 2, 2: 4, 3: 4}.get(prefix[6])
    if size_bytes is None:
        raise corrupt(f"is a .npy array of unknown version {prefix[6]}")
    length = int.from_bytes(stream.read(size_bytes), "little")
    if length > _MAX_NPY_HEADER:
        raise corrupt(f"has a header of {length} bytes")
    raw = stream.read(length)
    if len(raw) != length:
        raise corrupt("has a header cut short")
    try:
        header = ast.literal_eval(raw.decode("utf-8" if prefix[6] == 3 else "latin-1"))
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError, UnicodeDecodeError):
        raise corrupt("has an unreadable header") from None
    if not isinstance(header, dict) or set(header) != {"descr", "shape", "fortran_order"}:
        raise corrupt("has a malformed header")
    shape, fortran, descr = header["shape"], header["fortran_order"], header["descr"]
    if not isinstance(shape, tuple) or not all(type(n) is int and n >= 0 for n in shape) or type(fortran) is not bool:
        raise corrupt("has a malformed header")
    if not isinstance(descr, str):
        raise CalibrationFileError(f"calibration array {name!r} is a structured array, not a field", path)
    try:
        dtype = np.dtype(descr)
    except (TypeError, ValueError):
        raise corrupt(f"has an unknown dtype {descr[:40]!r}") from None
    return dtype, fortran, shape, 8 + size_bytes + length


def _dtype_name(dtype: np.dtype) -> str:
    return f"complex values ({dtype})" if dtype.kind == "c" else f"dtype {dtype}"


def _expected_shapes(kind: str, nby: int, nbx: int) -> dict[str, tuple[int, ...]]:
    """Array name -> shape of a calibration of ``kind`` with ``nby x nbx`` bins."""
    expected = {name: (nby, nbx, *shape) for name, (shape, _) in ARRAYS.items()}
    expected.update({name: shape for name, (shape, _) in GLOBAL_ARRAYS.items()})
    expected["site_responses"] = (4 if kind == "full" else 1, nby, nbx, 4)
    return expected if kind == "full" else {name: expected[name] for name in FLAT_ARRAYS}


def _check_record(meta: Any, path: Path | None, error: type[PicamcalError]) -> tuple[str, int, int]:
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
    if "in_situ" in meta:
        fields.mapping(meta["in_situ"], "record 'in_situ'")
    return kind, nby, nbx


def _check_input(fields: Fields, entry: Any, where: str) -> None:
    """One ``inputs`` entry: the role, and the types of what reports and summaries show."""
    fields.mapping(entry, where, ("role",))
    fields.text(entry["role"], f"{where}.role")
    for key in ("name", "sha256", "format"):
        if key in entry and entry[key] is not None:
            fields.text(entry[key], f"{where}.{key}")
    for key in ("clipped_fraction", "median_fraction", "p99_fraction", "temporal_noise_dn", "averaged_noise_dn"):
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


def _validate(arrays: Any, meta: Any, path: Path | None, error: type[PicamcalError] = CalibrationFileError) -> None:
    """Check a calibration's record and fields: shapes that agree with the record, real finite values, and a
    positive white (a calibration that passes corrects to finite images)."""
    kind, nby, nbx = _check_record(meta, path, error)
    if not isinstance(arrays, dict):
        raise error(f"the calibration's arrays must be a dict, not {type(arrays).__name__}", path)
    expected = _expected_shapes(kind, nby, nbx)
    for name, shape in expected.items():
        if name not in arrays:
            raise error(f"calibration lacks the array {name!r}", path)
        array = arrays[name]
        if not isinstance(array, np.ndarray):
            raise error(f"calibration array {name!r} is a {type(array).__name__}, not an array", path)
        wanted = "b" if name in _BOOL_ARRAYS else "f"
        if array.dtype.kind != wanted or array.dtype.itemsize > 8:
            raise error(
                f"calibration array {name!r} has {_dtype_name(array.dtype)}, expected {_KIND_NAMES[wanted]}", path
            )
        if array.shape != shape:
            raise error(f"calibration array {name!r} has shape {array.shape}, expected {shape}", path)
        if wanted == "f" and not np.all(np.isfinite(array)):
            raise error(f"calibration array {name!r} holds non-finite values (NaN or infinity)", path)
        positive = array[0] if name == "site_responses" else array if name in _POSITIVE_ARRAYS else None
        if positive is not None and not np.all(positive > 0):
            count = int(np.count_nonzero(~(positive > 0)))
            which = "the white's responses" if name == "site_responses" else "values"
            raise error(
                f"calibration array {name!r} holds {count} {which} <= 0: a white response or gain must be positive",
                path,
            )
    extra = sorted(set(arrays) & (set(ARRAYS) | set(GLOBAL_ARRAYS)) - set(expected))
    if extra:
        raise error(f"a {kind} calibration holds {', '.join(map(repr, extra))}: inconsistent", path)


def is_calibration_file(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is a picamcal calibration that loads: a file ``overwrite`` may replace.

    Examples
    --------
    >>> is_calibration_file("cal.npz")  # doctest: +SKIP
    True
    """
    try:
        load_calibration(path)
    except CalibrationFileError:
        return False
    return True
