"""The Correct widget, and what the three widgets share: the frames layers hold, layers put in the viewer, work in
napari's worker threads, and picamcal's errors and warnings in napari's notification area.

:func:`correct_layer` is :func:`picamcal.correct` as a layer; :func:`noise_penalty_layer` the noise penalty of a
mode over an image. The widget's Save runs the batch ``picamcal correct`` runs (:func:`picamcal.batch.run_batch`),
so its files are the command's: its formats, names and overwrite rules. A picamcal error is the command line's one
line (``str(exc)``, :func:`say_error`), and nothing is written. magicgui's widgets are made without Qt; napari and
Qt are imported when a widget is built (by napari, which has them loaded already), so importing this module stays
cheap.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from magicgui.types import FileDialogMode
from magicgui.widgets import CheckBox, ComboBox, Container, FileEdit, PushButton, Table

from ..calibration import Calibration
from ..calibration.resample import calibration_for_raw
from ..correct import choose_mode, correct
from ..errors import PicamcalError, PicamcalWarning
from ..interpolate import interpolation_matrix, upsample
from ..modes import MODE_NAMES, Mode
from ..output import BATCH_FORMATS
from ..raw import RawImage, read_raw
from ._layers import METADATA_KEY, NOISE_COLORMAP, UNITS, LayerData, image_layer, pixel_size_um, raw_metadata

if TYPE_CHECKING:
    import napari.viewer

__all__ = [
    "CorrectWidget",
    "Frame",
    "WorkerHost",
    "check_fits",
    "correct_layer",
    "frames_of",
    "noise_penalty_layer",
    "put_layer",
    "read_only_table",
    "record_of",
    "say_error",
    "say_info",
    "say_warnings",
    "show_rows",
]


class Frame(NamedTuple):
    """A raw frame a layer holds: the name its corrected layers take, its file, its RawImage when loaded, and the
    options of :func:`picamcal.read_raw` it was read with (a headless dump's format and size, a black level given)."""

    name: str
    path: Path | None
    raw: RawImage | None
    options: Mapping[str, Any]

    def read(self) -> RawImage:
        """The RawImage: the layer's own, else read from the file as it was read before."""
        if self.raw is not None:
            return self.raw
        assert self.path is not None
        return read_raw(self.path, **read_raw_options(self.options))


def record_of(layer: Any) -> Mapping[str, Any]:
    """picamcal's record of a layer (``metadata["picamcal"]``, :mod:`picamcal.napari._layers`); empty for others."""
    record = (getattr(layer, "metadata", None) or {}).get(METADATA_KEY)
    return record if isinstance(record, Mapping) else {}


def frames_of(layers: Iterable[Any]) -> list[Frame]:
    """The raw frames the layers hold, each once and in order: a file's RGB and mosaic layers are one frame, a stack's
    layers one frame per file; calibration maps and layers of other plugins hold none.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> record = {"path": "run/white.dng", "raw": None, "read_options": {}}
    >>> rgb = SimpleNamespace(name="white", metadata={"picamcal": record})
    >>> mosaic = SimpleNamespace(name="white (raw)", metadata={"picamcal": record})
    >>> stack = SimpleNamespace(name="run", metadata={"picamcal": {"paths": ["run/a.dng", "run/b.dng"]}})
    >>> [(f.name, str(f.path)) for f in frames_of([rgb, mosaic, stack, SimpleNamespace(name="x", metadata={})])]
    [('white', 'run/white.dng'), ('a', 'run/a.dng'), ('b', 'run/b.dng')]
    """
    frames: dict[Any, Frame] = {}
    for layer in layers:
        record = record_of(layer)
        raw = record.get("raw")
        options = record.get("read_options") or {}
        if record.get("paths"):  # a stack: one frame per file
            for path in record["paths"]:
                frames.setdefault(str(path), Frame(Path(path).stem, Path(path), None, options))
        elif isinstance(raw, RawImage) or (record.get("path") and "calibration" not in record and "map" not in record):
            path = Path(record["path"]) if record.get("path") else None
            key = str(path) if path is not None else id(raw)
            name = path.stem if path is not None else str(layer.name).removesuffix(" (raw)")
            frames.setdefault(key, Frame(name, path, raw if isinstance(raw, RawImage) else None, options))
    return list(frames.values())


def read_raw_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """A layer's recorded reading options (JSON: lists) as :func:`picamcal.read_raw` takes them (tuples).

    Examples
    --------
    >>> read_raw_options({"raw_format": "SBGGR10_CSI2P", "size": [640, 480], "black_level": [64, 64, 64, 64]})
    {'raw_format': 'SBGGR10_CSI2P', 'size': (640, 480), 'black_level': (64, 64, 64, 64)}
    """
    return {key: tuple(value) if isinstance(value, list) else value for key, value in options.items()}


def batch_read_options(options: Mapping[str, Any]) -> tuple[tuple[str, Any], ...]:
    """A layer's reading options as :class:`picamcal.batch.BatchOptions` takes them (``size`` is its ``raw_size``),
    as a key to group the files read alike.

    Examples
    --------
    >>> batch_read_options({"raw_format": "SBGGR10_CSI2P", "size": [640, 480], "sensor": "imx219"})
    (('raw_format', 'SBGGR10_CSI2P'), ('raw_size', (640, 480)), ('sensor', 'imx219'))
    """
    return tuple(("raw_size" if key == "size" else key, value) for key, value in read_raw_options(options).items())


def check_fits(raw: RawImage, calibration: Calibration) -> None:
    """Refuse a frame larger than the calibration's sensor area, as ``picamcal correct`` refuses its file before
    decoding it (:func:`picamcal.batch.worker.frame_bound`), with the command's words.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(160, 120)), seed=1))
    >>> check_fits(RawImage(np.zeros((240, 320), np.uint16), "BGGR", 64, 1023, 10, "imx219", {"path": "a.dng"}), cal)
    Traceback (most recent call last):
    ...
    picamcal.errors.CalibrationFileError: a.dng: image does not match the calibration: size 320x240, larger than the \
calibration's 160x120 sensor area, so outside it: calibrate in a mode that covers it (a full-sensor or binned mode \
covers every mode)
    """
    from ..batch.worker import frame_bound
    from ..limits import check_size

    check_size(raw.source, raw.width, raw.height, frame_bound(calibration))


def correct_layer(
    raw: RawImage,
    calibration: Calibration,
    mode: str | Mode | None = None,
    name: str = "",
    *,
    read_options: Mapping[str, Any] | None = None,
) -> LayerData:
    """A raw frame corrected with a calibration as an RGB image layer: :func:`picamcal.correct`'s values, named for
    the mode (``"white (centre)"``).

    The layer's record (``metadata["picamcal"]``) is the frame's (:func:`picamcal.napari._layers.raw_metadata`, so
    it still holds the frame) with ``kind`` ``"corrected"``, the ``mode`` and the ``calibration``'s file; it has
    the frame's physical pixel size as its scale, so it lies over the frame's own layers.

    Parameters
    ----------
    raw : RawImage
    calibration : Calibration
    mode : {"uncorrected", "flat", "centre", "pure"} or Mode, optional
        Default: the best the calibration does (:func:`picamcal.correct.choose_mode`).
    name : str
        The frame's name; default its file's stem, else ``"image"``.
    read_options : mapping, optional
        The options of :func:`picamcal.read_raw` the frame was read with, kept in the record (as the reader's).

    Raises
    ------
    CalibrationFileError
        A mode the calibration cannot do, or a frame it does not fit (:func:`check_fits`, then as
        :func:`picamcal.correct`).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal = picamcal.calibrate(**refs)
    >>> data, kwargs, kind = correct_layer(refs["white"], cal, "centre", name="white")
    >>> kind, kwargs["name"], kwargs["metadata"]["picamcal"]["mode"]
    ('image', 'white (centre)', 'centre')
    >>> bool(np.array_equal(data, picamcal.correct(refs["white"], cal, "centre")))
    True
    """
    mode = choose_mode(calibration, mode)
    check_fits(raw, calibration)
    rgb = correct(raw, calibration, mode)
    path = raw.metadata.get("path")
    name = name or (Path(path).stem if path else "image")
    record = raw_metadata(raw, read_options=read_options)
    calibration_path = getattr(calibration, "path", None)
    record.update(
        kind="corrected", mode=mode.value, calibration=None if calibration_path is None else str(calibration_path)
    )
    return image_layer(rgb, f"{name} ({mode.value})", record, pixel_size=record["pixel_size_um"])


def noise_penalty_layer(
    calibration: Calibration, mode: str | Mode | None = None, raw: RawImage | None = None
) -> LayerData:
    """The noise penalty of a correction mode over the image, as a translucent layer to lay over it.

    The penalty is :meth:`~picamcal.calibration.Calibration.noise_penalty` (the factor by which the mode multiplies
    read noise, relative to the sensor centre), the worst channel in each bin, as ``picamcal report`` and the
    calibration's own map layer show it; here it is resampled to every pixel of ``raw`` (its sensor mode's fields,
    :func:`picamcal.calibration.resample.calibration_for_raw`, as :func:`picamcal.correct` takes them) with the
    spline the correction interpolates its fields with (held at the outer bins' values beyond their centres), or of
    the calibration's own frame without ``raw``. Colour map ``inferno`` from 1 (no penalty), additive blending at
    half opacity, named ``"noise penalty (<mode>)"``, with the frame's physical pixel size as its scale.

    Raises
    ------
    CalibrationFileError
        A mode the calibration cannot do, or a frame it does not fit.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal = picamcal.calibrate(**refs)
    >>> data, kwargs, _ = noise_penalty_layer(cal, "centre", refs["white"])
    >>> data.shape, kwargs["name"], kwargs["colormap"], kwargs["blending"]
    ((240, 320), 'noise penalty (centre)', 'inferno', 'additive')
    >>> worst = cal.noise_penalty("centre").max()  # in the corner bins, whose centres the spline passes through
    >>> bool(np.isclose(data.max(), worst, rtol=1e-6)), float(kwargs["contrast_limits"][0])
    (True, 1.0)
    """
    mode = choose_mode(calibration, mode)
    if raw is not None:
        check_fits(raw, calibration)
    fitted = calibration if raw is None else calibration_for_raw(calibration, raw)
    penalty = fitted.noise_penalty(mode).max(axis=-1).astype(np.float64)
    centres_y, centres_x = fitted.bin_centres
    # Held at the outer bins' values beyond their centres: a cubic extrapolated over the last half bin overshoots.
    rows = interpolation_matrix(centres_y, np.clip(np.arange(fitted.height), centres_y[0], centres_y[-1]))
    columns = interpolation_matrix(centres_x, np.clip(np.arange(fitted.width), centres_x[0], centres_x[-1]))
    data = np.ascontiguousarray(upsample(penalty, rows, columns), dtype=np.float32)
    size = raw_metadata(raw)["pixel_size_um"] if raw is not None else pixel_size_um(fitted.sensor, fitted.geometry)
    calibration_path = getattr(calibration, "path", None)
    kwargs: dict[str, Any] = {
        "name": f"noise penalty ({mode.value})",
        "colormap": NOISE_COLORMAP,
        "blending": "additive",
        "opacity": 0.5,
        "contrast_limits": (1.0, max(float(penalty.max()), 1.0 + 1e-6)),
        "metadata": {
            METADATA_KEY: {
                "map": "noise penalty",
                "mode": mode.value,
                "calibration": None if calibration_path is None else str(calibration_path),
            }
        },
    }
    if size is not None:
        kwargs.update(scale=(size, size), units=(UNITS, UNITS))
    return (data, kwargs, "image")


# Showing results and errors in the viewer ------------------------------------------------------------------------


def say_error(exc: BaseException) -> None:
    """A picamcal error as its one line in napari's notification area (the command line's ``str(exc)``); anything
    else is a bug, raised on for napari's own handler."""
    if not isinstance(exc, PicamcalError):
        raise exc
    from napari.utils import notifications

    notifications.show_error(str(exc))


def say_warnings(caught: Iterable[warnings.WarningMessage]) -> None:
    """picamcal's warnings, each once, in napari's notification area (other libraries' are not picamcal's to say)."""
    from napari.utils import notifications

    for message in dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, PicamcalWarning)):
        notifications.show_warning(message)


