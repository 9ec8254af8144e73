"""The fused correction kernel in C: ``_kernel.c``, compiled once per installation and loaded with ctypes.

The kernel is that of :mod:`picamcal.kernels` (black, flat field, Malvar-He-Cutler demosaic, matrix field, float32
output or codes in one pass), with the same float32 operations in the same order as the numba and numpy paths:
codes equal numpy's bit for bit (uint16 ones of a power-of-two scale, and a :class:`~picamcal.kernels.SrgbTable`'s),
and the float32 values too (each operation is an IEEE float32 one, correctly rounded, none fused). Its point is the
start: loading the compiled library takes about a millisecond, where numba's runtime takes about half a second to
load its own cached kernel. It keeps no threads between calls, so a process may fork after using it.

The same library encodes a float32 image as those codes (:func:`encode_c`; :func:`encode_image` picks it, else
numba's or numpy's): the single-file outputs of a float image (``uint16-tiff``, the sRGB formats) convert with the
kernel's own code.

The first process that needs the kernel compiles it with the system's C compiler (under a second) into the cache
(:func:`cache_dir`), under a name keyed by the source, the compiler command, its flags and the machine (and the
CPU, as the code is built for the host's instruction set); every later process loads that file without starting
any other process. Workers that compile at once each write a temporary file and rename it into place. Without a
compiler, or when it fails, the failure is remembered next to where the library would be (with the compiler's
message), so that a machine without a compiler does not try again in every process: ``engine="auto"`` of
:func:`picamcal.correct.correct` then uses numba or numpy, and ``engine="c"`` raises
:class:`~picamcal.errors.KernelBuildError`. A cache that cannot be written is replaced by a private temporary
folder for this process.

The compiler: ``$CC``, else the one Python was built with (``sysconfig``'s ``CC``, its first word), else ``cc``.
No fast-math: ``-ffp-contract=off`` keeps a multiply and an add two roundings, as numpy does them (aarch64 gcc
fuses them by default).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shlex
import shutil
import sysconfig
import tempfile
import threading
from pathlib import Path

import numpy as np

from ._atomic import atomic_path
from .errors import KernelBuildError, OutputError
from .kernels import (
    CorrectionFields,
    SrgbTable,
    encode_codes,
    encode_numba,
    encode_table,
    kernel_threads,
    numba_available,
    output_array,
)

#: The kernel's source, shipped in the package.
SOURCE = Path(__file__).with_name("_kernel.c")
#: Compiler flags. ``-march=native``: the host's vector instructions, as numba uses them (on x86-64, SSE2 alone
#: leaves the interleaved writes and the rounding of codes unvectorised); the library's name is keyed by the CPU.
FLAGS = ("-O3", "-march=native", "-shared", "-fPIC", "-pthread", "-ffp-contract=off", "-std=gnu11")
#: Rows per work item, as the numba kernel's (:data:`picamcal.kernels.NUMBA_BLOCK_ROWS`).
C_BLOCK_ROWS = 64
#: Rows per work item of :func:`encode_c`.
ENCODE_BLOCK_ROWS = 16
#: Values of :func:`encode_image`'s ``engine``.
ENCODE_ENGINES = ("auto", "c", "numba", "numpy")

#: The lines of /proc/cpuinfo that say which instructions the CPU has (x86, Arm, RISC-V), not its speed or cores.
_CPU_LINES = {
    "vendor_id",
    "cpu family",
    "model",
    "model name",
    "flags",
    "features",
    "cpu implementer",
    "cpu architecture",
    "cpu variant",
    "cpu part",
    "isa",
    "uarch",
}

_lock = threading.Lock()


class _Output(ctypes.Structure):
    """``picamcal_output`` of ``_kernel.c``: what is written for each pixel."""

    _fields_ = [
        ("out", ctypes.c_void_p),
        ("kind", ctypes.c_int64),
        ("scale", ctypes.c_float),
        ("matrix", ctypes.c_float * 9),
        ("base", ctypes.c_void_p),
        ("inside", ctypes.c_void_p),
        ("cells", ctypes.c_int64),
    ]


#: ``picamcal_output.kind``: float32 values, scaled uint16 codes, the sRGB formats' uint8 or uint16 codes.
_KINDS = {"float32": 0, "scaled": 1, "uint8": 2, "uint16": 3}


class _EncodeJob(ctypes.Structure):
    """``picamcal_encode_job`` of ``_kernel.c``: the same fields in the same order."""

    _fields_ = [
        ("image", ctypes.c_void_p),
        ("height", ctypes.c_int64),
        ("width", ctypes.c_int64),
        ("output", _Output),
        ("block_rows", ctypes.c_int64),
        ("threads", ctypes.c_int64),
    ]


class _Job(ctypes.Structure):
    """``picamcal_job`` of ``_kernel.c``: the same fields in the same order."""

    _fields_ = [
        ("bayer", ctypes.c_void_p),
        ("height", ctypes.c_int64),
        ("width", ctypes.c_int64),
        ("black", ctypes.c_void_p),
        ("channels", ctypes.c_void_p),
        ("site_gains", ctypes.c_void_p),
        ("white", ctypes.c_void_p),
        ("white_ny", ctypes.c_int64),
        ("white_first", ctypes.c_void_p),
        ("white_weights", ctypes.c_void_p),
        ("matrices", ctypes.c_void_p),
        ("matrix_ny", ctypes.c_int64),
        ("matrix_nx", ctypes.c_int64),
        ("matrix_row_first", ctypes.c_void_p),
        ("matrix_row_weights", ctypes.c_void_p),
        ("matrix_col_first", ctypes.c_void_p),
        ("matrix_col_weights", ctypes.c_void_p),
        ("matrix_runs", ctypes.c_void_p),
        ("n_runs", ctypes.c_int64),
        ("output", _Output),
        ("block_rows", ctypes.c_int64),
        ("threads", ctypes.c_int64),
        ("clip_level", ctypes.c_int64),
        ("clipped", ctypes.c_int64),
    ]


def cache_dir() -> Path:
    """Where the compiled kernel is kept: ``$PICAMCAL_CACHE_DIR``, else ``$XDG_CACHE_HOME/picamcal``, else
    ``~/.cache/picamcal``.

    Examples
    --------
    >>> cache_dir().name != ""
    True
    """
    if folder := os.environ.get("PICAMCAL_CACHE_DIR"):
        return Path(folder)
    base = os.environ.get("XDG_CACHE_HOME", "")
    if not os.path.isabs(base):  # the XDG specification: a relative path is to be ignored
        base = os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "picamcal"


def compiler() -> list[str]:
    """The C compiler command: ``$CC`` (split as a shell would), else Python's own (its first word), else ``cc``.

    Examples
    --------
    >>> len(compiler()) >= 1
    True
    """
    if command := shlex.split(os.environ.get("CC", "")):
        return command
    configured = (sysconfig.get_config_var("CC") or "").split()
    return configured[:1] or ["cc"]


def _cpu() -> str:
    """What identifies this CPU's instruction set: the first processor's model and feature lines of /proc/cpuinfo."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            lines = []
            for line in f:
                if not line.strip():
                    break
                if line.partition(":")[0].strip().lower() in _CPU_LINES:
                    lines.append(line.strip())
            return "\n".join(lines)
    except OSError:
        return platform.processor()


