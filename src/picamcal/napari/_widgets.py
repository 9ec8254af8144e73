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
    "INSPECT_COLUMNS",
    "CalibrateWidget",
    "CorrectWidget",
    "InspectWidget",
    "correct_layer",
    "export_tuning_files",
    "files_of_layers",
    "inspection_rows",
    "noise_penalty_layer",
]

#: The columns of the Inspect table: those of ``picamcal inspect``'s table (``frames`` only where a file has several).
INSPECT_COLUMNS = (
    "file",
    "format",
    "sensor",
    "size",
    "sensor mode",
    "pattern",
    "bits",
    "black",
    "white",
    "signal",
    "exposure",
    "gain",
)


def inspection_rows(records: Sequence[Mapping[str, Any]]) -> tuple[list[str], list[list[str]], list[str]]:
    """``picamcal inspect``'s table and the lines below it, for the records of
    :func:`picamcal.describe.inspect_files`: the columns, the rows (each cell as the command prints it) and the
    notes and warnings (each warning once, naming the files that gave it).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, render
    >>> _ = picamcal.write_dng("white.dng", render(make_camera("imx219", size=(64, 48)), "white", rng=1))
    >>> from picamcal.describe import inspect_files
    >>> columns, rows, lines = inspection_rows(inspect_files([Path("white.dng")]))
    >>> dict(zip(columns, rows[0]))["size"], dict(zip(columns, rows[0]))["pattern"], lines
    ('64x48', 'BGGR', [])
    """
    from ..cli.inspecting import _figure, _gain, _levels, _mode, _signal

    columns = list(INSPECT_COLUMNS)
    several = any("frames" in r for r in records)
    if several:
        columns.append("frames")
    rows = []
    for r in records:
        if "width" not in r:  # not an image (a sidecar, a calibration, notes), or unreadable
            row = [Path(r["path"]).name, r["format"] if r["readable"] else "unreadable"]
        else:
            row = [
                Path(r["path"]).name,
                r["format"],
                r.get("sensor") or ("?" if r["raw"] else "-"),
                f"{r['width']}x{r['height']}",
                _mode(r.get("geometry")),
                r.get("pattern", "-"),
                r["bit_depth"],
                _levels(r.get("black_level")) if r["raw"] else "-",
                r.get("white_level", "-"),
                _signal(dict(r)),
                _figure(r.get("exposure_time_s"), 1e3, " ms"),
                _gain(dict(r)),
                *([r.get("frames", "-")] if several else []),
            ]
        rows.append([str(cell) for cell in row] + [""] * (len(columns) - len(row)))
    lines: list[str] = []
    said: dict[str, list[str]] = {}
    for r in records:
        name = Path(r["path"]).name
        if "error" in r:
            lines.append(f"{name}: cannot read: {r['error']}")
        if "note" in r:
            lines.append(f"{name}: not raw: {r['note']}")
        if "width" not in r and "sensor_mode" in r:  # a calibration: where on the sensor it was taken
            lines.append(f"{name}: sensor mode {r['sensor_mode']}")
        for warning in [*r.get("notes", []), *r["warnings"]]:
            said.setdefault(warning, []).append(name)
    for warning, names in said.items():
        who = names[0] if len(names) == 1 else f"{names[0]} and {len(names) - 1} more"
        lines.append(f"{who}: {warning}")
    return columns, rows, lines


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
