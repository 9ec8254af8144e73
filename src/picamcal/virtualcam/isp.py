"""The virtual camera's ISP: the raw stream's bytes as each platform writes them, and the processed streams.

Raw buffers (libcamera ``pipeline/rpi/vc4/vc4.cpp`` and ``pisp/pisp.cpp`` ``platformValidate``; the layouts in
:mod:`picamcal.raw.picamera2`):

- Pi 4 (``vc4``): unpacked ``S<order><bits>`` holds the sensor's value in the low bits of a little-endian 16-bit
  word (one byte at 8 bits); ``_CSI2P`` is MIPI CSI-2 packed (:func:`picamcal.raw.packing.pack`);
- Pi 5 (``pisp``): ``S<order>16`` holds the value scaled to 16 bits; ``<order>_PISP_COMP1`` is that, compressed
  (:func:`picamcal.raw.picamera2.pisp.pisp_compress`).

Processed streams follow the Pi ISP's order with picamcal's emulation of the tuning file (:mod:`picamcal.export.isp`):
black level (``rpi.black_level``), the static lens shading tables (``rpi.alsc``, at the white balance's colour
temperature; the adaptive part of ALSC is not emulated), the colour gains and digital gain, demosaicing (each 2x2
Bayer quad is one RGB sample, so outputs larger than half the mode are blockier than a Pi's), the crop and scaling
to the output size (nearest sample), the colour matrix (``rpi.ccm``), the gamma curve (``rpi.contrast``) and the
output format: RGB888 (B, G, R in memory), BGR888 (R, G, B), XRGB8888 (B, G, R, 255), XBGR8888 (R, G, B, 255),
RGB161616/BGR161616 (the same orders, 16 bits per channel; Pi 5 only), YUV420/YVU420 (planar) and NV12/NV21, in the
stream's colour space (full-range sYCC, limited-range SMPTE 170M or
Rec.709).

Examples
--------
>>> gamma = gamma_table(None)
>>> int(gamma[0]), int(gamma[-1])
(0, 255)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..export.isp import channel_tables, table_to_pixels
from ..geometry import SensorMode
from ..raw.model import site_channels
from ..raw.packing import pack, packed_row_bytes
from ..raw.picamera2.pisp import pisp_compress
from .timing import row_blocks

#: Y'CbCr luma coefficients (Kr, Kb) by encoding.
_LUMA = {"Rec601": (0.299, 0.114), "Rec709": (0.2126, 0.0722), "Rec2020": (0.2627, 0.0593)}


@dataclass(frozen=True)
class Layout:
    """A configured stream's buffer: format name, size, stride and frame size in bytes."""

    format: str
    width: int
    height: int
    stride: int
    frame_size: int


def encode_raw(frame: np.ndarray, layout: Layout, bits: int, dest: np.ndarray) -> None:
    """Write a raw frame (uint16 at ``bits`` bits) into ``dest`` (uint8, height x stride) in the layout's format.

    Examples
    --------
    >>> frame = np.array([[100, 200, 300, 400]], dtype=np.uint16)
    >>> dest = np.zeros((1, 32), np.uint8)
    >>> encode_raw(frame, Layout("SRGGB10", 4, 1, 32, 32), 10, dest)
    >>> dest[0, :8].view("<u2").tolist()
    [100, 200, 300, 400]
    >>> encode_raw(frame, Layout("SRGGB16", 4, 1, 32, 32), 10, dest)
    >>> dest[0, :8].view("<u2").tolist()
    [6400, 12800, 19200, 25600]
    """
    name, height, width = layout.format, layout.height, layout.width
    if name.endswith("_PISP_COMP1"):

        def compress(a: int, b: int) -> None:
            pisp_compress(frame[a:b], shift=16 - bits, out=dest[a:b])

        row_blocks("raw stream", compress, height)
    elif name.endswith("_CSI2P"):
        kernel = _compiled_pack() if bits in (10, 12) else None
        if kernel is None:
            dest[:] = pack(frame, bits, layout.stride)
        elif dest.shape[1] < (need := packed_row_bytes(width, bits)):  # the kernel would write past the buffer
            raise ValueError(f"stride {dest.shape[1]} is shorter than the {need} bytes of a row")
        else:
            row_blocks("raw stream", lambda a, b: kernel(frame[a:b], bits, dest[a:b]), height)
    elif name.endswith("16"):
        dest[:, : 2 * width].view("<u2")[:] = frame << (16 - bits) if bits < 16 else frame
    elif bits == 8:
        dest[:, :width] = frame
    else:
        dest[:, : 2 * width].view("<u2")[:] = frame


