"""The reading-options dialog: what a file that does not say enough about itself asks for when napari opens it.

A headless dump (``rpicam-raw -o``) has no header: its raw format and frame size (and the stride, frame, sensor and
black level where the defaults do not do) come from the user, as the command line's ``--raw-format``, ``--size``,
``--stride``, ``--frame``, ``--sensor`` and ``--black-level``; a frame whose black level nothing gives (a dump of a
sensor picamcal does not know, a DNG without a BlackLevel tag) asks for ``--sensor`` or ``--black-level``. The
answers go through the command line's own parsing (:mod:`picamcal.cli._common`), so a bad one gets the command
line's message, and then to :func:`picamcal.read_raw`.

The reader asks through :func:`ask_read_options`, a module-level function the tests replace with one that returns
the answers (``parse_answers`` of what a user would type): no test waits for a human. :class:`ReadOptionsDialog` is
the real dialog (Qt through qtpy, imported when one is built), which a test can build, fill and submit without
showing it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: What a request asks for: a headless dump's reading options, or a black level.
HEADLESS = "headless"
BLACK_LEVEL = "black level"
#: The answers' keys, in the dialog's order, each with its label and the command line option it stands for.
FIELDS: dict[str, tuple[str, str]] = {
    "raw_format": ("Raw format", "--raw-format"),
    "size": ("Frame size", "--size"),
    "stride": ("Stride (bytes per row)", "--stride"),
    "frame": ("Frame", "--frame"),
    "sensor": ("Sensor", "--sensor"),
    "black_level": ("Black level (DN)", "--black-level"),
}
#: The fields of each kind of request.
REQUEST_FIELDS = {HEADLESS: tuple(FIELDS), BLACK_LEVEL: ("sensor", "black_level")}
#: What a field left empty means, shown in it.
PLACEHOLDERS = {
    "raw_format": "SBGGR10_CSI2P, SRGGB12_CSI2P, SGBRG16, ...",
    "size": "WIDTHxHEIGHT",
    "stride": "libcamera's alignment",
    "frame": "0 (the first)",
    "sensor": "the file's, or the one of its size",
    "black_level": "the file's or the sensor's: one value, or four",
}


@dataclass(frozen=True)
class Request:
    """What the reader asks of the user about one file.

    Attributes
    ----------
    path : Path
        The file.
    need : {HEADLESS, BLACK_LEVEL}
        What it needs.
    reason : str
        Why, in one line (picamcal's own message: the headless hint, or why the black level is missing).
    defaults : mapping of str to str
        The fields' initial text, by key of :data:`FIELDS`.
    required : bool
        Whether the file cannot be read without the answers (cancelling then opens nothing); if not, cancelling
        reads it as it is.
    """

    path: Path
    need: str
    reason: str
    defaults: Mapping[str, str] = field(default_factory=dict)
    required: bool = True


def headless_defaults(path: str | Path) -> dict[str, str]:
    """Likely answers for a headless dump: the registry sensor whose full-size frames, packed at its bit depth or
    16-bit at libcamera's alignment, divide the file exactly (what :func:`picamcal.raw.headless.headless_hint`
    suggests), in its unflipped Bayer order; empty if none does.

    Examples
    --------
    >>> from picamcal.raw.picamera2.formats import parse_raw_format
    >>> row = parse_raw_format("SRGGB10_CSI2P").row_bytes(3280)  # an IMX219 full frame, 10-bit packed
    >>> _ = Path("frame.raw").write_bytes(bytes(-(-row // 32) * 32 * 2464))
    >>> headless_defaults("frame.raw")
    {'raw_format': 'SBGGR10_CSI2P', 'size': '3280x2464', 'sensor': 'imx219'}
    >>> _ = Path("other.raw").write_bytes(bytes(1000))
    >>> headless_defaults("other.raw")
    {}
    """
    from ..raw.headless import default_strides
    from ..raw.picamera2.formats import parse_raw_format
    from ..sensors import SENSORS

    try:
        nbytes = Path(path).stat().st_size
    except OSError:
        return {}
    for entry in SENSORS.values():
        if entry.monochrome or not nbytes or entry.default_pattern is None:
            continue
        for name in (f"S{entry.default_pattern}{entry.bit_depth}_CSI2P", f"S{entry.default_pattern}16"):
            for stride, _ in default_strides(parse_raw_format(name), entry.width)[:2]:
                if nbytes % (stride * entry.height) == 0:
                    return {"raw_format": name, "size": f"{entry.width}x{entry.height}", "sensor": entry.name}
    return {}


def parse_answers(answers: Mapping[str, str | None], need: str = HEADLESS) -> dict[str, Any]:
    """The keyword arguments of :func:`picamcal.read_raw` that the dialog's answers stand for, checked as the command
    line checks its options (:func:`picamcal.cli._common.read_options`, ``parse_sensor``, ``in_range``).

    An empty answer is the option not given. Only the keys given a value are returned.

    Raises
    ------
    typer.BadParameter
        An answer the command line refuses; ``format_message()`` is the line it prints (``Invalid value for ...``).

    Examples
    --------
    >>> parse_answers({"raw_format": "SBGGR10_CSI2P", "size": "640x480", "stride": "", "black_level": "64"})
    {'black_level': [64.0], 'raw_format': 'SBGGR10_CSI2P', 'size': (640, 480)}
    >>> for typed in ({"size": "640x47"}, {"stride": "0"}, {"sensor": "imx21"}):
    ...     try:
    ...         parse_answers({"raw_format": "SBGGR10_CSI2P", **typed})
    ...     except Exception as exc:
    ...         print(exc.format_message())
    Invalid value for --size: '640x47': width and height must be even and at least 16
    Invalid value for '--stride': 0 is outside the accepted range, 1 or more
    Invalid value for --sensor: unknown sensor 'imx21'; did you mean imx219?
    >>> parse_answers({"black_level": "64"}, BLACK_LEVEL)
    {'black_level': [64.0]}
    """
    import typer

    from ..cli._common import in_range, parse_sensor, read_options

    def text(key: str) -> str | None:
        value = (answers.get(key) or "").strip()
        return value or None

    raw_format = text("raw_format")
    if need == HEADLESS and raw_format is None:
        raise typer.BadParameter(
            "a headless dump needs its raw format: rpicam-raw prints it as 'Raw stream: WIDTHxHEIGHT stride BYTES "
            "format NAME'",
            param_hint="'--raw-format'",
        )
    stride = _whole_number(text("stride"), "--stride", in_range(1))
    frame = _whole_number(text("frame"), "--frame", in_range(0))
    options = read_options(
        None, text("black_level"), raw_format, text("size"), stride, frame, parse_sensor(text("sensor"))
    )
    return {key: value for key, value in options.items() if value is not None}


def _whole_number(text: str | None, option: str, check: Callable[[Any], Any]) -> int | None:
    """``text`` as the command line's integer option ``option`` takes it (click's message for what is not an integer),
    checked by its callback ``check``."""
    import typer

    if text is None:
        return None
    try:
        return int(check(int(text)))
    except ValueError:
        raise typer.BadParameter(f"{text!r} is not a valid integer.", param_hint=f"'{option}'") from None
    except typer.BadParameter as exc:
        raise typer.BadParameter(exc.message, param_hint=f"'{option}'") from None


def _sensor_names() -> list[str]:
    from ..sensors import SENSORS

    return sorted(name for name, entry in SENSORS.items() if not entry.monochrome)


class ReadOptionsDialog:
    """The dialog of one :class:`Request`: a form of its fields, a line saying why it is asked, OK and Cancel.

    Built without being shown: :meth:`run` shows it (modal) and returns the options, or None if cancelled. OK
    checks the answers (:func:`parse_answers`); a bad one keeps the dialog open with the command line's message in
    :attr:`error`.

    Attributes
    ----------
    dialog : QDialog
    fields : dict of str to QLineEdit or QComboBox
        The request's fields, by key of :data:`FIELDS` (the raw format and sensor are editable combo boxes).
    error : QLabel
        The message of the last refused answer (empty at first).
    options : dict or None
        The read_raw keyword arguments of the accepted answers.
    """

    def __init__(self, request: Request, parent: Any = None) -> None:
        from qtpy.QtWidgets import QComboBox, QDialog, QDialogButtonBox, QFormLayout, QLabel, QLineEdit, QVBoxLayout

        self.request = request
        self.options: dict[str, Any] | None = None
        self.dialog = QDialog(parent)
        what = "Reading options" if request.need == HEADLESS else "Black level"
        self.dialog.setWindowTitle(f"picamcal: {what} for {request.path.name}")
        layout = QVBoxLayout(self.dialog)
        self.reason = QLabel(request.reason)
        self.reason.setWordWrap(True)
        layout.addWidget(self.reason)
        form = QFormLayout()
        self.fields: dict[str, Any] = {}
        for key in REQUEST_FIELDS[request.need]:
            label, option = FIELDS[key]
            default = request.defaults.get(key, "")
            if key in ("raw_format", "sensor"):
                from ..raw.picamera2.formats import RAW_FORMATS

                box = QComboBox()
                box.setEditable(True)
                box.addItems(["", *(RAW_FORMATS if key == "raw_format" else _sensor_names())])
                box.setCurrentText(default)
                line = box.lineEdit()
                if line is not None:
                    line.setPlaceholderText(PLACEHOLDERS[key])
                widget: Any = box
            else:
                widget = QLineEdit(default)
                widget.setPlaceholderText(PLACEHOLDERS[key])
            widget.setToolTip(option)
            self.fields[key] = widget
            form.addRow(f"{label} ({option})", widget)
        layout.addLayout(form)
        self.error = QLabel("")
        self.error.setWordWrap(True)
        self.error.setStyleSheet("color: #e05050")
        layout.addWidget(self.error)
        buttons = QDialogButtonBox(QDialogButtonBox.Ok | QDialogButtonBox.Cancel)
        buttons.accepted.connect(self._ok)
        buttons.rejected.connect(self.dialog.reject)
        layout.addWidget(buttons)
        self.buttons = buttons

    def answers(self) -> dict[str, str]:
        """The text of each field, by key."""
        return {
            key: widget.currentText() if hasattr(widget, "currentText") else widget.text()
            for key, widget in self.fields.items()
        }

    def _ok(self) -> None:
        self.submit()

    def submit(self) -> bool:
        """Check the answers: accepted, the dialog closes with :attr:`options` set; refused, it stays open, the
        command line's message in :attr:`error`. Returns whether they were accepted."""
        import typer

        try:
            self.options = parse_answers(self.answers(), self.request.need)
        except typer.BadParameter as exc:
            self.error.setText(exc.format_message())
            return False
        self.error.setText("")
        self.dialog.accept()
        return True

    def run(self) -> dict[str, Any] | None:
        """Show the dialog until it is answered: the options, or None if cancelled."""
        accepted = self.dialog.exec_()
        return self.options if accepted else None


def ask_read_options(request: Request) -> dict[str, Any] | None:
    """Ask the user for what ``request`` needs: the :func:`picamcal.read_raw` keyword arguments of the answers, or
    None if the dialog was cancelled or cannot be shown (no Qt application: napari is not running).

    The reader calls this module's function by name, so tests replace it (``monkeypatch.setattr``) with one that
    returns answers at once.

    Examples
    --------
    What a test puts in its place, answering at once what a user would type:

    >>> def answer(request: Request) -> dict[str, Any] | None:
    ...     return parse_answers({"raw_format": "SBGGR10_CSI2P", "size": "320x240"}, request.need)
    >>> answer(Request(Path("frame.raw"), HEADLESS, "a headless dump"))
    {'raw_format': 'SBGGR10_CSI2P', 'size': (320, 240)}
    """
    try:
        from qtpy.QtWidgets import QApplication
    except Exception:  # no Qt binding at all
        return None
    if QApplication.instance() is None:
        return None
    parent = _main_window()
    return ReadOptionsDialog(request, parent).run()


def _main_window() -> Any:
    """napari's window of the current viewer, to centre the dialog on; None if there is none."""
    try:
        import napari

        viewer = napari.current_viewer()
        return None if viewer is None else viewer.window._qt_window
    except Exception:  # a viewer without a Qt window (headless): no parent
        return None


def describe_options(options: Mapping[str, Any]) -> str:
    """The command line options that stand for read_raw keyword arguments, for a layer's record and messages.

    Examples
    --------
    >>> describe_options({"raw_format": "SBGGR10_CSI2P", "size": (640, 480), "black_level": [64.0]})
    '--raw-format SBGGR10_CSI2P --size 640x480 --black-level 64'
    """
    parts = []
    for key, (_, option) in FIELDS.items():
        value = options.get(key)
        if value is None:
            continue
        if key == "size":
            text = f"{value[0]}x{value[1]}"
        elif key == "black_level":
            text = ",".join(f"{v:g}" if isinstance(v, float) and math.isfinite(v) else str(v) for v in value)
        else:
            text = str(value)
        parts.append(f"{option} {text}")
    return " ".join(parts)