def _key(source: bytes, command: list[str]) -> str:
    """The cached library's name stem: a hash of everything the compiled code depends on."""
    digest = hashlib.sha256(source)
    for part in (*command, *FLAGS, platform.machine(), _cpu()):
        digest.update(b"\0" + part.encode("utf-8", "surrogateescape"))
    return digest.hexdigest()[:20]


def _compiler_identity(command: list[str]) -> str:
    """Where the compiler is and when it was installed, so that installing or changing one tries again."""
    found = shutil.which(command[0])
    if found is None:
        return "missing"
    try:
        status = os.stat(found)
    except OSError:
        return "missing"
    return f"{found}:{status.st_mtime_ns}:{status.st_size}"


class _CompileFailed(Exception):
    """The compiler's message, raised inside :func:`~picamcal._atomic.atomic_path` so that its temporary goes."""


def _compile(command: list[str], source: bytes, library: Path) -> str | None:
    """Compile ``source`` into ``library``, written whole or not at all (:func:`~picamcal._atomic.atomic_path`, whose
    temporaries a killed compile leaves are removed later); the compiler's message if it failed, else None.

    Raises
    ------
    OutputError
        ``library``'s folder cannot be written.
    """
    import subprocess

    try:
        with atomic_path(library) as temporary:
            try:
                result = subprocess.run(
                    [*command, *FLAGS, "-x", "c", "-o", str(temporary), "-"],
                    input=source,
                    capture_output=True,
                    timeout=600,
                )
            except OSError as exc:
                raise _CompileFailed(f"cannot run {command[0]} ({exc.strerror or exc})") from None
            except subprocess.TimeoutExpired:
                raise _CompileFailed(f"{shlex.join(command)} did not finish in 10 minutes") from None
            if result.returncode != 0:
                message = result.stderr.decode("utf-8", "replace").strip()
                raise _CompileFailed(message or f"{shlex.join(command)} exited with status {result.returncode}")
            os.chmod(temporary, 0o755)  # as a compiler's output usually is
    except _CompileFailed as failed:
        return str(failed)
    return None


