"""The napari widgets (Correct, Calibrate, Inspect) in a real napari viewer: their layers, files and words are the
library's and the command line's.

The viewer is napari's own test fixture, ``make_napari_viewer``, on a virtual X display (:mod:`napari_support`: napari
draws with OpenGL, which Qt's offscreen platform lacks). napari's pytest plugin is off for the suite (pyproject's
addopts, ``-p no:napari``): its autouse fixtures would import napari's Qt main window for each of the suite's tests.
Its fixture and what it needs from the plugin (the fixture ``mock_app_model``, two command-line options and each
test's phase reports) are brought in here instead, so the fixture is napari's.

Every comparison is exact: the widgets call the library functions the command line calls, on the same files.
"""

from __future__ import annotations

import json
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tifffile
from napari.utils._testsupport import make_napari_viewer, mock_app_model  # noqa: F401  napari's fixture, and its own
from PIL import Image

import picamcal
from conftest import one_error, simulated_calibration
from napari_support import qt_application_on_virtual_display
from picamcal import load_calibration, read_raw
from picamcal.cli.inspecting import _json_safe
from picamcal.napari._layers import calibration_layers, raw_layers
from picamcal.napari._sample import calibration_run, sample_folder
from picamcal.napari._widgets import (
    CalibrateWidget,
    CorrectWidget,
    InspectWidget,
    inspection_rows,
    noise_penalty_layer,
)
from picamcal.simulate import make_camera, simulate_references

SIZE = (320, 240)
MODES = ("uncorrected", "flat", "centre", "pure")
#: How long a worker may take on a busy machine before a test gives up (never a timing assertion).
WAIT_MS = 300_000


class _PhaseReports:
    """napari's plugin records each test's phase reports on its item (``item.rep_call``), which its fixture reads."""

    @pytest.hookimpl(tryfirst=True, hookwrapper=True)
    def pytest_runtest_makereport(self, item: pytest.Item, call: Any) -> Any:
        outcome = yield
        report = outcome.get_result()
        setattr(item, f"rep_{report.when}", report)


