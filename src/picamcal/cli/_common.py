"""What the commands share: the app, the consoles, the options several commands take and their parsing.

Parsing turns a command-line value into what the library takes, or raises ``typer.BadParameter`` naming the option;
it checks only what the library cannot (the option's own syntax) or must not be asked too late (before hours of
work).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from typer.core import TyperGroup

from .._atomic import refuse_foreign, refuse_inputs_as_output
from .._version import __version__
from ..errors import OutputError, PicamcalError, closest
from ..modes import MODE_NAMES, Mode, parse_mode

if TYPE_CHECKING:  # rich is imported when a command prints, not for --help
    from rich.console import Console
    from rich.progress import Progress


class _Group(TyperGroup):
    """``picamcal``: its help lists each command with the whole first paragraph of its help, wrapped."""

    def get_help_option(self, ctx: Any) -> Any:
        """``--help``, false when not given: typer leaves it None, and checks a value that is not a bool with
        pydantic, whose import (0.1 s) would make ``picamcal COMMAND --help`` take half as long again."""
        option = super().get_help_option(ctx)
        if option is not None:
            option.default = False
        return option

    def format_help_text(self, ctx: Any, formatter: Any) -> None:
        """The app's help, then the order to run the commands in (:data:`WORKFLOW`), above the options and commands."""
        super().format_help_text(ctx, formatter)
        with formatter.section("Workflow, in this order"):
            formatter.write_dl([(f"{step}. {name}", what) for step, (name, what) in enumerate(WORKFLOW, 1)])

    def format_commands(self, ctx: Any, formatter: Any) -> None:
        rows = []
        for name in self.list_commands(ctx):
            command = self.get_command(ctx, name)
            if command is not None and not command.hidden:
                rows.append((name, " ".join((command.help or "").split("\n\n")[0].split())))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


#: The commands of the usual workflow, in the order to run them, with what each does: ``picamcal --help`` shows them
#: above the list of every command.
WORKFLOW = (
    ("inspect", "check what picamcal reads from your raw files"),
    ("calibrate", "measure the flat field and colour unmixing from references"),
    ("correct", "correct your images with the calibration"),
    ("export-tuning", "put the flat field into libcamera's tuning files"),
    ("report", "check the calibration: verdicts, maps, expected accuracy"),
)
# Plain help (click's), not rich's: typer's rich help imports markdown and syntax highlighting, which doubled the time
# every --help took; the content is the same, with paragraphs wrapped to the terminal.
app = typer.Typer(
    cls=_Group,
    help="Flat-field and colour-crosstalk calibration for Raspberry Pi cameras behind custom optics.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    rich_markup_mode=None,
)
MODE_HELP = "; ".join(f"{mode.value}: {mode.description}" for mode in Mode)
PatternOption = Annotated[
    str | None, typer.Option("--pattern", help="Override the files' Bayer order (RGGB, GBRG, BGGR, GRBG).")
]
BlackOption = Annotated[
    str | None, typer.Option("--black-level", help="Override the files' black level: one value or four (DN).")
]


#: No raw format holds more than 16 bits, so no black level reaches 2**16 DN.
MAX_BLACK_LEVEL = 65535


def parse_black_level(text: str | None) -> list[float] | None:
    """``--black-level``: one level for every site, or four, one per 2x2 site, in DN."""
    if text is None:
        return None
    try:
        values = [float(v) for v in text.replace(",", " ").split()]
    except ValueError:
        raise typer.BadParameter(f"{text!r} is not one number or four", param_hint="--black-level") from None
    if len(values) not in (1, 4):
        raise typer.BadParameter("give one value or four (one per 2x2 site)", param_hint="--black-level")
    if not all(math.isfinite(v) and 0 <= v <= MAX_BLACK_LEVEL for v in values):
        raise typer.BadParameter(
            f"{text!r}: each level must be a number from 0 to {MAX_BLACK_LEVEL} DN (no raw format has more than 16 "
            "bits)",
            param_hint="--black-level",
        )
    return values


def in_range(
    low: float | None = None,
    high: float | None = None,
    *,
    above: bool = False,
    below: bool = False,
    unit: str = "",
    why: str = "",
) -> Callable[[Any], Any]:
    """A typer callback refusing a number outside ``low``..``high`` (``above``/``below``: the bound itself excluded).

    NaN and infinities are always refused; click's own ranges let NaN through. The message names the value, the
    accepted range and, with ``why``, the reason for it.
    """
    if low is not None and high is not None:
        text = f"{'more than' if above else 'from'} {low:g} {'and less than' if below else 'to'} {high:g}"
    elif low is not None:
        text = f"more than {low:g}" if above else f"{low:g} or more"
    else:
        text = f"less than {high:g}" if below else f"{high:g} or less"
    accepted = f"{text}{unit}" + (f" ({why})" if why else "")

    def check(value: Any) -> Any:
        for number in value if isinstance(value, tuple) else () if value is None else (value,):
            fits = math.isfinite(number)
            fits = fits and (low is None or (number > low if above else number >= low))
            fits = fits and (high is None or (number < high if below else number <= high))
            if not fits:
                raise typer.BadParameter(f"{number:g} is outside the accepted range, {accepted}")
        return value

    return check


