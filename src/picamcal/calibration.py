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

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import atomic_path
from .bayer import bin_centres
from .errors import CalibrationFileError
from .raw.model import RawImage

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


@dataclass
class Calibration:
    """A calibration of one sensor (and its optics): flat field and colour-unmixing field, with provenance.

    Build one with :func:`picamcal.calibrate`; save it with :meth:`save` and read it with
    :func:`load_calibration`. Arrays are described in :data:`ARRAYS`; ``meta`` is the JSON record.
    A ``flat`` calibration (from a white alone, :attr:`kind`) holds only :data:`FLAT_ARRAYS`.

    Attributes
    ----------
    arrays : dict of str to ndarray
    meta : dict
    path : Path or None
        The file it was loaded from (:func:`load_calibration`), for messages; not saved.

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

        Examples
        --------
        >>> cal.save("cal.npz")  # doctest: +SKIP
        """
        path = Path(path)
        record = {"schema": SCHEMA, "schema_version": SCHEMA_VERSION, **self.meta}
        with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
            # Uncompressed: the fields are noise-like floats that barely compress, and saving stays fast.
            np.savez(f, metadata=np.array(json.dumps(record)), **self.arrays)
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
    """Read a calibration written by :meth:`Calibration.save`, checking its schema, kind and array shapes.

    Raises
    ------
    CalibrationFileError
        Missing, corrupt, an image given in its place, of another schema or version, or with inconsistent
        arrays.

    Examples
    --------
    >>> cal = picamcal.load_calibration("cal.npz")  # doctest: +SKIP
    >>> cal.sensor, cal.bin_size, cal.kind  # doctest: +SKIP
    ('imx219', 16, 'full')
    """
    path = Path(path)
    if not path.is_file():
        raise CalibrationFileError("no such calibration file", path)
    _not_a_calibration(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            if "metadata" not in data.files:
                raise CalibrationFileError("not a picamcal calibration file (an .npz without its record)", path)
            contents = {name: np.array(data[name]) for name in data.files}
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise CalibrationFileError(f"not a readable picamcal calibration ({type(exc).__name__}: {exc})", path) from exc
    except ValueError:  # numpy's advice about allow_pickle does not apply: a calibration holds no objects
        raise CalibrationFileError("not a picamcal calibration file (it holds Python objects)", path) from None
    try:
        record = json.loads(str(contents.pop("metadata")))
    except ValueError:
        raise CalibrationFileError("not a picamcal calibration file (its record is not JSON)", path) from None
    if not isinstance(record, dict) or record.get("schema") != SCHEMA:
        raise CalibrationFileError("not a picamcal calibration file", path)
    if record.get("schema_version") != SCHEMA_VERSION:
        raise CalibrationFileError(
            f"calibration schema version {record.get('schema_version')!r} is not supported "
            f"(this picamcal reads version {SCHEMA_VERSION})",
            path,
        )
    record.pop("schema")
    record.pop("schema_version")
    _validate(contents, record, path)
    return Calibration(contents, record, path)


def _expected_shapes(kind: str, nby: int, nbx: int) -> dict[str, tuple[int, ...]]:
    """Array name -> shape of a calibration of ``kind`` with ``nby x nbx`` bins."""
    expected = {name: (nby, nbx, *shape) for name, (shape, _) in ARRAYS.items()}
    expected.update({name: shape for name, (shape, _) in GLOBAL_ARRAYS.items()})
    expected["site_responses"] = (4 if kind == "full" else 1, nby, nbx, 4)
    return expected if kind == "full" else {name: expected[name] for name in FLAT_ARRAYS}


def _validate(arrays: dict[str, np.ndarray], meta: dict[str, Any], path: Path) -> None:
    try:
        nby = -(-int(meta["height"]) // int(meta["bin_size"]))
        nbx = -(-int(meta["width"]) // int(meta["bin_size"]))
        str(meta["pattern"])
        meta["centre_region"]
    except (KeyError, TypeError, ValueError) as exc:
        raise CalibrationFileError(f"calibration record lacks {exc}", path) from None
    kind = meta.get("kind", "full")
    if kind not in KINDS:
        raise CalibrationFileError(f"unknown calibration kind {kind!r} (expected {' or '.join(KINDS)})", path)
    expected = _expected_shapes(kind, nby, nbx)
    for name, shape in expected.items():
        if name not in arrays:
            raise CalibrationFileError(f"calibration lacks the array {name!r}", path)
        if arrays[name].shape != shape:
            raise CalibrationFileError(
                f"calibration array {name!r} has shape {arrays[name].shape}, expected {shape}", path
            )
        if arrays[name].dtype != bool and not np.all(np.isfinite(arrays[name])):
            raise CalibrationFileError(f"calibration array {name!r} holds non-finite values", path)
    extra = sorted(set(arrays) & (set(ARRAYS) | set(GLOBAL_ARRAYS)) - set(expected))
    if extra:
        raise CalibrationFileError(f"a {kind} calibration holds {', '.join(map(repr, extra))}: inconsistent", path)


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