@pytest.fixture(scope="session", autouse=True)
def _qt_application(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The QApplication, on a virtual display started for it, before pytest-qt's ``qapp`` would make one; napari's
    settings (read when they are first loaded, as it is made) in a folder of the session, not the user's home. The
    folder."""
    folder = tmp_path_factory.mktemp("napari")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("NAPARI_CONFIG", str(folder / "settings.yaml"))
        patch.setenv("XDG_CACHE_HOME", str(folder / "cache"))  # napari's theme icons
        qt_application_on_virtual_display()
    return folder


@pytest.fixture(scope="module", autouse=True)
def _napari(pytestconfig: pytest.Config, _qt_application: Path) -> Any:
    """What napari's pytest plugin gives its fixture (the plugin is off): its two options, at their defaults, and the
    phase reports; and, while this module runs, napari's cache in the session's folder rather than the user's home
    (put back after, for the modules after it and the programs they start)."""
    plugin = None
    if not pytestconfig.pluginmanager.has_plugin("napari"):
        for option in ("--show-napari-viewer", "--save-leaked-object-graph"):
            setattr(pytestconfig.option, option, False)  # config.getoption(name) reads this attribute
        plugin = pytestconfig.pluginmanager.register(_PhaseReports(), "picamcal-napari-phase-reports")
    import matplotlib

    matplotlib.get_cachedir()  # the report's figures: their font cache stays where it is (asked once, kept)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("XDG_CACHE_HOME", str(_qt_application / "cache"))
        yield
    if plugin is not None:
        pytestconfig.pluginmanager.unregister(name="picamcal-napari-phase-reports")


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A simulated IMX219 run (320 x 240) with its full calibration (``cal``), a flat one (``flat``: white and black),
    a calibration of another size (``small``) and a corrupt one (``corrupt``)."""
    folder = tmp_path_factory.mktemp("widgets")
    refs, cal = simulated_calibration(folder, SIZE, seed=1)
    picamcal.calibrate(read_raw(refs["white"]), black=read_raw(refs["black"])).save(folder / "flat.npz")
    picamcal.calibrate(**simulate_references(make_camera("imx219", size=(160, 120)), seed=2)).save(folder / "small.npz")
    (folder / "corrupt.npz").write_bytes(b"PK\x03\x04 not a calibration")
    return {
        **refs,
        "cal": cal,
        "flat": folder / "flat.npz",
        "small": folder / "small.npz",
        "corrupt": folder / "corrupt.npz",
    }


@pytest.fixture
def viewer(make_napari_viewer: Any) -> Any:  # noqa: F811  (the parameter is napari's fixture, imported above)
    """A napari viewer (not shown) from napari's own fixture, which closes it after the test."""
    return make_napari_viewer()


@pytest.fixture
def said(monkeypatch: pytest.MonkeyPatch) -> dict[str, list[str]]:
    """What the widgets say in napari's notification area, by kind (``error``, ``warning``, ``info``)."""
    from napari.utils import notifications

    lines: dict[str, list[str]] = {"error": [], "warning": [], "info": []}
    for kind, said_of_kind in lines.items():
        monkeypatch.setattr(notifications, f"show_{kind}", lambda message, *_, into=said_of_kind: into.append(message))
    return lines


def add(viewer: Any, layers: list[Any]) -> list[Any]:
    """Layer data tuples added to the viewer, as napari adds a reader's."""
    from napari.layers import Layer

    return [viewer.add_layer(Layer.create(*layer)) for layer in layers]


def add_frame(viewer: Any, path: Path) -> Any:
    """A raw file's layers as picamcal's reader makes them (RGB and mosaic); the RGB layer."""
    return add(viewer, raw_layers(read_raw(path), path.stem))[0]


def select(viewer: Any, *layers: Any) -> None:
    viewer.layers.selection.clear()
    viewer.layers.selection.update(layers)


def docked(viewer: Any, widget: Any) -> Any:
    """The widget in a dock of the viewer's window (closed with it), as napari shows a plugin's widget."""
    viewer.window.add_dock_widget(widget)
    return widget


def finish(qtbot: Any, widget: Any) -> None:
    """Wait, processing events, until the widget's workers have finished and their results are shown."""
    qtbot.waitUntil(lambda: not widget.host.busy, timeout=WAIT_MS)


def pixels(path: Path) -> np.ndarray:
    return tifffile.imread(path) if path.suffix == ".tiff" else np.asarray(Image.open(path))


def test_napari_builds_the_manifests_widgets_with_its_viewer(viewer):
    # From the Plugins menu: npe2 imports each class the manifest names and napari passes it the viewer.
    for name, kind in (("Correct", CorrectWidget), ("Calibrate", CalibrateWidget), ("Inspect", InspectWidget)):
        _, widget = viewer.window.add_plugin_dock_widget("picamcal", name)
        assert type(widget) is kind and getattr(widget.viewer, "__wrapped__", widget.viewer) is viewer  # napari's proxy


# Correct -----------------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_the_correct_widgets_layers_are_picamcal_correct_in_every_mode(viewer, qtbot, run, said):
    widget = docked(viewer, CorrectWidget(viewer))
    white, target = add_frame(viewer, run["white"]), add_frame(viewer, run["target"])
    widget.open_file.value = run["cal"]
    assert widget.mode_choice.choices == MODES and widget.mode_choice.value == "centre"  # the calibration's best
    select(viewer, white, target)
    cal = load_calibration(run["cal"])
    for mode in MODES:
        widget.mode_choice.value = mode
        widget.correct()
        finish(qtbot, widget)
        for name in ("white", "target"):
            layer = viewer.layers[f"{name} ({mode})"]
            assert layer.rgb and layer.metadata["picamcal"]["mode"] == mode
            np.testing.assert_array_equal(layer.data, picamcal.correct(read_raw(run[name]), cal, mode))
    assert set(viewer.layers.selection) == {white, target}  # still what the next action works on
    widget.correct()  # again: the result replaced, not added beside it
    finish(qtbot, widget)
    assert [layer.name for layer in viewer.layers].count("white (pure)") == 1
    widget.open_file.value = run["flat"]  # a flat-field calibration does the modes without unmixing
    assert widget.mode_choice.choices == ("uncorrected", "flat") and widget.mode_choice.value == "flat"
    assert said["error"] == []


def test_the_noise_penalty_toggle_adds_and_removes_its_layer(viewer, qtbot, run, said):
    widget = docked(viewer, CorrectWidget(viewer))
    white = add_frame(viewer, run["white"])
    select(viewer, white)
    add(viewer, calibration_layers(load_calibration(run["cal"]), "cal")[-1:])  # a calibration opened as its maps
    assert widget.calibration_choice.value == str(run["cal"])  # is the one to correct with
    widget.show_penalty.value = True
    finish(qtbot, widget)
    layer = viewer.layers["noise penalty (centre)"]
    expected, _, _ = noise_penalty_layer(load_calibration(run["cal"]), "centre", read_raw(run["white"]))
    np.testing.assert_array_equal(layer.data, expected)
    assert layer.data.shape == (SIZE[1], SIZE[0]) and list(layer.scale) == list(white.scale)  # over the image
    assert layer.colormap.name == "inferno" and layer.blending == "additive"
    widget.mode_choice.value = "flat"  # follows the mode
    finish(qtbot, widget)
    assert [layer.name for layer in viewer.layers if layer.name.startswith("noise penalty")] == ["noise penalty (flat)"]
    widget.show_penalty.value = False
    assert not any(layer.name.startswith("noise penalty") for layer in viewer.layers)
    assert said["error"] == []


def test_save_writes_the_files_picamcal_correct_writes(viewer, qtbot, run, said, cli, tmp_path):
    widget = docked(viewer, CorrectWidget(viewer))
    select(viewer, add_frame(viewer, run["white"]), add_frame(viewer, run["target"]))
    widget.open_file.value = run["cal"]
    widget.mode_choice.value = "pure"
    for output_format, suffix in (("uint16-tiff", ".tiff"), ("srgb-png", ".png")):
        widget.output_format.value = output_format
        widget.folder.value = tmp_path / output_format
        widget.save()
        finish(qtbot, widget)
        status, _, _ = cli(
            "correct", run["cal"], run["white"], run["target"], "--out", tmp_path / f"cli-{output_format}",
            "--mode", "pure", "--output-format", output_format, "--workers", "0",
        )  # fmt: skip
        assert status == 0
        for name in ("white", "target"):
            ours, theirs = (
                tmp_path / output_format / f"{name}{suffix}",
                tmp_path / f"cli-{output_format}" / f"{name}{suffix}",
            )
            np.testing.assert_array_equal(pixels(ours), pixels(theirs))
        assert said["info"][-1].startswith(f"wrote 2 image(s) to {tmp_path / output_format} in mode pure")
    widget.save()  # again: done already, skipped as the command skips them
    finish(qtbot, widget)
    assert "skipped 2 (done already)" in said["info"][-1]
    assert said["error"] == []


# Calibrate ---------------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_the_calibrate_widget_gives_the_calibration_and_verdicts_of_the_cli(
    viewer, qtbot, said, cli, tmp_path, monkeypatch
):
    from qtpy.QtCore import QTimer

    from picamcal.report import write_report

    add(viewer, calibration_run())  # the sample data: the five references of a simulated run
    widget = docked(viewer, CalibrateWidget(viewer))
    folder = sample_folder()
    assert {role: combo.value for role, combo in widget.roles.items()} == {
        role: str(folder / f"{role}.dng") for role in ("white", "red", "green", "blue", "black")
    }  # each layer takes the role it is named for
    # The calibration waits until the viewer's event loop has run while it waits: it can go on only if it runs in a
    # thread of its own (on the viewer's thread it would wait the whole minute, however fast the machine).
    module = sys.modules["picamcal.calibrate"]
    waiting, viewer_ran, went_on = threading.Event(), threading.Event(), []

    def calibrate_once_the_viewer_ran(*args: Any, **kwargs: Any) -> Any:
        waiting.set()
        went_on.append(viewer_ran.wait(60))
        return real_calibrate(*args, **kwargs)

    real_calibrate = module.calibrate
    timer = QTimer()
    timer.timeout.connect(lambda: waiting.is_set() and viewer_ran.set())
    with monkeypatch.context() as patch:
        patch.setattr(module, "calibrate", calibrate_once_the_viewer_ran)
        timer.start(1)
        widget.calibrate()
        finish(qtbot, widget)
        timer.stop()
    assert went_on == [True]
    assert widget.progress.value == widget.progress.max == 7  # five frames read, the calibration, the checks

    status, _, _ = cli("calibrate", folder, "--out", tmp_path / "cli.npz")
    assert status == 0
    theirs = load_calibration(tmp_path / "cli.npz")
    ours = widget.calibration
    assert ours is not None and ours.to_arrays().keys() == theirs.to_arrays().keys()
    for name, array in theirs.to_arrays().items():
        np.testing.assert_array_equal(ours.to_arrays()[name], array, err_msg=name)
    monkeypatch.setattr("picamcal.report.html._figures", lambda *_: [])  # not compared; 5 s of plots
    report = write_report(theirs, tmp_path / "report")
    checks = json.loads((report.parent / "report.json").read_text())["checks"]
    assert widget.checks_table.value["data"] == [[c["name"], c["verdict"], c["summary"]] for c in checks]
    assert [layer.name for layer in viewer.layers][-1] == "calibration noise penalty"  # its maps

    widget.out_file.value = tmp_path / "widget.npz"
    assert widget.save() == tmp_path / "widget.npz"
    saved = load_calibration(tmp_path / "widget.npz")
    for name, array in theirs.to_arrays().items():
        np.testing.assert_array_equal(saved.to_arrays()[name], array, err_msg=name)
    assert "widget noise penalty" in [layer.name for layer in viewer.layers]  # the maps take the file's name
    before = (tmp_path / "widget.npz").read_bytes()
    assert widget.save() is None  # exists already: refused as the command refuses it
    status, lines, _ = cli("calibrate", folder, "--out", tmp_path / "widget.npz")
    assert said["error"] == [one_error(status, lines)]
    assert (tmp_path / "widget.npz").read_bytes() == before

    widget.tuning_folder.value = tmp_path / "tuning"
    widget.export()
    finish(qtbot, widget)
    status, _, _ = cli("export-tuning", tmp_path / "widget.npz", "--out", tmp_path / "cli-tuning")
    assert status == 0
    names = sorted(p.name for p in (tmp_path / "cli-tuning").iterdir())
    assert names == ["imx219_pisp.json", "imx219_vc4.json"] == sorted(p.name for p in (tmp_path / "tuning").iterdir())
    for name in names:
        assert json.loads((tmp_path / "tuning" / name).read_text()) == json.loads(
            (tmp_path / "cli-tuning" / name).read_text()
        )


