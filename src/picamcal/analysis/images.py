"""The images a wheel analysis compares: one per correction mode, from a raw or processed file."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..calibration import Calibration
from ..correct import correct, correct_processed, malvar_demosaic
from ..errors import RawFormatError
from ..modes import Mode
from ..raw import read_raw
from ..raw.processed import read_processed


def images_by_mode(
    path: str | os.PathLike[str], calibration: Calibration | None = None, *, input_encoding: str = "srgb"
) -> dict[str, np.ndarray]:
    """Linear RGB images of one file, keyed by correction mode.

    A raw file with a calibration gives every mode it has (:attr:`picamcal.calibration.Calibration.modes`: a
    flat-field calibration has no ``centre`` or ``pure``); without a calibration, only ``uncorrected``
    (black-subtracted, demosaiced, scaled so its 99th percentile is 1). A processed file (JPEG, PNG, TIFF) gives
    ``uncorrected`` (linearised with ``input_encoding``) and, with a calibration, the unmixing modes of
    :func:`picamcal.correct.correct_processed`.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references, simulate_target
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    >>> path = picamcal.write_dng("target.dng", simulate_target(camera, seed=2)[0])
    >>> images = images_by_mode(path, cal)
    >>> sorted(images), images["centre"].shape
    (['centre', 'flat', 'pure', 'uncorrected'], (240, 320, 3))
    >>> list(images_by_mode(path))
    ['uncorrected']
    """
    path = Path(path)
    try:
        raw = read_raw(path)
    except RawFormatError as raw_error:
        try:
            processed = read_processed(path, input_encoding)
        except RawFormatError:
            raise raw_error from None
        images = {str(Mode.UNCORRECTED): processed.rgb}
        if calibration is not None and calibration.has_unmixing:  # a flat calibration has nothing to unmix with
            images.update({str(m): correct_processed(processed, calibration, m) for m in Mode if m.needs_unmixing})
        return images
    if calibration is not None:
        return {str(mode): correct(raw, calibration, mode) for mode in calibration.modes}
    rgb = malvar_demosaic(raw.black_subtracted(), raw.pattern)
    return {str(Mode.UNCORRECTED): rgb / max(float(np.percentile(rgb, 99)), 1e-6)}