def gamma_table(curve: tuple[np.ndarray, np.ndarray] | None, size: int = 4096) -> np.ndarray:
    """An 8-bit lookup table of ``size`` entries over linear 0..1: the tuning's gamma curve, else sRGB's."""
    x = np.linspace(0.0, 1.0, size)
    if curve is None:
        y = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    else:
        y = np.interp(x, curve[0], curve[1])
    return np.clip(np.rint(y * 255.0), 0, 255).astype(np.uint8)


@dataclass
class OutputPlan:
    """How one processed stream samples the mode: its layout, colour space and the quad indices of its pixels.

    The distinct rows and columns are processed once each (an output larger than the quads repeats them).
    """

    layout: Layout
    colour_space: Any
    rows: np.ndarray
    cols: np.ndarray

    def __post_init__(self) -> None:
        self.unique_rows, self.row_index = np.unique(self.rows, return_inverse=True)
        self.unique_cols, self.col_index = np.unique(self.cols, return_inverse=True)
        self.repeats = len(self.unique_rows) < len(self.rows) or len(self.unique_cols) < len(self.cols)


def sample_indices(crop: tuple[int, int, int, int], width: int, height: int, quads: tuple[int, int]) -> tuple:
    """Quad rows and columns (into the mode's half-size RGB) of an output of ``width`` x ``height`` showing ``crop``
    (x, y, w, h in mode pixels), nearest sample.

    Examples
    --------
    >>> rows, cols = sample_indices((0, 0, 8, 4), 4, 2, (4, 2))
    >>> rows.tolist(), cols.tolist()
    ([0, 1], [0, 1, 2, 3])
    """
    x, y, w, h = crop
    qw, qh = quads
    cols = np.floor((x + (np.arange(width) + 0.5) * w / width) / 2).astype(np.intp).clip(0, qw - 1)
    rows = np.floor((y + (np.arange(height) + 0.5) * h / height) / 2).astype(np.intp).clip(0, qh - 1)
    return rows, cols


