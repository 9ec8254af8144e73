"""One run of the ``picamcal`` command: every error becomes one line on stderr and exit status 2, here and nowhere
else; warnings and what libraries print are held back until the command ends, then printed, or folded into that
one line when it fails."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

import typer

from ..errors import PicamcalError, PicamcalWarning
from ._common import app


@dataclass
class _Held:
    """What a command's run holds back: the warnings given (``caught``) and the lines libraries logged."""

    caught: list[warnings.WarningMessage] = field(default_factory=list)
    log: list[str] = field(default_factory=list)

    @property
    def warnings(self) -> list[str]:
        """picamcal's own warnings, each once (a batch's files give the same one each); other libraries' are not
        picamcal's to print."""
        return list(dict.fromkeys(str(w.message) for w in self.caught if issubclass(w.category, PicamcalWarning)))

    def release(self) -> None:
        """Print what was held back, when the command did not fail."""
        for line in self.log:
            print(line, file=sys.stderr)
        for message in self.warnings:
            print(f"picamcal: warning: {message}", file=sys.stderr)

    def fail(self, message: str) -> NoReturn:
        """The one error line every problem ends in (never wrapped, whatever the terminal), and exit status 2.

        Warnings given before the error are folded into it, so that the line stays one; the libraries' lines are
        their own view of the same problem and are dropped.
        """
        if self.warnings:
            message += f" (after {len(self.warnings)} warning(s): {'; '.join(self.warnings)})"
        print(f"picamcal: error: {' '.join(message.split())}", file=sys.stderr)
        sys.exit(2)


class _HoldLog(logging.Handler):
    def __init__(self, lines: list[str]) -> None:
        super().__init__(logging.WARNING)
        self.lines = lines

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(f"{record.name}: {record.getMessage()}")


@contextlib.contextmanager
def _holding() -> Iterator[_Held]:
    """Hold back warnings and log records for one command, and silence what C libraries write to stderr.

    The warning filters stay as they are (a warning given once per place stays once); ``record`` only keeps what
    passes them, and everything is put back when the command ends.
    """
    held = _Held()
    # picamcal says what is wrong with a file in its own one line; tifffile would log its own view of it too.
    logging.getLogger("tifffile").setLevel(logging.CRITICAL)
    handler = _HoldLog(held.log)
    logging.getLogger().addHandler(handler)
    try:
        with warnings.catch_warnings(record=True) as caught, _silence_native_stderr():
            held.caught = caught
            yield held
    finally:
        logging.getLogger().removeHandler(handler)


@contextlib.contextmanager
def _silence_native_stderr() -> Iterator[None]:
    """Drop what C libraries write straight to file descriptor 2 (LibRaw's "Unexpected end of file").

    picamcal reports the same problems in its own words. Descriptor 2 points at the null device while the command
    runs, and ``sys.stderr`` (picamcal's own lines, rich's progress) at a duplicate of the real one. Nothing changes
    when ``sys.stderr`` is not descriptor 2 (a test capturing it).
    """
    try:
        native = sys.stderr.fileno() == 2
    except (AttributeError, OSError, ValueError):
        native = False
    if not native:
        yield
        return
    sys.stderr.flush()
    python_stderr = sys.stderr
    saved = os.dup(2)
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 2)
    os.close(null)
    sys.stderr = open(  # closed below, after descriptor 2 is restored
        saved, "w", encoding=python_stderr.encoding, errors=python_stderr.errors, buffering=1, closefd=False
    )
    try:
        yield
    finally:
        sys.stderr.flush()
        sys.stderr.close()
        sys.stderr = python_stderr
        os.dup2(saved, 2)
        os.close(saved)


def _spread_role_options(args: list[str]) -> list[str]:
    """``calibrate --white a.dng b.dng`` as ``--white a.dng --white b.dng``: several frames per reference role.

    Click options take one value each; the values after a role option that name existing files (not folders,
    not options) are taken as more frames of that role. ``--help`` shows the help whatever else is given, so it is
    shown without reading the roles (whose module imports numpy).
    """
    if "calibrate" not in args[:1] or "--help" in args:
        return args
    from ..references import ROLES

    roles = {f"--{role}" for role in ROLES}
    out: list[str] = []
    role = None
    for arg in args:
        if arg in roles:
            role = arg
        elif role is not None and out and out[-1] != role and not arg.startswith("-") and Path(arg).is_file():
            out.append(role)
        elif arg.startswith("-") or out[-1:] != [role]:
            role = None
        out.append(arg)
    return out


def _click_exceptions() -> Any:
    """click's exceptions module: typer 0.2x carries its own copy of click."""
    import importlib

    try:
        return importlib.import_module("typer._click.exceptions")
    except ImportError:
        return importlib.import_module("click.exceptions")


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``picamcal`` command: runs the app and turns every error into one line and exit status 2."""
    click = _click_exceptions()
    args = _spread_role_options(list(sys.argv[1:] if argv is None else argv))
    with _holding() as held:
        try:
            code = app(args=args, prog_name="picamcal", standalone_mode=False)
        except click.UsageError as exc:
            command = exc.ctx.command_path if exc.ctx is not None else "picamcal"
            if not args:  # no command given: the error carries the help (click's NoArgsIsHelpError); show it first
                print(exc.format_message())
                held.fail(f"give a command (see {command} --help)")
            held.fail(f"{exc.format_message().rstrip('.')} (see {command} --help)")
        except click.ClickException as exc:
            held.fail(exc.format_message())
        except typer.Abort:
            held.release()
            print("picamcal: interrupted", file=sys.stderr)
            sys.exit(130)
        except PicamcalError as exc:
            held.fail(str(exc))
        held.release()
    sys.exit(code if isinstance(code, int) else 0)