#: More worker processes than this per core only cost memory (each holds a frame and the calibration).
MAX_WORKERS_PER_CORE = 4
#: Colour temperatures of real light sources, from candle light (about 1900 K) to a clear blue sky (10000 K and more).
COLOUR_TEMPERATURE = in_range(1000, 20000, unit=" K", why="the colour temperature of a light source")

RawFormatOption = Annotated[
    str | None,
    typer.Option(
        "--raw-format",
        help="Read headless raw dumps (rpicam-raw, libcamera-raw) in this libcamera format: SBGGR10_CSI2P, "
        "SRGGB12_CSI2P, SGBRG16, ...",
    ),
]
RawSizeOption = Annotated[str | None, typer.Option("--size", help="With --raw-format: WIDTHxHEIGHT of a frame.")]
StrideOption = Annotated[
    int | None,
    typer.Option(
        "--stride", help="With --raw-format: bytes per row (default: libcamera's alignment).", callback=in_range(1)
    ),
]
FrameOption = Annotated[
    int | None,
    typer.Option(
        "--frame", help="With --raw-format: the frame of a multi-frame dump (0 = the first).", callback=in_range(0)
    ),
]


def parse_sensor(value: str | None) -> str | None:
    """``--sensor``: a registry sensor's name, or a sensor outside the registry, with one warning
    (:func:`picamcal.sensors.given_sensor`); a near miss of a registry name gets "did you mean"."""
    if value is None:
        return None
    from ..sensors import given_sensor

    try:
        return given_sensor(value)
    except PicamcalError as exc:
        raise typer.BadParameter(exc.problem, param_hint="--sensor") from None


RawSensorOption = Annotated[
    str | None,
    typer.Option(
        "--sensor",
        help="The sensor, for files that do not name it (picamera2's DNGs, headless dumps): imx219, imx477, ... A "
        "file of a size only one sensor has is taken as that sensor; another name is a sensor picamcal knows "
        "nothing of.",
        callback=parse_sensor,
    ),
]


def _parse_sensor_crop(value: str | None) -> tuple[int, int, int, int] | None:
    from ..geometry import parse_sensor_crop

    try:
        return parse_sensor_crop(value)
    except PicamcalError as exc:
        raise typer.BadParameter(exc.problem, param_hint="--sensor-crop") from None


def _parse_sensor_mode(value: str | None) -> str | None:
    from ..geometry import parse_sensor_mode

    try:
        parse_sensor_mode(value)
    except PicamcalError as exc:
        raise typer.BadParameter(exc.problem, param_hint="--sensor-mode") from None
    return value


SensorCropOption = Annotated[
    str | None,
    typer.Option(
        "--sensor-crop",
        help="X,Y,WIDTH,HEIGHT in full-sensor pixels, for files that do not say it: the sensor area the raw frames "
        "were read from (a mode picamcal's registry does not know); with --processed, the area the images show "
        "(picamera2's ScalerCrop). Default: what the file says, else the sensor's mode of the frame's size, else the "
        "whole sensor.",
        callback=_parse_sensor_crop,
    ),
]
SensorModeOption = Annotated[
    str | None,
    typer.Option(
        "--sensor-mode",
        help="WIDTHxHEIGHT[:BITS]: the sensor's mode the frames come from (docs/sensor-modes.md lists each "
        "sensor's), for files that do not say it; with --processed, the mode the camera ran in (its lens shading "
        "is computed for it; the area shown is libcamera's default crop for the image's size unless --sensor-crop "
        "gives it).",
        callback=_parse_sensor_mode,
    ),
]


def choice(value: str, choices: Sequence[str], option: str) -> str:
    """``value`` as one of ``choices``, compared case-insensitively; a near miss, of a whole choice or of one of its
    parts (``png`` of ``srgb-png``), gets "did you mean"."""
    by_key = {c.lower(): c for c in choices}
    if value.lower() in by_key:
        return by_key[value.lower()]
    near = closest(value, choices, parts=True)
    hint = f"; did you mean {near}?" if near else ""
    raise typer.BadParameter(f"{value!r} is not one of {', '.join(choices)}{hint}", param_hint=option)


