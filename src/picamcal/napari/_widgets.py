"""The dock widgets napari's Plugins menu lists (``napari.yaml``): Correct, Calibrate and Inspect.

Each is a magicgui ``Container`` napari builds with its viewer, a thin skin over the library: Correct
(:mod:`picamcal.napari._correct_widget`: :func:`picamcal.correct` into layers, the noise penalty over the image, the
files of ``picamcal correct``), Calibrate (:mod:`picamcal.napari._calibrate_widget`: :func:`picamcal.calibrate`,
the report's checks, the ``.npz`` and the tuning files of ``picamcal export-tuning``) and Inspect, here:
``picamcal inspect``'s table and warnings for the files of the selected layers. Work that reads files or computes
runs in napari's worker threads; a picamcal error is the command line's one line in napari's notification area.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from magicgui.widgets import Container, PushButton, TextEdit

from ..describe import INSPECT_COLUMNS
from ._calibrate_widget import CalibrateWidget, export_tuning_files
from ._correct_widget import (
    CorrectWidget,
    WorkerHost,
    correct_layer,
    noise_penalty_layer,
    read_only_table,
    record_of,
    show_rows,
)

if TYPE_CHECKING:
    import napari.viewer

__all__ = [
    "CalibrateWidget",
    "CorrectWidget",
    "InspectWidget",
    "correct_layer",
    "export_tuning_files",
    "files_of_layers",
    "inspection_rows",
    "noise_penalty_layer",
]


def inspection_rows(records: Sequence[Mapping[str, Any]]) -> tuple[list[str], list[list[str]], list[str]]:
    """``picamcal inspect``'s table and the lines below it (:func:`picamcal.describe.inspection_table`), for the
    records of :func:`picamcal.describe.inspect_files`: the columns, the rows (every row as long as the columns) and
    the lines.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, render
    >>> _ = picamcal.write_dng("white.dng", render(make_camera("imx219", size=(64, 48)), "white", rng=1))
    >>> from picamcal.describe import inspect_files
    >>> columns, rows, lines = inspection_rows(inspect_files([Path("white.dng")]))
    >>> dict(zip(columns, rows[0]))["size"], dict(zip(columns, rows[0]))["pattern"], lines
    ('64x48', 'BGGR', [])
    """
    from ..describe import inspection_table

    columns, rows, lines, _ = inspection_table([dict(r) for r in records])
    return columns, [row + [""] * (len(columns) - len(row)) for row in rows], lines


#: Milliseconds the selection must stay as it is before the Inspect widget looks at its files.
SETTLE_MS = 150


def files_of_layers(layers: Iterable[Any]) -> list[Path]:
    """The files the layers came from (a raw frame's, a stack's, a calibration's), each once, in order."""
    found: dict[str, Path] = {}
    for layer in layers:
        record = record_of(layer)
        for path in record.get("paths") or ([record["path"]] if record.get("path") else []):
            found.setdefault(str(path), Path(path))
    return list(found.values())


def _inspect(paths: list[Path]) -> list[dict[str, Any]]:
    from ..describe import inspect_files

    return inspect_files(paths)


class InspectWidget(Container):
    """``picamcal inspect`` for the files of the selected layers: its table (read-only) and its notes and warnings.

    It follows the selection (once it has settled: a change of many layers at once, or the viewer closing, is one
    look, or none); the button inspects again (after the files changed on disk).
    """

    def __init__(self, napari_viewer: napari.viewer.Viewer) -> None:
        from qtpy.QtCore import QTimer

        super().__init__()
        self.viewer = napari_viewer
        self.host = WorkerHost()
        self.records: list[dict[str, Any]] = []
        self._button = PushButton(text="Inspect the selected layers' files")
        self.table = read_only_table(INSPECT_COLUMNS)
        self.notes = TextEdit(value="")
        self.notes.read_only = True
        self.extend([self._button, self.table, self.notes])
        self._asked = 0
        self._shown: list[Path] | None = None
        self._settled = QTimer(self.native)  # goes with the widget: nothing is looked at once the viewer closes
        self._settled.setSingleShot(True)
        self._settled.setInterval(SETTLE_MS)
        self._settled.timeout.connect(self._selection_settled)
        self._button.changed.connect(self.inspect)
        napari_viewer.layers.selection.events.changed.connect(self._selection_changed)

    def _selection_changed(self, *_: Any) -> None:
        try:
            self._settled.start()  # again: a change within SETTLE_MS of the last waits for the next
        except RuntimeError:  # the widget is gone, the viewer closing: nothing to look at
            pass

    def _selected_files(self) -> list[Path]:
        selection = self.viewer.layers.selection
        return files_of_layers(layer for layer in self.viewer.layers if layer in selection)  # in the list's order

    def _selection_settled(self) -> None:
        if self._selected_files() != self._shown:  # not the files shown already
            self.inspect()

    def inspect(self, *_: Any) -> Any:
        """Inspect the files of the selected layers in a worker; the table shows them when it is done. The worker, or
        None when no file is selected."""
        paths = self._selected_files()
        self._asked += 1
        self._shown = paths
        if not paths:
            self._show([], self._asked)
            return None
        asked = self._asked
        return self.host.start(_inspect, paths, on_done=lambda records: self._show(records, asked))

    def _show(self, records: list[dict[str, Any]], asked: int) -> None:
        if asked != self._asked:  # the selection changed since: a later inspection shows its files
            return
        self.records = records
        columns, rows, lines = inspection_rows(records)
        show_rows(self.table, columns, rows)
        self.notes.value = "\n".join(lines)
