"""Shared fixtures: a small, exactly known linear sensor model that needs no simulator."""

from __future__ import annotations

import numpy as np
import pytest

from picamcal.raw import RawImage, site_channels

SPECTRAL = np.array([[0.90, 0.10, 0.02], [0.08, 0.85, 0.12], [0.02, 0.12, 0.88]])


def linear_mixing(height: int, width: int, pattern: str) -> np.ndarray:
    """A smooth per-pixel mixing field (H, W, 3 primaries): vignetting plus crosstalk growing with radius."""
    y, x = np.mgrid[0:height, 0:width]
    r2 = ((x - (width - 1) / 2) ** 2 + (y - (height - 1) / 2) ** 2) / (width / 2) ** 2
    channel = np.empty((height, width), dtype=np.intp)
    for site, c in enumerate(site_channels(pattern)):
        channel[site // 2 :: 2, site % 2 :: 2] = c
    own = SPECTRAL[channel] * (1 - 0.3 * r2)[..., None]
    leak = 0.12 * r2[..., None] * (np.arange(3) != channel[..., None])
    return (1 - 0.45 * r2)[..., None] * (own + leak)


def render_linear(mixing: np.ndarray, amounts, scale: float = 700.0, black: int = 64, bits: int = 10) -> RawImage:
    """Render a noiseless raw of uniform primaries ``amounts`` through a mixing field; quantised."""
    signal = mixing @ np.asarray(amounts, dtype=float) * scale + black
    bayer = np.clip(np.round(signal), 0, 2**bits - 1).astype(np.uint16)
    return bayer


@pytest.fixture(params=["BGGR", "RGGB"])
def linear_refs(request) -> dict[str, RawImage]:
    """White, red, green, blue and black references of the linear model (256 x 192)."""
    pattern = request.param
    mixing = linear_mixing(192, 256, pattern)
    amounts = {"white": (1, 1, 1), "red": (1, 0, 0), "green": (0, 1, 0), "blue": (0, 0, 1), "black": (0, 0, 0)}
    return {
        name: RawImage(render_linear(mixing, a), pattern, (64,) * 4, 1023, 10, "imx219", {"path": f"<{name}>"})
        for name, a in amounts.items()
    }