def parse_mode_option(value: str) -> str:
    """``--mode`` as a mode's name; an old name (balance) is accepted with a warning."""
    try:
        return parse_mode(value.lower()).value
    except ValueError:
        return choice(value, MODE_NAMES, "--mode")  # not a mode: the usage error, with "did you mean"


def read_options(
    pattern: str | None,
    black_level: str | None,
    raw_format: str | None = None,
    size: str | None = None,
    stride: int | None = None,
    frame: int | None = None,
    sensor: str | None = None,
) -> dict[str, Any]:
    """The keyword arguments of read_raw that a command's reading options stand for."""
    from ..raw import PATTERNS

    if raw_format is None and (size is not None or stride is not None or frame is not None):
        raise typer.BadParameter("--size, --stride and --frame describe a headless dump: give --raw-format too")
    return {
        "pattern": None if pattern is None else choice(pattern, PATTERNS, "--pattern"),
        "black_level": parse_black_level(black_level),
        "raw_format": raw_format,
        "size": parse_size(size, "--size") if size is not None else None,
        "stride": stride,
        "frame": frame,
        "sensor": sensor,
    }


def reader(pattern: str | None, black_level: str | None, **headless: Any) -> Callable[[Path], Any]:
    """A read_raw with the command's overrides and headless-dump options applied."""
    from ..raw import read_raw

    options = read_options(pattern, black_level, **headless)

    def read(path: Path):
        return read_raw(path, **options)

    return read


@functools.cache
def console() -> Console:
    """Standard error, where the commands say what they do and did."""
    from rich.console import Console

    return Console(stderr=True)


def progress_bar(rate: bool = False) -> Progress:
    """A bar on stderr for a known number of steps; none off a terminal.

    With ``rate``, a task's field ``rate`` (text such as "3.1 files/s") and the time remaining are shown too.
    """
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn()]
    if rate:
        columns += [TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TimeRemainingColumn()]
    else:
        columns.append(TimeElapsedColumn())
    return Progress(
        *columns,
        console=console(),
        transient=True,
        disable=not console().is_terminal,  # off a terminal, rich would leave an empty line on stderr
    )


def _version(value: bool) -> None:
    if value:
        print(f"picamcal {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    # False, not None: typer checks a value that is not a bool with pydantic, whose import would double the time
    # of every command's --help.
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version.")
    ] = False,
) -> None:
    """Flat-field and colour-crosstalk calibration for Raspberry Pi cameras behind custom optics."""


def parse_colour_options(specs: Sequence[str] | None) -> dict[str, tuple[int, int, int]]:
    """``--colour NAME=R,G,B`` (repeatable) as name -> (R, G, B), 0-255 (:func:`picamcal.references.parse_colours`)."""
    from ..references import parse_colours

    try:
        return parse_colours(specs or ())
    except PicamcalError as exc:
        raise typer.BadParameter(exc.problem, param_hint="--colour") from None


def parse_tiles(text: str | None) -> tuple[int, int] | None:
    """``--mosaic COLUMNSxROWS`` as (columns, rows)."""
    if text is None:
        return None
    try:
        columns, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise typer.BadParameter(f"{text!r} is not COLUMNSxROWS", param_hint="--mosaic") from None
    return columns, rows


def parse_size(size: str | None, option: str = "--size") -> tuple[int, int] | None:
    """``WIDTHxHEIGHT`` as (width, height): even, and at least 16 pixels each."""
    if size is None:
        return None
    try:
        w, h = (int(v) for v in size.lower().split("x"))
    except ValueError:
        raise typer.BadParameter(f"{size!r} is not WIDTHxHEIGHT", param_hint=option) from None
    if w < 16 or h < 16 or w % 2 or h % 2:
        raise typer.BadParameter(f"{size!r}: width and height must be even and at least 16", param_hint=option)
    return w, h


def parse_numbers(text: str | None, count: int, option: str) -> tuple[float, ...] | None:
    """``count`` numbers separated by commas or spaces."""
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.replace(",", " ").split())
    except ValueError:
        values = ()
    if len(values) != count:
        raise typer.BadParameter(f"{text!r} is not {count} comma-separated numbers", param_hint=option)
    return values


def stdout_console() -> Console:
    """Standard output; not squeezed to 80 columns when it is a file or a pipe."""
    from rich.console import Console

    stdout = Console()
    return stdout if stdout.is_terminal else Console(width=200)


def check_output(
    path: Path, overwrite: bool, is_own: Callable[[Path], bool], what: str, inputs: Sequence[Path | None] = ()
) -> None:
    """Refuse an output before the work starts: an input of the command, or a file there without --overwrite, or
    one picamcal did not write (which not even --overwrite replaces)."""
    refuse_inputs_as_output(path, inputs)
    if path.exists() and not overwrite:
        raise OutputError("exists already (use --overwrite to replace it)", path)
    refuse_foreign(path, is_own, what)
