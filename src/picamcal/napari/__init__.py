"""picamcal in napari: a reader for every raw format picamcal reads and for calibrations, the Correct, Calibrate and
Inspect widgets, sample data and writers (``napari.yaml``, found by napari through the ``napari.manifest`` entry
point). Install with ``pip install "picamcal[napari]"``; napari loads these modules when it needs them, and nothing
here imports Qt unless napari asks for a widget, so ``import picamcal`` and the command line stay as fast."""