def say_info(message: str) -> None:
    """A line saying what was done (written files), in napari's notification area."""
    from napari.utils import notifications

    notifications.show_info(message)


def put_layer(viewer: Any, layer: LayerData) -> Any:
    """Add a layer to the viewer, or replace the data of the layer of its name (correcting again replaces the result
    rather than piling up copies); the selection stays as it was."""
    from napari.layers import Image, Layer

    data, kwargs, kind = layer
    existing = next((each for each in viewer.layers if each.name == kwargs["name"]), None)
    rgb = bool(kwargs.get("rgb", False))
    if isinstance(existing, Image) and existing.rgb == rgb and existing.data.shape == data.shape:
        existing.data = data
        existing.metadata = kwargs["metadata"]
        existing.contrast_limits = kwargs["contrast_limits"]
        return existing
    if existing is not None:
        viewer.layers.remove(existing)
    selection = viewer.layers.selection
    selected, active = set(selection), selection.active
    added = viewer.add_layer(Layer.create(data, kwargs, kind))
    selection.clear()  # napari selects a new layer; the user's selection stays what the next action works on
    selection.update(each for each in selected if each in viewer.layers)
    selection.active = active if active in viewer.layers else None
    return added


def read_only_table(columns: Sequence[str]) -> Table:
    """An empty table (a QTableWidget) with these columns, which the user reads but cannot edit."""
    from qtpy.QtWidgets import QAbstractItemView

    table = Table(value={"data": [], "index": [], "columns": list(columns)})
    table.native.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
    return table