def _first_error(message: str) -> str:
    """The line of a compiler's message that says what went wrong: the first with "error", else the first."""
    lines = [line.strip() for line in message.splitlines() if line.strip()]
    return next((line for line in lines if "error" in line.lower()), lines[0] if lines else "no message")


def _compile_failure(command: list[str], message: str) -> str:
    return (
        f"the C kernel cannot be compiled with {shlex.join(command)}: {_first_error(message)}. Install a C "
        'compiler (Debian: apt install gcc libc6-dev), set CC to one, or use engine="numba"'
    )


def _failed(problem: str, marker: Path | None) -> KernelBuildError:
    remembered = f" (remembered in {marker}: delete it to try again)" if marker is not None else ""
    return KernelBuildError(problem + remembered)


def _open(path: Path) -> ctypes.CDLL:
    """Load the compiled library and declare its function; OSError if it is no loadable library of this source."""
    library = ctypes.CDLL(str(path))
    for name, struct in (("job", _Job), ("encode_job", _EncodeJob)):
        try:
            size = getattr(library, f"picamcal_{name}_size")
        except AttributeError:
            raise OSError(f"{path} is not a build of this kernel (it has no picamcal_{name}_size)") from None
        size.restype, size.argtypes = ctypes.c_size_t, []
        if size() != ctypes.sizeof(struct):
            raise OSError(f"{path} was built from another layout of the kernel's arguments")
    library.picamcal_correct.restype = ctypes.c_int
    library.picamcal_correct.argtypes = [ctypes.POINTER(_Job)]
    library.picamcal_encode.restype = ctypes.c_int
    library.picamcal_encode.argtypes = [ctypes.POINTER(_EncodeJob)]
    return library


def _load_failure(path: Path, exc: OSError) -> str:
    return (
        f"the C kernel compiled into {path} cannot be loaded ({exc}): set PICAMCAL_CACHE_DIR to a folder that "
        'libraries may be loaded from (not mounted noexec), or use engine="numba"'
    )


@functools.cache
def _library() -> ctypes.CDLL | KernelBuildError:
    """The compiled kernel, loaded from the cache or compiled into it; the error when it cannot be built.

    A failure is remembered in a marker file keyed like the library and by the compiler file itself (installing
    one tries again): its first line is the error, the rest the compiler's whole message.
    """
    with _lock:
        source = SOURCE.read_bytes()
        command = compiler()
        key = _key(source, command)
        folder = cache_dir()
        library = folder / f"kernel-{key}.so"
        if library.exists():
            try:
                return _open(library)
            except OSError:
                pass  # damaged, or not loadable here: compiled again below, unless that failed before
        identity = hashlib.sha256(_compiler_identity(command).encode()).hexdigest()[:12]
        marker = folder / f"kernel-{key}-{identity}.failed"
        try:
            return _failed(marker.read_text(encoding="utf-8", errors="replace").partition("\n")[0], marker)
        except OSError:
            pass  # no failure remembered
        try:
            folder.mkdir(parents=True, exist_ok=True)
            message = _compile(command, source, library)
        except (OSError, OutputError):
            return _build_privately(command, source, library.name)
        if message is None:
            try:
                return _open(library)
            except OSError as exc:
                problem, message = _load_failure(library, exc), ""
        else:
            problem = _compile_failure(command, message)
        try:
            with atomic_path(marker) as temporary:
                temporary.write_text(f"{problem}\n{message}", encoding="utf-8")
        except OutputError:
            return _failed(problem, None)
        return _failed(problem, marker)