def test_a_white_alone_gives_the_flat_calibration_of_the_cli(viewer, qtbot, run, said, cli, tmp_path):
    widget = docked(viewer, CalibrateWidget(viewer))
    widget.folder.value = run["white"].parent  # assigns the five references, as calibrate FOLDER finds them
    assert widget.roles["blue"].value == str(run["blue"])
    for role in ("red", "green", "blue", "black"):
        widget.roles[role].value = None
    widget.calibrate()
    finish(qtbot, widget)
    status, _, _ = cli("calibrate", "--white", run["white"], "--out", tmp_path / "flat.npz")
    theirs = load_calibration(tmp_path / "flat.npz")
    assert status == 0 and widget.calibration is not None and widget.calibration.kind == theirs.kind == "flat"
    for name, array in theirs.to_arrays().items():
        np.testing.assert_array_equal(widget.calibration.to_arrays()[name], array, err_msg=name)
    assert widget.checks_table.value["data"][0][0] == "vignetting_centre" and said["error"] == []


# Inspect -----------------------------------------------------------------------------------------------------------


def test_inspect_shows_the_rows_of_picamcal_inspect(viewer, qtbot, run, said, cli):
    widget = docked(viewer, InspectWidget(viewer))
    white = add_frame(viewer, run["white"])
    penalty = add(viewer, calibration_layers(load_calibration(run["cal"]), "cal")[-1:])[0]  # one map is enough
    select(viewer, white, penalty)  # the frame and a calibration: their two files, once the selection has settled
    qtbot.waitUntil(lambda: len(widget.records) == 2, timeout=WAIT_MS)
    status, _, out = cli("inspect", run["white"], run["cal"], "--json")
    assert status == 0 and _json_safe(widget.records) == json.loads(out)
    status, _, table = cli("inspect", run["white"], run["cal"])
    rows = [[cell.strip() for cell in line.strip().strip("│").split("│")] for line in table.splitlines()]
    shown = widget.table.value
    cells = [["" if cell is None else cell for cell in row] for row in shown["data"]]  # an empty cell reads None
    assert [row for row in rows if row[0] in ("white.dng", "cal.npz")] == cells
    columns, _, lines = inspection_rows(widget.records)
    assert list(shown["columns"]) == columns and widget.notes.value == "\n".join(lines)
    assert "cal.npz: sensor mode" in widget.notes.value
    assert said["error"] == []