def show_rows(table: Table, columns: Sequence[str], rows: Sequence[Sequence[str]]) -> None:
    """Replace a table's rows (and columns)."""
    table.value = {"data": [list(row) for row in rows], "index": list(range(len(rows))), "columns": list(columns)}


class WorkerHost:
    """What a widget needs to run work in napari's worker threads and hear of its end.

    ``busy`` is true while a worker it started runs (the tests wait on it); a picamcal error ends the worker with
    its one line (:func:`say_error`), and the warnings it gave are shown as napari warnings.
    """

    def __init__(self) -> None:
        self.workers: list[Any] = []

    @property
    def busy(self) -> bool:
        """Whether a worker this widget started has not finished yet."""
        return bool(self.workers)

    def start(
        self,
        function: Callable[..., Any],
        *args: Any,
        on_yield: Callable[[Any], None] | None = None,
        on_done: Callable[[Any], None] | None = None,
        buttons: Sequence[PushButton] = (),
    ) -> Any:
        """Run ``function(*args)`` (a generator yields to ``on_yield`` as it goes) in a worker thread; ``on_done``
        takes its result. The ``buttons`` are disabled until it finishes."""
        from napari.qt.threading import create_worker

        worker = create_worker(function, *args, _start_thread=False, _ignore_errors=True)
        if on_yield is not None:
            worker.yielded.connect(on_yield)
        if on_done is not None:
            worker.returned.connect(on_done)
        worker.errored.connect(say_error)
        worker.warned.connect(_say_worker_warning)
        for button in buttons:
            button.enabled = False

        def finished() -> None:
            for button in buttons:
                button.enabled = True
            self.workers.remove(worker)

        worker.finished.connect(finished)
        self.workers.append(worker)
        worker.start()
        return worker