def _build_privately(command: list[str], source: bytes, name: str) -> ctypes.CDLL | KernelBuildError:
    """Compile into a temporary folder of this process's own (the cache cannot be written), load, and remove it."""
    try:
        with tempfile.TemporaryDirectory(prefix="picamcal-kernel-") as private:
            library = Path(private) / name
            message = _compile(command, source, library)
            if message is not None:
                return _failed(_compile_failure(command, message), None)
            try:
                return _open(library)  # loaded: the mapping outlives the file
            except OSError as exc:
                return _failed(_load_failure(library, exc), None)
    except (OSError, OutputError) as exc:
        return _failed(_compile_failure(command, f"error: no folder to compile in ({exc})"), None)


def c_available() -> bool:
    """Whether the C kernel can run here: loaded from the cache, or compiled into it now (under a second, once).

    Examples
    --------
    >>> c_available() in (True, False)
    True
    """
    return not isinstance(_library(), KernelBuildError)


def _address(array: np.ndarray | None) -> int | None:
    return None if array is None else array.ctypes.data


def _contiguous(array: np.ndarray, dtype: type, shape: tuple[int, ...], name: str) -> np.ndarray:
    """``array`` as a C-contiguous array of ``dtype``; ValueError if its shape is not ``shape`` (the kernel would
    read outside it)."""
    array = np.ascontiguousarray(array, dtype=dtype)
    if array.shape != shape:
        raise ValueError(f"{name} has shape {array.shape}, the kernel needs {shape}")
    return array


def _check_taps(first: np.ndarray, n_coefficients: int, name: str) -> None:
    if first.size and (first.min() < 0 or first.max() + 4 > n_coefficients):
        raise ValueError(f"{name} reach outside the {n_coefficients} spline coefficients")


