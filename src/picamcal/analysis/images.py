"""The images a wheel analysis compares: one per correction mode, from a raw or processed file."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..calibration import Calibration
from ..correct import correct, correct_processed, demosaic
from ..errors import RawFormatError
from ..raw import read_raw
from ..raw.processed import read_processed


def images_by_mode(
    path: str | os.PathLike[str], calibration: Calibration | None = None, *, input_encoding: str = "srgb"
) -> dict[str, np.ndarray]:
    """Linear RGB images of one file, keyed by correction mode.

    A raw file with a calibration gives every mode it has (``balance`` is the uncorrected image; a flat-field
    calibration has no ``centre`` or ``pure``); without a
    calibration, only ``uncorrected`` (black-subtracted, demosaiced, scaled so its 99th percentile is 1).
    A processed file (JPEG, PNG, TIFF) gives ``uncorrected`` (linearised with ``input_encoding``) and, with
    a calibration, the unmixing modes of :func:`picamcal.correct.correct_processed`.

    Examples
    --------
    >>> images = images_by_mode("target.dng", load_calibration("cal.npz"))  # doctest: +SKIP
    >>> sorted(images)  # doctest: +SKIP
    ['balance', 'centre', 'flat', 'pure']
    """
    path = Path(path)
    try:
        raw = read_raw(path)
    except RawFormatError as raw_error:
        try:
            processed = read_processed(path, input_encoding)
        except RawFormatError:
            raise raw_error from None
        images = {"uncorrected": processed.rgb}
        if calibration is not None and calibration.has_unmixing:  # a flat calibration has nothing to unmix with
            images.update({mode: correct_processed(processed, calibration, mode) for mode in ("centre", "pure")})
        return images
    if calibration is not None:
        return {mode: correct(raw, calibration, mode) for mode in calibration.modes}
    rgb = demosaic(raw.black_subtracted(), raw.pattern)
    return {"uncorrected": rgb / max(float(np.percentile(rgb, 99)), 1e-6)}