def _say_worker_warning(shown: tuple[Any, ...]) -> None:
    """A worker's warning (the arguments of ``warnings.showwarning``), when it is picamcal's."""
    message, category = shown[0], shown[1]
    if isinstance(category, type) and issubclass(category, PicamcalWarning):
        from napari.utils import notifications

        notifications.show_warning(str(message))


# The Correct widget ------------------------------------------------------------------------------------------------


def _correct_frames(frames: Sequence[Frame], calibration: Calibration, mode: str) -> Iterator[LayerData]:
    """Each frame corrected, as a layer (a worker's generator: the viewer takes each as it comes)."""
    for frame in frames:
        yield correct_layer(frame.read(), calibration, mode, frame.name, read_options=frame.options)


def _penalty(calibration: Calibration, mode: str, frame: Frame | None) -> LayerData:
    return noise_penalty_layer(calibration, mode, None if frame is None else frame.read())


def _save(
    calibration: Path, groups: Mapping[tuple[tuple[str, Any], ...], list[Path]], options: Mapping[str, Any]
) -> list[Any]:
    """``picamcal correct CALIBRATION FILES --out ...`` for each group of files read alike, in this process."""
    from ..batch import BatchOptions, run_batch

    return [
        run_batch(calibration, paths, BatchOptions(**options, **dict(read), workers=0))
        for read, paths in groups.items()
    ]


