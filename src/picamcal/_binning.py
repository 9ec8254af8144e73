"""A one-pass numba kernel for Bayer binning, used by :func:`picamcal.bayer.bin_sites` when numba is installed.

numba is optional (32-bit Raspberry Pi OS has no wheels); without it the numpy path in ``bayer`` runs.
"""

from __future__ import annotations

import numpy as np

try:
    from numba import njit, prange

    _HAS_NUMBA = True
except ImportError:  # pragma: no cover - exercised where numba is absent
    _HAS_NUMBA = False


if _HAS_NUMBA:

    @njit(parallel=True, cache=True)
    def _site_sums(mosaic: np.ndarray, bin_size: int, nby: int, nbx: int) -> np.ndarray:  # pragma: no cover
        height, width = mosaic.shape
        sums = np.zeros((nby, nbx, 4), dtype=np.float64)
        for by in prange(nby):  # each thread owns whole rows of bins: no two write the same sum
            for y in range(by * bin_size, min(height, (by + 1) * bin_size)):
                site_row = 2 * (y & 1)
                for x in range(width):
                    sums[by, x // bin_size, site_row + (x & 1)] += mosaic[y, x]
        return sums


def site_sums(mosaic: np.ndarray, bin_size: int, nby: int, nbx: int) -> np.ndarray | None:
    """Per-bin, per-site sums of a mosaic in one pass, or None when numba is not installed."""
    if not _HAS_NUMBA:
        return None
    return _site_sums(np.ascontiguousarray(mosaic), bin_size, nby, nbx)