def correct_c(
    bayer: np.ndarray,
    fields: CorrectionFields,
    out: np.ndarray | None = None,
    block_rows: int = C_BLOCK_ROWS,
    *,
    code_scale: float | None = None,
    table: SrgbTable | None = None,
    clipped: tuple[int, np.ndarray] | None = None,
) -> np.ndarray:
    """The fused correction with the compiled C kernel (same arithmetic as :func:`picamcal.kernels.correct_numpy`).

    The first call in a process loads the kernel (about a millisecond), or compiles it once per installation
    (under a second). It runs on :func:`picamcal.kernels.kernel_threads` threads with the GIL released; each thread
    allocates a few rows of its own; nothing else is allocated besides ``out``.

    Parameters
    ----------
    bayer : ndarray of uint16, shape (H, W)
        The raw mosaic (even H and W).
    fields : CorrectionFields
        From :func:`picamcal.correct.correction_fields`, with the image's black level.
    out : ndarray, optional
        float32 (H, W, 3), or of the codes' type with ``code_scale`` or ``table``.
    block_rows : int
        Rows per work item handed to a thread.
    code_scale, table : float or SrgbTable, optional
        Return codes instead of float32: uint16 ``round(value * code_scale)``
        (:func:`picamcal.kernels.encode_codes`; a power of two, for the codes to be those of numpy bit for bit),
        or those of ``table`` (:func:`picamcal.kernels.encode_table`).
    clipped : (level, count), optional
        Count the mosaic's samples at or above ``level`` (its white level) into ``count[0]``, an int64 array, as the
        kernel reads them (:func:`picamcal.correct.warn_if_clipped` without a pass of its own over the frame).

    Returns
    -------
    ndarray of float32, or of the codes' type, shape (H, W, 3)

    Raises
    ------
    KernelBuildError
        The kernel cannot be compiled here (no C compiler, or it failed); the message says what to do.
    ValueError
        The fields do not fit the mosaic.

    Examples
    --------
    >>> from picamcal.correct import correction_fields
    >>> from picamcal.kernels import correct_numpy
    >>> from picamcal.output.colour import srgb_encoding
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal, raw = picamcal.calibrate(**refs), refs["white"]
    >>> black = np.asarray(raw.black_level, dtype=np.float32)
    >>> fields = correction_fields(cal, "centre", raw.height, raw.width)._replace(black=black)
    >>> if c_available():  # a machine without a C compiler has numba or numpy instead
    ...     assert np.array_equal(correct_c(raw.bayer, fields), correct_numpy(raw.bayer, fields))
    ...     codes = correct_c(raw.bayer, fields, code_scale=32768)
    ...     assert np.array_equal(codes, correct_numpy(raw.bayer, fields, code_scale=32768))
    ...     srgb = srgb_encoding(bits=8)  # the sRGB outputs' uint8 codes, straight from the kernel
    ...     codes = correct_c(raw.bayer, fields, table=srgb)
    ...     assert np.array_equal(codes, correct_numpy(raw.bayer, fields, table=srgb))
    """
    library = _library()
    if isinstance(library, KernelBuildError):
        raise library
    bayer = np.ascontiguousarray(bayer, dtype=np.uint16)
    if bayer.ndim != 2 or bayer.shape[0] % 2 or bayer.shape[1] % 2 or 0 in bayer.shape:
        raise ValueError(f"the mosaic must be 2-D with even height and width, not of shape {bayer.shape}")
    if block_rows < 1:
        raise ValueError(f"block_rows must be at least 1, not {block_rows}")
    height, width = bayer.shape
    output, keep = _output(out, height, width, code_scale, table)
    black = _contiguous(fields.black, np.float32, (4,), "black")
    channels = _contiguous(fields.channels, np.int64, (4,), "channels")
    site_gains = _contiguous(fields.site_gains, np.float32, (4,), "site_gains")
    # Only the fields the kernel reads (the white's taps with a white, the matrices' with matrices), and checked: a
    # tap outside its coefficients would read outside the array.
    white = white_first = white_weights = None
    if fields.white is not None:
        white = np.ascontiguousarray(fields.white, dtype=np.float32)
        white = _contiguous(white, np.float32, (4, white.shape[1], width // 2), "white")
        white_first = _contiguous(fields.white_rows.first, np.int64, (height,), "white_rows.first")
        white_weights = _contiguous(fields.white_rows.weights, np.float32, (4, height), "white_rows.weights")
        _check_taps(white_first, white.shape[1], "white_rows.first")
    matrices = row_first = row_weights = col_first = col_weights = runs = None
    if fields.matrices is not None:
        matrices = np.ascontiguousarray(fields.matrices, dtype=np.float32)
        matrices = _contiguous(matrices, np.float32, (9, *matrices.shape[1:]), "matrices")
        row_first = _contiguous(fields.matrix_rows.first, np.int64, (height,), "matrix_rows.first")
        row_weights = _contiguous(fields.matrix_rows.weights, np.float32, (4, height), "matrix_rows.weights")
        col_first = _contiguous(fields.matrix_cols.first, np.int64, (width,), "matrix_cols.first")
        col_weights = _contiguous(fields.matrix_cols.weights, np.float32, (4, width), "matrix_cols.weights")
        runs = np.ascontiguousarray(fields.matrix_cols.runs, dtype=np.uint64)
        _check_taps(row_first, matrices.shape[1], "matrix_rows.first")
        _check_taps(col_first, matrices.shape[2], "matrix_cols.first")
        if runs.ndim != 1 or runs.size < 2 or runs[0] != 0 or runs[-1] != width or np.any(runs[1:] < runs[:-1]):
            raise ValueError(f"matrix_cols.runs must rise from 0 to the width {width}")
    job = _Job(
        bayer=_address(bayer),
        height=height,
        width=width,
        black=_address(black),
        channels=_address(channels),
        site_gains=_address(site_gains),
        white=_address(white),
        white_ny=0 if white is None else white.shape[1],
        white_first=_address(white_first),
        white_weights=_address(white_weights),
        matrices=_address(matrices),
        matrix_ny=0 if matrices is None else matrices.shape[1],
        matrix_nx=0 if matrices is None else matrices.shape[2],
        matrix_row_first=_address(row_first),
        matrix_row_weights=_address(row_weights),
        matrix_col_first=_address(col_first),
        matrix_col_weights=_address(col_weights),
        matrix_runs=_address(runs),
        n_runs=0 if runs is None else runs.size - 1,
        output=output,
        block_rows=block_rows,
        threads=kernel_threads(),
        clip_level=65536 if clipped is None else min(max(int(clipped[0]), 0), 65536),
    )
    if library.picamcal_correct(ctypes.byref(job)) != 0:
        raise MemoryError("the C kernel's threads could not allocate their rows")
    if clipped is not None:
        clipped[1][0] = job.clipped
    return keep[0]


def _output(
    out: np.ndarray | None, height: int, width: int, code_scale: float | None, table: SrgbTable | None
) -> tuple[_Output, tuple[np.ndarray, ...]]:
    """``picamcal_output`` for ``out`` (:func:`picamcal.kernels.output_array`), and the arrays it points into
    (``out`` first), to be kept alive while the kernel runs; ValueError for a table the kernel would misread."""
    if table is None:
        array = output_array(out, height, width, np.float32 if code_scale is None else np.uint16)
        output = _Output(_address(array), _KINDS["float32" if code_scale is None else "scaled"], code_scale or 0.0)
        return output, (array,)
    if code_scale is not None:
        raise ValueError("codes are either scaled (code_scale) or from a table, not both")
    base, inside = np.ascontiguousarray(table.base), np.ascontiguousarray(table.inside, dtype=np.float32)
    matrix = np.asarray(table.matrix, dtype=np.float32)
    cells = base.size - 1
    if base.dtype not in (np.uint8, np.uint16) or base.ndim != 1 or cells < 1 or inside.shape != base.shape:
        raise ValueError("an sRGB table's base is uint8 or uint16 (cells + 1,), and its inside float32 of that shape")
    if cells & (cells - 1) or matrix.shape != (3, 3) or not np.isfinite(matrix).all():
        raise ValueError("an sRGB table has a power of two of cells and a finite 3x3 matrix")
    codes = output_array(out, height, width, base.dtype)
    elements = (ctypes.c_float * 9)(*matrix.ravel().tolist())
    output = _Output(_address(codes), _KINDS[base.dtype.name], 0.0, elements, _address(base), _address(inside), cells)
    return output, (codes, base, inside)


def encode_c(
    rgb: np.ndarray,
    out: np.ndarray | None = None,
    *,
    code_scale: float | None = None,
    table: SrgbTable | None = None,
    block_rows: int = ENCODE_BLOCK_ROWS,
    threads: int | None = None,
) -> np.ndarray:
    """A float32 (H, W, 3) image's codes with the compiled library, on ``threads`` threads (None:
    :func:`picamcal.kernels.kernel_threads`): those the kernel writes (:func:`correct_c`), bit for bit.

    Parameters
    ----------
    rgb : ndarray of float32, shape (H, W, 3)
    out : ndarray, optional
        Of the codes' type, (H, W, 3).
    code_scale, table : float or SrgbTable
        uint16 ``round(value * code_scale)`` (:func:`picamcal.kernels.encode_codes`), or the codes of ``table``
        (:func:`picamcal.kernels.encode_table`): one of them.
    block_rows : int
        Rows per work item handed to a thread.
    threads : int, optional
        1 for a caller that runs its own threads (each converting a strip of an image).

    Raises
    ------
    KernelBuildError
        The library cannot be compiled here.

    Examples
    --------
    >>> if c_available():
    ...     print(encode_c(np.array([[[1.0, 0.5, np.nan]]], np.float32), code_scale=32768).ravel())
    ... else:
    ...     print(np.array([32768, 16384, 0], np.uint16))
    [32768 16384     0]
    """
    library = _library()
    if isinstance(library, KernelBuildError):
        raise library
    if code_scale is None and table is None:
        raise ValueError("encode_c makes codes: give code_scale or table")
    if block_rows < 1 or (threads is not None and threads < 1):
        raise ValueError(f"block_rows and threads must be at least 1, not {block_rows} and {threads}")
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"an image to encode is (H, W, 3), not {rgb.shape}")
    height, width = rgb.shape[:2]
    output, keep = _output(out, height, width, code_scale, table)
    job = _EncodeJob(_address(rgb), height, width, output, block_rows, threads or kernel_threads())
    library.picamcal_encode(ctypes.byref(job))
    return keep[0]


def encode_image(
    rgb: np.ndarray,
    out: np.ndarray | None = None,
    *,
    code_scale: float | None = None,
    table: SrgbTable | None = None,
    engine: str = "auto",
) -> np.ndarray:
    """A corrected float image's codes, as the correction kernels write them: with the C library, else numba's
    parallel loop, else numpy strip by strip (``engine="auto"``, as :func:`picamcal.correct.correct` picks).

    A float32 image gives the codes the kernel writes, bit for bit; another float type is rounded to float32 a
    strip of rows at a time (no full-size copy).

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3)
        Linear RGB, the white reference at 1.0.
    out : ndarray, optional
        Of the codes' type, (H, W, 3).
    code_scale, table : float or SrgbTable
        uint16 ``round(value * code_scale)`` (:func:`picamcal.kernels.encode_codes`; ``uint16-tiff``'s with
        :data:`picamcal.correct.UINT16_WHITE`), or the codes of ``table``
        (:func:`picamcal.kernels.encode_table`; the sRGB formats' with :func:`picamcal.output.colour.srgb_encoding`).
    engine : {"auto", "c", "numba", "numpy"}

    Returns
    -------
    ndarray of uint16, or of the table's codes, shape (H, W, 3)

    Examples
    --------
    >>> rgb = np.array([[[1.0, 0.5, 2.5]]], np.float32)
    >>> encode_image(rgb, code_scale=32768).ravel()
    array([32768, 16384, 65535], dtype=uint16)
    >>> from picamcal.output.colour import srgb_encoding
    >>> encode_image(rgb, table=srgb_encoding(bits=8), engine="numpy").ravel()
    array([231, 170, 255], dtype=uint8)
    """
    if engine not in ENCODE_ENGINES:
        raise ValueError(f"unknown engine {engine!r}: choose one of {', '.join(ENCODE_ENGINES)}")
    if (code_scale is None) == (table is None):
        raise ValueError("give either code_scale or table")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"an image to encode is (H, W, 3), not {rgb.shape}")
    height, width = rgb.shape[:2]
    out = output_array(out, height, width, np.uint16 if table is None else table.base.dtype)
    if rgb.dtype != np.float32 or not rgb.flags.c_contiguous:  # float32 strips of about a megapixel
        step = max(1, (1 << 20) // max(1, width))
        for y in range(0, height, step):
            strip = np.ascontiguousarray(rgb[y : y + step], dtype=np.float32)
            encode_image(strip, out[y : y + step], code_scale=code_scale, table=table, engine=engine)
        return out
    if engine in ("auto", "c"):
        try:
            return encode_c(rgb, out, code_scale=code_scale, table=table)
        except KernelBuildError:
            if engine == "c":
                raise
    if engine == "numba" or (engine == "auto" and numba_available()):
        try:
            return encode_numba(rgb, out, code_scale=code_scale, table=table)
        except ImportError:
            if engine == "numba":
                raise
    step = max(1, (1 << 20) // max(1, width))  # numpy's temporaries: a strip of rows at a time
    for y in range(0, height, step):
        if table is None:
            encode_codes(rgb[y : y + step], code_scale or 0.0, out[y : y + step])
        else:
            encode_table(rgb[y : y + step], table, out[y : y + step])
    return out