class CorrectWidget(Container):
    """Correct the selected layers' raw frames with a calibration, in a mode, into new layers; show the mode's noise
    penalty over the image; save the corrections as ``picamcal correct`` writes them.

    The calibration is a file opened here, or one the viewer holds as layers (opened by picamcal's reader, or made
    by the Calibrate widget). The modes offered are those it does (a flat-field calibration: uncorrected and flat),
    its best chosen (:func:`picamcal.correct.choose_mode`).
    """

    def __init__(self, napari_viewer: napari.viewer.Viewer) -> None:
        super().__init__()
        self.viewer = napari_viewer
        self.host = WorkerHost()
        self._opened: list[str] = []
        self._calibrations: dict[str, Calibration] = {}
        self._penalty_layers: list[Any] = []
        self.calibration_choice = ComboBox(label="calibration", choices=self._calibration_choices, nullable=True)
        self.open_file = FileEdit(label="open", mode=FileDialogMode.EXISTING_FILE, filter="*.npz", nullable=True)
        self.mode_choice = ComboBox(label="mode", choices=list(MODE_NAMES), value=Mode.CENTRE.value)
        self.correct_button = PushButton(text="Correct the selected layers")
        self.show_penalty = CheckBox(text="Show the noise penalty over the image")
        self.output_format = ComboBox(label="format", choices=list(BATCH_FORMATS), value="float32-tiff")
        self.folder = FileEdit(label="save to", mode=FileDialogMode.EXISTING_DIRECTORY, nullable=True)
        self.overwrite = CheckBox(text="Replace existing outputs (--overwrite)")
        self.save_button = PushButton(text="Save the selected layers' corrections")
        self.extend(
            [
                self.calibration_choice,
                self.open_file,
                self.mode_choice,
                self.correct_button,
                self.show_penalty,
                self.output_format,
                self.folder,
                self.overwrite,
                self.save_button,
            ]
        )
        self.open_file.changed.connect(self._open)
        self.calibration_choice.changed.connect(self._calibration_changed)
        self.mode_choice.changed.connect(self._refresh_penalty)
        self.show_penalty.changed.connect(self._refresh_penalty)
        self.correct_button.changed.connect(self.correct)
        self.save_button.changed.connect(self.save)
        napari_viewer.layers.events.inserted.connect(self._layers_changed)
        napari_viewer.layers.events.removed.connect(self._layers_changed)
        self._layers_changed()

    @property
    def calibration(self) -> Calibration | None:
        """The chosen calibration."""
        key = self.calibration_choice.value
        return None if key is None else self._calibrations.get(key)

    def _calibration_choices(self, _: Any = None) -> list[tuple[str, str]]:
        """The calibrations opened here and those the viewer's layers hold (by file, or by layer for an unsaved one)."""
        keys = list(self._opened)
        for layer in self.viewer.layers:
            record = record_of(layer)
            calibration = record.get("calibration")
            if isinstance(calibration, Calibration):
                key = record.get("path") or str(layer.name).removesuffix(f" {record.get('map', '')}")
                self._calibrations[key] = calibration
                keys.append(key)
        return [(key, key) for key in dict.fromkeys(keys)]

    def _layers_changed(self, *_: Any) -> None:
        self.calibration_choice.reset_choices()
        if self.calibration_choice.value is None and self.calibration_choice.choices:
            self.calibration_choice.value = self.calibration_choice.choices[-1]

    def _open(self, path: Path | None) -> None:
        """Open a calibration file as ``picamcal correct`` does: a calibration, or a lens shading table's flat field."""
        if path is None or not Path(path).is_file():  # nothing chosen yet, or a name still being typed
            return
        from ..export.tables import load_flat_field

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                calibration = load_flat_field(path)
            except PicamcalError as exc:
                say_error(exc)
                return
            finally:
                say_warnings(caught)
        key = str(path)
        self._calibrations[key] = calibration
        self._opened.append(key)
        self.calibration_choice.reset_choices()
        self.calibration_choice.value = key

    def _calibration_changed(self, *_: Any) -> None:
        calibration = self.calibration
        if calibration is None:
            return
        modes = [mode.value for mode in calibration.modes]
        current = self.mode_choice.value
        self.mode_choice.choices = modes
        self.mode_choice.value = current if current in modes else choose_mode(calibration).value
        self._refresh_penalty()

    def _chosen(self) -> Calibration | None:
        calibration = self.calibration
        if calibration is None:
            say_error(PicamcalError("choose a calibration: open a file, or load one as layers"))
        return calibration

    def _selected_frames(self) -> list[Frame]:
        frames = frames_of(self.viewer.layers.selection)
        if not frames:
            say_error(PicamcalError("select the layers of the raw frames to correct"))
        return frames

    def correct(self, *_: Any) -> Any:
        """Correct the selected layers' frames in the chosen mode, each into a layer ``"<name> (<mode>)"``; the
        worker, or None when there is nothing to do."""
        calibration = self._chosen()
        frames = self._selected_frames() if calibration is not None else []
        if calibration is None or not frames:
            return None
        return self.host.start(
            _correct_frames,
            frames,
            calibration,
            self.mode_choice.value,
            on_yield=lambda layer: put_layer(self.viewer, layer),
            buttons=[self.correct_button],
        )

    def _refresh_penalty(self, *_: Any) -> Any:
        """Remove the noise-penalty layer; when shown, make it again for the chosen calibration and mode, over the
        first selected frame (or the calibration's own frame)."""
        for layer in self._penalty_layers:
            if layer in self.viewer.layers:
                self.viewer.layers.remove(layer)
        self._penalty_layers.clear()
        calibration = self.calibration
        if not self.show_penalty.value or calibration is None:
            return None
        frames = frames_of(self.viewer.layers.selection)
        return self.host.start(
            _penalty, calibration, self.mode_choice.value, frames[0] if frames else None, on_done=self._put_penalty
        )

    def _put_penalty(self, layer: LayerData) -> None:
        if self.show_penalty.value:  # not switched off while it was being made
            self._penalty_layers.append(put_layer(self.viewer, layer))

    def save(self, *_: Any) -> Any:
        """Write the selected layers' frames, corrected, into the chosen folder in the chosen format, as ``picamcal
        correct CALIBRATION FILES --out FOLDER --mode MODE --output-format FORMAT`` does; the worker, or None."""
        calibration = self._chosen()
        frames = self._selected_frames() if calibration is not None else []
        if calibration is None or not frames:
            return None
        if calibration.path is None:
            say_error(PicamcalError("save the calibration first (Calibrate widget): the outputs record its file"))
            return None
        folder = self.folder.value
        if not isinstance(folder, Path):
            say_error(PicamcalError("choose the folder to save to"))
            return None
        groups: dict[tuple[tuple[str, Any], ...], list[Path]] = {}
        for frame in frames:
            if frame.path is not None:
                groups.setdefault(batch_read_options(frame.options), []).append(frame.path)
        options = {
            "out_dir": folder,
            "mode": self.mode_choice.value,
            "output_format": self.output_format.value,
            "overwrite": self.overwrite.value,
        }
        return self.host.start(
            _save,
            calibration.path,
            groups,
            options,
            on_done=self._saved,
            buttons=[self.save_button],
        )

    def _saved(self, results: list[Any]) -> None:
        from napari.utils import notifications

        for result in results:
            error = result.failure_of_one_file()
            if error is not None:  # one file that failed: the command's one line
                say_error(error)
                continue
            for path, reason in result.failed:
                notifications.show_error(f"failed: {path}: {reason}")
            kept = result.kept_message()
            if kept is not None:
                notifications.show_warning(kept)
            say_info(
                f"wrote {len(result.done)} image(s) to {self.folder.value} in mode {result.mode}; skipped "
                f"{len(result.skipped)} (done already); failed {len(result.failed)}"
            )
