"""Live unmixing on the Pi: the calibration's colour unmixing applied in place to a picamera2 stream.

A camera running with the lens shading table exported from the calibration (``picamcal export-tuning``) sends
frames that are already flat. What is left is what :func:`picamcal.correct.correct_processed` does to such an
image: divide out the residual between the exported table (as the ISP applies it) and the calibration's flat
field, with the colour gains, and unmix, all in linear camera RGB, around the colour matrix the ISP applied
(``rpi.ccm``, undone before and redone after). Every step is linear in the pixel, so per pixel they compose into
one 3 x 3 matrix

    M(y, x) = CCM · U(y, x) · diag(residual(y, x)) · CCM⁻¹

(``U`` the paper's unmixing, eq. for ``Unmixed``; ``Cx U`` in mode ``pure``). :func:`unmixing_field` computes it
once per stream size by putting three unit images through :func:`~picamcal.correct.correct_processed` itself,
so the live path and the file path cannot drift apart.

The frames are 8-bit and gamma encoded (the tuning file's ``rpi.contrast`` gamma curve), and the unmixing only
holds on linear values, so each pixel goes through a 256-entry table to linear float32, the matrix, and back to
the code that is the exact rounding of the curve (a 16384-entry table and one comparison: :func:`tone_curve_tables`).
Against ``correct_processed`` on the same frame, encoded with the exact inverse curve and rounded, the codes are
the same (``tests/test_live.py``: none differs); one could differ by a code only where the composed matrix's
float32 rounding (below 1e-6) puts a value across a code's edge. Applying the matrix to the encoded codes instead
is off by up to 169 codes on a target of saturated colours (docs/live.md).

picamera2's names for the RGB formats are libcamera's (DRM fourcc) names, which give the channels from the most
significant byte of a little-endian word: ``RGB888`` holds B, G, R in memory order, ``BGR888`` R, G, B,
``XBGR8888`` R, G, B, X and ``XRGB8888`` B, G, R, X (the Picamera2 manual, Appendix A). :data:`STREAM_FORMATS`
holds the byte offsets; the padding byte of the 32-bit formats is left as it is.

picamera2 is imported only inside :meth:`LiveUnmixer.callback`, when no other ``MappedArray`` is given.
"""

from .camera import camera_sensor_mode
from .stream import (
    ENCODE_TABLE_SIZE,
    STREAM_FORMATS,
    LiveStreamError,
    StreamFormat,
    ToneCurve,
    stream_format,
    tone_curve_tables,
)
from .unmixer import ENGINES, LiveUnmixer, unmixing_field

__all__ = [
    "ENCODE_TABLE_SIZE",
    "ENGINES",
    "STREAM_FORMATS",
    "LiveStreamError",
    "LiveUnmixer",
    "StreamFormat",
    "ToneCurve",
    "camera_sensor_mode",
    "stream_format",
    "tone_curve_tables",
    "unmixing_field",
]