# Bad input ---------------------------------------------------------------------------------------------------------


def test_what_the_cli_refuses_is_refused_with_its_line_and_nothing_written(viewer, qtbot, run, said, cli, tmp_path):
    widget = docked(viewer, CorrectWidget(viewer))
    select(viewer, add_frame(viewer, run["white"]))
    out = tmp_path / "out"

    widget.open_file.value = run["corrupt"]  # a corrupt calibration file
    assert said["error"] == [one_error(*cli("correct", run["corrupt"], run["white"], "--out", out)[:2])]
    assert widget.calibration is None

    widget.open_file.value = run["small"]  # a calibration of another size
    widget.correct()
    finish(qtbot, widget)
    widget.folder.value = out
    widget.save()
    finish(qtbot, widget)
    line = one_error(*cli("correct", run["small"], run["white"], "--out", out, "--workers", "0")[:2])
    assert said["error"][1:] == [line, line]
    assert not out.exists() and "white (centre)" not in [layer.name for layer in viewer.layers]

    calibrate = docked(viewer, CalibrateWidget(viewer))  # a smoothing over the bin grid's limit
    calibrate.folder.value = run["white"].parent
    calibrate.smoothing.value = 100
    calibrate.calibrate()
    finish(qtbot, calibrate)
    line = one_error(*cli("calibrate", run["white"].parent, "--smoothing", "100", "--out", tmp_path / "x.npz")[:2])
    assert said["error"][3:] == [line] and calibrate.calibration is None and not (tmp_path / "x.npz").exists()
