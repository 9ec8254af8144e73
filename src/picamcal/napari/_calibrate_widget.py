"""The Calibrate widget: reference layers or files to a calibration, in a worker thread with a progress bar; its checks
with the verdicts and words of ``picamcal report``, its maps as layers, its ``.npz`` and its tuning files.

The calibration is :func:`picamcal.calibrate`'s, given the frames ``picamcal calibrate`` would read; the checks are
:func:`picamcal.analysis.diagnostics.diagnose`'s, the report's verdict table. Saving follows the command's rules
(the output may not be an input, nor replace a file without "overwrite", nor ever replace a file picamcal did not
write) and writes atomically; :func:`export_tuning_files` is ``picamcal export-tuning CAL --out DIR``.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Generator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from magicgui.types import FileDialogMode
from magicgui.widgets import (
    CheckBox,
    ComboBox,
    Container,
    FileEdit,
    FloatSpinBox,
    Label,
    ProgressBar,
    PushButton,
    SpinBox,
)

from ..calibration import Calibration
from ..errors import OutputError, PicamcalError
from ..raw import RawImage, read_raw
from ..references import ROLES, role_of
from ._correct_widget import Frame, WorkerHost, frames_of, put_layer, read_only_table, say_error, say_info, show_rows
from ._layers import calibration_layers

if TYPE_CHECKING:
    import napari.viewer

    from ..analysis.diagnostics import Check

__all__ = ["CHECK_COLUMNS", "CalibrateWidget", "check_rows", "export_tuning_files"]

#: The columns of the checks' table: those of the report's verdict table.
CHECK_COLUMNS = ("check", "verdict", "what was measured")
#: The name of a calibration's map layers until it is saved (then they take its file's stem).
UNSAVED = "calibration"

#: A reference frame: a layer's (read as it was), or a file of a folder of references.
Source = Frame | Path


def check_rows(checks: Sequence[Check]) -> list[list[str]]:
    """The report's verdict table: each check's name, verdict and finding, in the report's words
    (:meth:`picamcal.analysis.diagnostics.Check.to_dict`, as ``picamcal report`` writes them).

    Examples
    --------
    >>> from picamcal.analysis.diagnostics import Check
    >>> check_rows([Check("dust", "pass", "no dust found")])
    [['dust', 'pass', 'no dust found']]
    """
    return [[record["name"], record["verdict"], record["summary"]] for record in (c.to_dict() for c in checks)]


def export_tuning_files(
    calibration: Calibration, out: str | os.PathLike[str], *, overwrite: bool = False
) -> tuple[list[Path], str | None]:
    """Write the Pi 4 and Pi 5 tuning files of a calibration into the folder ``out``, as ``picamcal export-tuning CAL
    --out OUT`` does: from the sensor's stock files (:func:`picamcal.export.tuning.export_bases`), named
    ``<sensor>_vc4.json`` and ``<sensor>_pisp.json``, with the command's checks before anything is written (an input
    as output, a file in the way without ``overwrite``, a file that is not a tuning file) and both computed before
    either is written; the files, and the note the command prints (None if none).

    Raises
    ------
    TuningError
        As :func:`picamcal.export.tuning.export_tuning` and :func:`~picamcal.export.tuning.save_tuning`.
    OutputError
        An output that exists (without ``overwrite``) or may not be replaced, or a folder that cannot be made.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> paths, note = export_tuning_files(cal, "tuning")
    >>> [path.name for path in paths], note
    (['imx219_vc4.json', 'imx219_pisp.json'], None)
    """
    from .._atomic import refuse_inputs_as_output
    from ..cli._common import check_output
    from ..export.tuning import (
        TARGET_NAMES,
        check_tuning,
        export_bases,
        export_tuning,
        is_tuning_file,
        load_export_base,
        save_tuning,
    )

    out = Path(out)
    chosen = export_bases(calibration, targets=list(TARGET_NAMES.values()))
    tunings = [load_export_base(path, chosen) for path in chosen.paths]
    label = {target: name for name, target in TARGET_NAMES.items()}
    outputs = [out / f"{chosen.stem}_{label[check_tuning(tuning)]}.json" for tuning in tunings]
    inputs = [*chosen.paths, calibration.path]
    refuse_inputs_as_output(out, inputs)
    for path in outputs:
        check_output(path, overwrite, is_tuning_file, "a libcamera tuning file", inputs)
    exported = [
        export_tuning(calibration, tuning, base_sensor=chosen.sensor, base_path=base)
        for tuning, base in zip(tunings, chosen.paths, strict=True)
    ]  # both before writing either, as the command does
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the folder: {exc.strerror or exc}", out) from exc
    written = [save_tuning(path, tuning, overwrite=overwrite) for path, tuning in zip(outputs, exported, strict=True)]
    return written, chosen.note


def _calibrate(
    refs: Mapping[str, Sequence[Source]], options: Mapping[str, Any], folder: Path | None
) -> Generator[tuple[int, int, str], None, tuple[Calibration, list[Check]]]:
    """Read each reference frame, calibrate, check: the steps done, of how many, and what is being done as it goes
    (a worker's generator); the calibration and its checks at the end."""
    from ..analysis.diagnostics import diagnose
    from ..calibrate import calibrate
    from ..references import colour_name, reference_light

    items = [(role, item) for role, frames in refs.items() for item in frames]
    total = len(items) + 2
    read: dict[str, list[RawImage]] = {}
    for done, (role, item) in enumerate(items):
        yield done, total, f"reading the {role} reference"
        read.setdefault(role, []).append(item.read() if isinstance(item, Frame) else read_raw(item))
    yield len(items), total, "calibrating"
    frames: dict[str, Any] = {role: raws[0] if len(raws) == 1 else raws for role, raws in read.items()}
    colours = {name: frames.pop(role) for role in list(frames) if (name := colour_name(role))}
    calibration = calibrate(**frames, colours=colours or None, **options)
    light = reference_light(folder) if folder is not None else None
    if light is not None:  # the light a folder of picamcal acquire records, as picamcal calibrate FOLDER takes it
        calibration = dataclasses.replace(calibration, light=light)
    yield len(items) + 1, total, "checking"
    checks = diagnose(calibration)
    yield total, total, "done"
    return calibration, checks


class CalibrateWidget(Container):
    """Calibrate from references: the layers (or a folder's files) of the white, red, green, blue and black, or a white
    alone (a flat-field calibration; black optional).

    Choosing a folder assigns its files to the roles as ``picamcal calibrate FOLDER`` does (with its extra colour
    references and the light its manifest records); layers named for a role are assigned when they are loaded.
    The calibration runs in a worker thread, with a progress bar; then the checks show with the report's verdicts
    and words, the maps as layers, and the calibration can be saved and its tuning files exported.
    """

    def __init__(self, napari_viewer: napari.viewer.Viewer) -> None:
        super().__init__()
        self.viewer = napari_viewer
        self.host = WorkerHost()
        self.calibration: Calibration | None = None
        self.checks: list[Check] = []
        self._sources: dict[str, list[Source]] = {}
        self._folder: Path | None = None
        self._extras: dict[str, list[Source]] = {}
        self._inputs: list[Path] = []  # the files read, which no output may replace
        self._maps: list[Any] = []
        self.folder = FileEdit(label="references folder", mode=FileDialogMode.EXISTING_DIRECTORY, nullable=True)
        self.roles = {role: ComboBox(label=role, choices=self._choices, nullable=True) for role in ROLES}
        self.bin_size = SpinBox(label="bin size (px)", value=16, min=2, max=1024, step=2)
        self.smoothing = FloatSpinBox(label="smoothing (bins)", value=0.0, min=0.0, max=1000.0, step=0.5)
        self.max_noise_penalty = FloatSpinBox(label="max noise penalty (0: none)", value=0.0, min=0.0, max=1e6)
        self.calibrate_button = PushButton(text="Calibrate")
        self.progress = ProgressBar(value=0, min=0, max=1, label="progress")
        self.status = Label(value="")
        self.checks_table = read_only_table(CHECK_COLUMNS)
        self.out_file = FileEdit(label="save as", mode=FileDialogMode.OPTIONAL_FILE, filter="*.npz", nullable=True)
        self.overwrite = CheckBox(text="Replace existing files (--overwrite)")
        self.save_button = PushButton(text="Save the calibration")
        self.tuning_folder = FileEdit(label="tuning files to", mode=FileDialogMode.EXISTING_DIRECTORY, nullable=True)
        self.export_button = PushButton(text="Export tuning (Pi 4 and Pi 5)")
        self.extend(
            [
                self.folder,
                *self.roles.values(),
                self.bin_size,
                self.smoothing,
                self.max_noise_penalty,
                self.calibrate_button,
                self.progress,
                self.status,
                self.checks_table,
                self.out_file,
                self.overwrite,
                self.save_button,
                self.tuning_folder,
                self.export_button,
            ]
        )
        self.folder.changed.connect(self._folder_chosen)
        self.calibrate_button.changed.connect(self.calibrate)
        self.save_button.changed.connect(self.save)
        self.export_button.changed.connect(self.export)
        napari_viewer.layers.events.inserted.connect(self._layers_changed)
        napari_viewer.layers.events.removed.connect(self._layers_changed)
        self._layers_changed()

    # The references --------------------------------------------------------------------------------------------

    def _choices(self, _: Any = None) -> list[tuple[str, str]]:
        """The frames of the viewer's layers and the folder's files, by file (or layer name for a frame in memory)."""
        return [(Path(key).name if os.sep in key else key, key) for key in self._sources]

    def _layers_changed(self, *_: Any) -> None:
        for frame in frames_of(self.viewer.layers):
            key = str(frame.path) if frame.path is not None else frame.name
            self._sources.setdefault(key, [frame])
        for combo in self.roles.values():
            combo.reset_choices()
        for role, combo in self.roles.items():  # a layer named for its role takes it, unless one is assigned
            if combo.value is None:
                combo.value = next((key for key in self._sources if role_of(Path(key).name) == role), None)

    def _folder_chosen(self, folder: Path | None) -> None:
        """Assign a folder's references to the roles, as ``picamcal calibrate FOLDER`` finds them."""
        if folder is None or not Path(folder).is_dir():
            return
        from ..references import find_references

        try:
            found = find_references(folder)
        except PicamcalError as exc:
            say_error(exc)
            return
        self._folder = Path(folder)
        self._extras = {}
        keys: dict[str, str] = {}
        for role, paths in found.items():
            frames: list[Source] = list(paths) if isinstance(paths, list) else [paths]
            if role not in self.roles:
                self._extras[role] = frames
                continue
            keys[role] = "; ".join(str(p) for p in frames)
            self._sources[keys[role]] = frames
        for role, combo in self.roles.items():
            combo.reset_choices()
            combo.value = keys.get(role)

    # Calibrating -------------------------------------------------------------------------------------------------

    def calibrate(self, *_: Any) -> Any:
        """Calibrate from the assigned references in a worker (the progress bar follows it); the worker, or None."""
        refs = {role: self._sources[combo.value] for role, combo in self.roles.items() if combo.value is not None}
        if "white" not in refs:
            say_error(PicamcalError("choose the white reference: a layer, or a folder of references"))
            return None
        folder = self._folder
        files = (item if isinstance(item, Path) else item.path for frames in refs.values() for item in frames)
        paths = [path for path in files if path is not None]
        if folder is not None and any(path.parent != folder for path in paths):
            folder = None  # the folder's light and extra colours belong to its references only
        refs.update(self._extras if folder is not None else {})
        options = {
            "bin_size": self.bin_size.value,
            "smoothing": self.smoothing.value,
            "max_noise_penalty": self.max_noise_penalty.value or None,
        }
        self._inputs = [*paths, *([folder] if folder is not None else [])]
        self.progress.value = 0
        return self.host.start(
            _calibrate,
            refs,
            options,
            folder,
            on_yield=self._step,
            on_done=self._calibrated,
            buttons=[self.calibrate_button],
        )

    def _step(self, step: tuple[int, int, str]) -> None:
        done, total, what = step
        self.progress.max = total
        self.progress.value = done
        self.status.value = what

    def _calibrated(self, result: tuple[Calibration, list[Check]]) -> None:
        self.calibration, self.checks = result
        passed = sum(check.verdict == "pass" for check in self.checks)
        warned = len(self.checks) - passed
        self.status.value = f"{passed} of {len(self.checks)} checks pass" + (
            f"; {warned} need a look" if warned else ""
        )
        show_rows(self.checks_table, CHECK_COLUMNS, check_rows(self.checks))
        self._show_maps(self.calibration, UNSAVED)

    def _show_maps(self, calibration: Calibration, name: str) -> None:
        """The calibration's maps as layers, in place of those shown before."""
        for layer in self._maps:
            if layer in self.viewer.layers:
                self.viewer.layers.remove(layer)
        self._maps = [put_layer(self.viewer, layer) for layer in calibration_layers(calibration, name)]

    # Saving --------------------------------------------------------------------------------------------------------

    def save(self, *_: Any) -> Path | None:
        """Save the calibration as ``picamcal calibrate --out`` does (its checks, atomically); its maps then take the
        file's name, so that the Correct widget finds it by its file. The file, or None."""
        from ..calibration import is_calibration_file, load_calibration
        from ..cli._common import check_output

        path = self.out_file.value
        if self.calibration is None or not isinstance(path, Path):
            say_error(PicamcalError("calibrate first, then choose the file to save the calibration in"))
            return None
        overwrite = self.overwrite.value
        try:
            check_output(path, overwrite, is_calibration_file, "a picamcal calibration", self._inputs)
            self.calibration.save(path, overwrite=overwrite)
            self.calibration = load_calibration(path)
        except PicamcalError as exc:
            say_error(exc)
            return None
        say_info(f"wrote {path}")
        self._show_maps(self.calibration, path.stem)
        return path

    def export(self, *_: Any) -> Any:
        """Export the tuning files for the Pi 4 and the Pi 5 into the chosen folder (:func:`export_tuning_files`), in
        a worker; the worker, or None."""
        folder = self.tuning_folder.value
        if self.calibration is None or not isinstance(folder, Path):
            say_error(PicamcalError("calibrate first, then choose the folder for the tuning files"))
            return None
        return self.host.start(
            _export, self.calibration, folder, self.overwrite.value, on_done=_exported, buttons=[self.export_button]
        )


def _export(calibration: Calibration, folder: Path, overwrite: bool) -> tuple[list[Path], str | None]:
    return export_tuning_files(calibration, folder, overwrite=overwrite)


def _exported(result: tuple[list[Path], str | None]) -> None:
    paths, note = result
    for path in paths:
        say_info(f"wrote {path}")
    if note:
        say_info(note)