class Isp:
    """The processing of one configured camera: lens shading tables for the mode, and the outputs' sampling.

    Parameters
    ----------
    tuning : dict
        The tuning file in force.
    mode : SensorMode
        Where the mode lies on the sensor (for the lens shading tables) and its user flips.
    order : str
        Bayer order of the raw frames.
    bits : int
        The mode's bit depth.
    black_level : float
        ``rpi.black_level`` on the 16-bit scale.
    gamma : (x, y) or None
        The tuning's gamma curve.
    """

    def __init__(
        self,
        tuning: dict[str, Any],
        mode: SensorMode,
        order: str,
        bits: int,
        black_level: float,
        gamma: tuple[np.ndarray, np.ndarray] | None,
    ) -> None:
        self.tuning, self.mode, self.order, self.bits = tuning, mode, order, bits
        self.black = float(black_level) * 2.0 ** (bits - 16)
        self.white = float((1 << bits) - 1)
        self.gamma = gamma_table(gamma)
        self.channels = [int(c) for c in site_channels(order)]
        # (colour temperature bucket, gains) in one attribute: the sensor's and the ISP's stages, in threads of their
        # own, never see one's bucket with the other's gains.
        self._lsc: tuple[float, np.ndarray] | None = None
        self.has_alsc = any("rpi.alsc" in a for a in tuning.get("algorithms", []))

    def lens_shading(self, ct: float) -> np.ndarray:
        """Per-site gains at the quads (4, height / 2, width / 2), recomputed when the colour temperature moves."""
        bucket = round(ct / 50.0) * 50.0
        cached = self._lsc
        if cached is not None and cached[0] == bucket:
            return cached[1]
        mode = self.mode
        qh, qw = mode.height // 2, mode.width // 2
        gains = np.ones((4, qh, qw), dtype=np.float32)
        if self.has_alsc:
            target = self.tuning.get("target", "bcm2835")
            tables = channel_tables(self.tuning, mode, bucket)
            py, px = table_to_pixels(target, mode.width, mode.height)
            for site, channel in enumerate(self.channels):
                sy, sx = divmod(site, 2)
                gains[site] = (py[sy::2][:qh] @ tables[channel] @ px[sx::2][:qw].T).astype(np.float32)
        self._lsc = (bucket, gains)
        return gains

    def linear_planes(self, frame: np.ndarray, ct: float) -> list[np.ndarray]:
        """The four Bayer sites of a raw frame, black subtracted, lens shading applied, on 0..1 (quad size): what
        :meth:`render` samples (the compiled render takes the quads it needs straight from the raw frame)."""
        gains = self.lens_shading(ct)
        return [self._site_values(frame, site, gains) for site in range(4)]

    def _site_values(self, frame: np.ndarray, site: int, gains: np.ndarray, step: int = 1) -> np.ndarray:
        """One Bayer site's values at every ``step``-th quad, black subtracted, lens shading applied, on 0..1 (numpy;
        the compiled planes kernel does the same float32 operations in the same order)."""
        sy, sx = divmod(site, 2)
        quads_h, quads_w = gains.shape[1:]
        values = frame[sy : 2 * quads_h : 2 * step, sx : 2 * quads_w : 2 * step].astype(np.float32)
        values -= np.float32(self.black)
        values *= gains[site, ::step, ::step]
        values *= np.float32(1.0 / (self.white - self.black))
        return values

    def statistics(self, frame: np.ndarray, ct: float) -> tuple[float, float, float]:
        """The frame's mean red, green and blue (the statistics the AGC and AWB see), from a coarse grid of the raw
        frame: the values :meth:`linear_planes` gives there, clipped to 0..1 (the same float32 arithmetic).

        They are taken from the raw frame, as the Pi 5's front end does, so that the IPA can run on a frame before
        the ISP has processed it.
        """
        gains = self.lens_shading(ct)
        step = max(1, min(gains.shape[1:]) // 64)
        sums = [0.0, 0.0, 0.0]
        counts = [0, 0, 0]
        for site, channel in enumerate(self.channels):
            sums[channel] += float(np.clip(self._site_values(frame, site, gains, step), 0, 1).mean())
            counts[channel] += 1
        return (sums[0] / counts[0], sums[1] / counts[1], sums[2] / counts[2])

    def render(
        self,
        frame: np.ndarray,
        ct: float,
        plan: OutputPlan,
        gains: tuple[float, float],
        digital_gain: float,
        ccm: np.ndarray,
        dest: np.ndarray,
    ) -> None:
        """Write one processed stream of a raw frame into ``dest`` (uint8, the buffer's bytes).

        Only the quads the output samples are developed (:meth:`linear_planes`' arithmetic at those quads). With
        numba, each distinct output row is made once from the raw frame and written straight into the buffer at the
        output's size (the rows that repeat it copied), with no frame-sized temporary between the stages.
        """
        layout = plan.layout
        weights = (np.float32(gains[0] * digital_gain), np.float32(digital_gain), np.float32(gains[1] * digital_gain))
        green_sites = [s for s, c in enumerate(self.channels) if c == 1]
        sites = (self.channels.index(0), green_sites[0], green_sites[-1], self.channels.index(2))
        matrix = ccm.astype(np.float32)
        lsc = self.lens_shading(ct)
        kernel = _compiled_render()
        if kernel is None:
            encoded = self._encode(frame, lsc, plan, weights, sites, matrix)
        else:
            develop = functools.partial(
                kernel, frame, np.float32(self.black), lsc, np.float32(1.0 / (self.white - self.black)),
                np.array(sites, np.intp), plan.unique_rows,
            )  # fmt: skip
            factors = np.array(weights, np.float32)
            direct = _direct_rows(layout, dest)
            if direct is not None:
                rows, order = direct
                cols, index = plan.unique_cols, plan.col_index
                row_blocks(
                    "ISP render",
                    lambda a, b: develop(
                        plan.row_index[a:b], cols, index, factors, matrix, self.gamma, order, rows[a:b]
                    ),
                    layout.height,
                )
                return
            encoded = np.empty((len(plan.unique_rows), len(plan.unique_cols), 3), dtype=np.uint8)
            flat = encoded.reshape(len(encoded), -1)
            distinct, rgb = np.arange(len(plan.unique_cols)), np.arange(3)
            row_blocks(
                "ISP render",
                lambda a, b: develop(
                    np.arange(a, b), plan.unique_cols, distinct, factors, matrix, self.gamma, rgb, flat[a:b]
                ),
                len(encoded),
            )
        if plan.repeats:
            write_output(encoded, layout, plan.colour_space, dest, (plan.row_index, plan.col_index))
        else:
            write_output(encoded, layout, plan.colour_space, dest)

    def _encode(
        self,
        frame: np.ndarray,
        lsc: np.ndarray,
        plan: OutputPlan,
        weights: tuple,
        sites: tuple[int, int, int, int],
        matrix: np.ndarray,
    ) -> np.ndarray:
        """The gamma-encoded RGB at the plan's distinct rows and columns (numpy)."""
        rows, cols = plan.unique_rows, plan.unique_cols
        red, green, green2, blue = (self._site_samples(frame, site, lsc, rows, cols) for site in sites)
        green += green2
        green *= np.float32(0.5)
        channels = [red, green, blue]
        for channel in range(3):
            channels[channel] *= weights[channel]
        encoded = np.empty((*red.shape, 3), dtype=np.uint8)
        top = np.float32(len(self.gamma) - 1)
        for out in range(3):
            mixed = channels[0] * matrix[out, 0]
            mixed += channels[1] * matrix[out, 1]
            mixed += channels[2] * matrix[out, 2]
            np.clip(mixed, 0.0, 1.0, out=mixed)
            mixed *= top
            encoded[..., out] = self.gamma[mixed.astype(np.intp)]
        return encoded

    def _site_samples(
        self, frame: np.ndarray, site: int, gains: np.ndarray, rows: np.ndarray, cols: np.ndarray
    ) -> np.ndarray:
        """One Bayer site's values at the quads ``rows`` x ``cols``: :meth:`_site_values` there (numpy)."""
        sy, sx = divmod(site, 2)
        values = frame[2 * rows + sy][:, 2 * cols + sx].astype(np.float32)
        values -= np.float32(self.black)
        values *= gains[site][rows][:, cols]
        values *= np.float32(1.0 / (self.white - self.black))
        return values


def write_output(
    rgb: np.ndarray, layout: Layout, colour_space: Any, dest: np.ndarray, expand: tuple[Any, Any] | None = None
) -> None:
    """Write gamma-encoded RGB (uint8, H x W x 3) into a buffer of the layout's format.

    ``expand`` gives the rows and columns of ``rgb`` each output pixel takes (an output larger than ``rgb``); the
    colour conversion is done before, on ``rgb``, and chroma is subsampled by taking every other sample.

    Examples
    --------
    >>> rgb = np.array([[[255, 128, 0]]], dtype=np.uint8)
    >>> dest = np.zeros((1, 4), np.uint8)
    >>> write_output(rgb, Layout("RGB888", 1, 1, 4, 4), None, dest)
    >>> dest[0, :3].tolist()  # B, G, R in memory
    [0, 128, 255]
    """
    name, width, height, stride = layout.format, layout.width, layout.height, layout.stride
    flat = dest.reshape(-1)
    rows, cols = expand if expand is not None else (np.arange(height), np.arange(width))
    if "161616" in name:  # 16 bits per channel: the 8-bit values scaled to the full range
        out16 = flat[: stride * height].reshape(height, stride)[:, : width * 6].view("<u2").reshape(height, width, 3)
        source = rgb[..., [2, 1, 0] if name == "RGB161616" else [0, 1, 2]].astype(np.uint16) * np.uint16(257)
        out16[:] = source[rows][:, cols] if expand is not None else source
        return
    if name in ("RGB888", "BGR888", "XRGB8888", "XBGR8888"):
        channels = 4 if name.startswith("X") else 3
        out = flat[: stride * height].reshape(height, stride)[:, : width * channels].reshape(height, width, channels)
        order = [2, 1, 0] if name in ("RGB888", "XRGB8888") else [0, 1, 2]
        source = rgb[..., order]
        out[..., :3] = source[rows][:, cols] if expand is not None else source
        if channels == 4:
            out[..., 3] = 255
        return
    y, cb, cr = _ycbcr(rgb, colour_space)
    luma = flat[: stride * height].reshape(height, stride)
    luma[:, :width] = y[rows][:, cols] if expand is not None else y
    half_h, half_w = height // 2, width // 2
    if expand is not None:  # each 2x2 block's chroma from its top-left sample
        chroma_rows, chroma_cols = rows[0 : 2 * half_h : 2], cols[0 : 2 * half_w : 2]
        cb, cr = cb[chroma_rows][:, chroma_cols], cr[chroma_rows][:, chroma_cols]
    else:
        cb = cb[: half_h * 2, : half_w * 2].reshape(half_h, 2, half_w, 2).mean(axis=(1, 3))
        cr = cr[: half_h * 2, : half_w * 2].reshape(half_h, 2, half_w, 2).mean(axis=(1, 3))
    cb8, cr8 = (np.clip(np.rint(c), 0, 255).astype(np.uint8) for c in (cb, cr))
    base = stride * height
    if name in ("YUV420", "YVU420"):
        chroma_stride = stride // 2
        first, second = (cb8, cr8) if name == "YUV420" else (cr8, cb8)
        size = chroma_stride * half_h
        flat[base : base + size].reshape(half_h, chroma_stride)[:, :half_w] = first
        flat[base + size : base + 2 * size].reshape(half_h, chroma_stride)[:, :half_w] = second
    else:  # NV12 / NV21: one plane of interleaved chroma
        plane = flat[base : base + stride * half_h].reshape(half_h, stride)[:, : 2 * half_w].reshape(half_h, half_w, 2)
        plane[..., 0], plane[..., 1] = (cb8, cr8) if name == "NV12" else (cr8, cb8)


def _ycbcr(rgb: np.ndarray, colour_space: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Y'CbCr of gamma-encoded RGB in the stream's colour space: luma as uint8, chroma as float (0..255)."""
    encoding = getattr(getattr(colour_space, "ycbcrEncoding", None), "name", "Rec601")
    limited = getattr(getattr(colour_space, "range", None), "name", "Full") == "Limited"
    kr, kb = _LUMA.get(encoding, _LUMA["Rec601"])
    values = rgb.astype(np.float32) / np.float32(255.0)
    r, g, b = values[..., 0], values[..., 1], values[..., 2]
    y = kr * r + (1 - kr - kb) * g + kb * b
    cb = (b - y) / (2 * (1 - kb))
    cr = (r - y) / (2 * (1 - kr))
    if limited:
        y8 = 16 + 219 * y
        cb, cr = 128 + 224 * cb, 128 + 224 * cr
    else:
        y8 = 255 * y
        cb, cr = 128 + 255 * cb, 128 + 255 * cr
    return np.clip(np.rint(y8), 0, 255).astype(np.uint8), cb, cr


def _direct_rows(layout: Layout, dest: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The rows of an RGB format's buffer as the compiled render writes them, and the channel of each byte of a
    pixel: 32-bit words for the formats of 4 bytes a pixel, 16-bit values for the 48-bit ones, else bytes (None for
    the Y'CbCr formats, written by numpy)."""
    name, width, height, stride = layout.format, layout.width, layout.height, layout.stride
    rows = dest.reshape(-1)[: stride * height].reshape(height, stride)
    if "161616" in name:
        rows = rows[:, : 6 * width].view("<u2")
    elif name in ("XRGB8888", "XBGR8888"):
        rows = rows[:, : 4 * width].view("<u4")
    elif name in ("RGB888", "BGR888"):
        rows = rows[:, : 3 * width]
    else:
        return None
    return rows, np.array([2, 1, 0] if name.startswith(("RGB", "XRGB")) else [0, 1, 2], dtype=np.intp)


def _render_loop(  # pragma: no cover - compiled by numba
    frame: np.ndarray,
    black: np.float32,
    lsc: np.ndarray,
    scale: np.float32,
    sites: np.ndarray,
    rows: np.ndarray,
    row_index: np.ndarray,
    cols: np.ndarray,
    col_index: np.ndarray,
    weights: np.ndarray,
    matrix: np.ndarray,
    gamma: np.ndarray,
    order: np.ndarray,
    out: np.ndarray,
) -> None:
    """:meth:`Isp.render` of some output rows (for numba): :meth:`Isp._encode`'s float32 arithmetic, from the raw
    frame to the output's pixels.

    Output row ``i`` shows quad row ``rows[row_index[i]]``; pixel ``j`` of it quad column ``cols[col_index[j]]``;
    byte (or 16-bit value) ``k`` of a pixel is channel ``order[k]``. ``out`` holds the rows as 32-bit words (a pixel
    of 4 bytes, the fourth 255), 16-bit values (three a pixel, the 8-bit codes times 257) or bytes (three a pixel).
    A row that shows the same quads as the one before is copied. Each distinct row's samples are developed in loops
    of their own, which the compiler vectorises, and then gathered into the pixels.
    """
    top = np.float32(len(gamma) - 1)
    zero, one, half = np.float32(0.0), np.float32(1.0), np.float32(0.5)
    n, width = len(cols), len(col_index)
    r, g, b = np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.float32)
    index = np.empty((3, n), np.int32)
    words = np.empty(n, np.uint32)
    pixels = np.empty((n, 3), np.uint8)  # a sample's bytes (or 16-bit values' codes) in memory order
    scaled = 257 if out.itemsize == 2 else 1
    shift_r = shift_g = shift_b = np.uint32(0)  # of each channel's byte in a 32-bit pixel
    for k in range(3):
        if order[k] == 0:
            shift_r = np.uint32(8 * k)
        elif order[k] == 1:
            shift_g = np.uint32(8 * k)
        else:
            shift_b = np.uint32(8 * k)
    weight_r, weight_g, weight_b = weights[0], weights[1], weights[2]
    red_y, red_x = divmod(sites[0], 2)
    green_y, green_x = divmod(sites[1], 2)
    green2_y, green2_x = divmod(sites[2], 2)
    blue_y, blue_x = divmod(sites[3], 2)
    contiguous = n > 0 and cols[n - 1] - cols[0] == n - 1  # cols are sorted and distinct
    last = -1
    for i in range(len(row_index)):
        line = out[i]
        if row_index[i] == last:
            line[:] = out[i - 1]
            continue
        last = row_index[i]
        y = rows[last]
        row_r, row_g, row_g2, row_b = (
            frame[2 * y + red_y],
            frame[2 * y + green_y],
            frame[2 * y + green2_y],
            frame[2 * y + blue_y],
        )
        gain_r, gain_g, gain_g2, gain_b = lsc[sites[0], y], lsc[sites[1], y], lsc[sites[2], y], lsc[sites[3], y]
        if contiguous:  # the same arithmetic on a run of quads, which the compiler vectorises
            c = cols[0]
            raw_r, raw_g = row_r[2 * c + red_x :], row_g[2 * c + green_x :]
            raw_g2, raw_b = row_g2[2 * c + green2_x :], row_b[2 * c + blue_x :]
            run_r, run_g, run_g2, run_b = gain_r[c:], gain_g[c:], gain_g2[c:], gain_b[c:]
            for j in range(n):
                r[j] = (np.float32(raw_r[2 * j]) - black) * run_r[j] * scale * weight_r
                green = (np.float32(raw_g[2 * j]) - black) * run_g[j] * scale
                green2 = (np.float32(raw_g2[2 * j]) - black) * run_g2[j] * scale
                g[j] = (green + green2) * half * weight_g
                b[j] = (np.float32(raw_b[2 * j]) - black) * run_b[j] * scale * weight_b
        else:
            for j in range(n):
                x = cols[j]
                r[j] = (np.float32(row_r[2 * x + red_x]) - black) * gain_r[x] * scale * weight_r
                green = (np.float32(row_g[2 * x + green_x]) - black) * gain_g[x] * scale
                green2 = (np.float32(row_g2[2 * x + green2_x]) - black) * gain_g2[x] * scale
                g[j] = (green + green2) * half * weight_g
                b[j] = (np.float32(row_b[2 * x + blue_x]) - black) * gain_b[x] * scale * weight_b
        for k in range(3):
            m0, m1, m2 = matrix[k, 0], matrix[k, 1], matrix[k, 2]
            codes = index[k]
            for j in range(n):
                codes[j] = np.int32(min(max(r[j] * m0 + g[j] * m1 + b[j] * m2, zero), one) * top)
        if out.itemsize == 4:
            for j in range(n):
                words[j] = (
                    (np.uint32(gamma[index[0, j]]) << shift_r)
                    | (np.uint32(gamma[index[1, j]]) << shift_g)
                    | (np.uint32(gamma[index[2, j]]) << shift_b)
                    | np.uint32(0xFF000000)
                )
            for j in range(width):
                line[j] = words[col_index[j]]
        else:
            for k in range(3):
                codes = index[order[k]]
                for j in range(n):
                    pixels[j, k] = gamma[codes[j]]
            for j in range(width):
                x = col_index[j]
                line[3 * j] = pixels[x, 0] * scaled
                line[3 * j + 1] = pixels[x, 1] * scaled
                line[3 * j + 2] = pixels[x, 2] * scaled


def _pack_loop(frame: np.ndarray, bits: int, out: np.ndarray) -> None:  # pragma: no cover - compiled by numba
    """:func:`picamcal.raw.packing.pack` into ``out`` (height x stride) in one pass, at 10 or 12 bits.

    The whole groups of a row (4 pixels in 5 bytes at 10 bits, 2 in 3 at 12) go through a loop of their own, with
    the shifts fixed, which the compiler vectorises; a group the row's end cuts short is padded with zeros.
    """
    height, width = frame.shape
    pixels = 4 if bits == 10 else 2
    nbytes = pixels + 1
    whole, groups = width // pixels, (width + pixels - 1) // pixels
    for y in range(height):
        row, dest = frame[y], out[y]
        if bits == 10:
            for group in range(whole):
                a, b = row[4 * group], row[4 * group + 1]
                c, d = row[4 * group + 2], row[4 * group + 3]
                at = 5 * group
                dest[at] = np.uint8(a >> 2)
                dest[at + 1] = np.uint8(b >> 2)
                dest[at + 2] = np.uint8(c >> 2)
                dest[at + 3] = np.uint8(d >> 2)
                dest[at + 4] = np.uint8((a & 3) | (b & 3) << 2 | (c & 3) << 4 | (d & 3) << 6)
        else:
            for group in range(whole):
                a, b = row[2 * group], row[2 * group + 1]
                at = 3 * group
                dest[at] = np.uint8(a >> 4)
                dest[at + 1] = np.uint8(b >> 4)
                dest[at + 2] = np.uint8((a & 15) | (b & 15) << 4)
        for group in range(whole, groups):
            low = 0
            for k in range(pixels):
                x = group * pixels + k
                value = int(row[x]) if x < width else 0
                dest[group * nbytes + k] = value >> (bits - 8)
                low |= (value & ((1 << (bits - 8)) - 1)) << ((bits - 8) * k)
            dest[group * nbytes + pixels] = low
        for i in range(groups * nbytes, len(dest)):
            dest[i] = 0


@functools.cache
def _compiled_render() -> Any:
    """:func:`_render_loop` compiled by numba (cached on disk), or None without numba."""
    try:
        import numba
    except ImportError:
        return None
    return numba.njit(cache=True, nogil=True, error_model="numpy")(_render_loop)


@functools.cache
def _compiled_pack() -> Any:
    """:func:`_pack_loop` compiled by numba (cached on disk), or None without numba."""
    try:
        import numba
    except ImportError:
        return None
    return numba.njit(cache=True, nogil=True)(_pack_loop)
