"""Messages that send the user the right way: every option a message names exists on the commands that can print it,
and the newcomer's stumbles of issue 31 (a black level asked for again, candidates that leave out the IMX219, a
folder that does not exist, a frame that is mostly clipped, a dark frame at other settings) each said rightly."""

from __future__ import annotations

import ast
import dataclasses
import re
import warnings
from pathlib import Path

import click
import numpy as np
import pytest
import typer

import picamcal
from picamcal import PicamcalWarning, RawImage, read_raw
from picamcal.cli import app, main
from picamcal.raw import to_picamera2
from picamcal.raw.packing import pack
from picamcal.simulate import make_camera, simulate_references, simulate_target

SOURCE = Path(picamcal.__file__).parent
OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def _command_options() -> dict[str, set[str]]:
    """Each command's long options, as typer builds them."""
    group = typer.main.get_command(app)
    context = click.Context(group)
    options = {}
    for name in group.list_commands(context):
        command = group.get_command(context, name)
        names = {o for p in command.params for o in (*p.opts, *p.secondary_opts) if o.startswith("--")}
        options[name] = names | {"--help"}
    return options


OPTIONS = _command_options()
#: The commands that read raw images with the reading options (--pattern, --black-level, --sensor, --raw-format, ...):
#: what the raw readers and the sensor registry say can reach any of them.
READING = frozenset(name for name, options in OPTIONS.items() if "--black-level" in options)
#: Where each library module's messages can be printed (the longest prefix wins), by the command line.
PRINTED_BY: dict[str, frozenset[str]] = {
    "raw/": READING,
    "sensors.py": READING,
    "raw/processed.py": frozenset({"correct"}),  # read_processed: correct --processed (inspect keeps the raw error)
    "describe.py": frozenset({"inspect"}),
    "calibrate.py": frozenset({"calibrate"}),
    "references.py": frozenset({"calibrate"}),
    "correct.py": frozenset({"correct"}),
    "batch/": frozenset({"correct"}),
    "calibration/fitting.py": frozenset({"calibrate"}),  # the noise-penalty bound
}
#: Functions whose messages only some of those commands can print.
FUNCTIONS_PRINTED_BY: dict[tuple[str, str], frozenset[str]] = {
    # Its messages about a crop or a mode echo the option given: only commands that take it can print them.
    ("raw/model.py", "raw_geometry"): frozenset(n for n, o in OPTIONS.items() if "--sensor-crop" in o),
    ("raw/picamera2/dump.py", "write_picamera2_npy"): frozenset({"simulate", "demo"}),  # they write .npy dumps
}
#: Options of other programs that messages name, with the program that has them.
OTHER_PROGRAMS = {"--awbgains": "rpicam-apps", "--list-cameras": "rpicam-hello", "--raw": "raspistill"}


def _messages(tree: ast.Module) -> list[tuple[str | None, str]]:
    """(enclosing function, text) of every string literal that is not a docstring, a typer option's name or help."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                skip.add(id(first.value))
        if isinstance(node, ast.Call):
            name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
            if name in ("Option", "Argument"):
                skip.update(id(sub) for sub in ast.walk(node))
    found: list[tuple[str | None, str]] = []

    def visit(node: ast.AST, function: str | None) -> None:
        for child in ast.iter_child_nodes(node):
            inner = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else function
            if isinstance(child, ast.Constant) and isinstance(child.value, str) and id(child) not in skip:
                found.append((function, child.value))
            visit(child, inner)

    visit(tree, None)
    return found


def _cli_printers(tree: ast.Module) -> dict[str, frozenset[str]]:
    """For a module of picamcal.cli: each function and the commands that can print its messages (a command's own, a
    helper's those of the commands of the module that call it)."""
    commands: dict[str, str] = {}
    calls: dict[str, set[str]] = {}
    for node in tree.body:
        if not isinstance(node, ast.FunctionDef):
            continue
        for decorator in node.decorator_list:
            if isinstance(decorator, ast.Call) and getattr(decorator.func, "attr", "") == "command":
                commands[node.name] = decorator.args[0].value if decorator.args else node.name.replace("_", "-")
        calls[node.name] = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}
    printers = {function: frozenset({command}) for function, command in commands.items()}
    for function in calls:
        if function not in commands:
            printers[function] = frozenset(
                commands[c] for c, names in calls.items() if function in names and c in commands
            )
    return printers


def _named_command(text: str, start: int) -> str | None:
    """The picamcal command a message names just before an option (``correct takes them with --processed``)."""
    before = text[max(0, start - 40) : start]
    named = [(m.start(), m.group(0)) for m in re.finditer(r"[a-z-]+", before) if m.group(0) in OPTIONS]
    return named[-1][1] if named else None


def test_every_option_a_message_names_exists_on_each_command_that_can_print_it():
    """The messages of the raw readers, the sensor registry, inspect, calibrate, correct and the command modules
    name only options of the commands that can print them (a message that names a command, "correct takes them with
    --processed", is checked against that command); every other message names an option of some command, or of the
    other program it names."""
    every = set().union(*OPTIONS.values())
    wrong = []
    checked = set()
    for path in sorted(SOURCE.rglob("*.py")):
        module = path.relative_to(SOURCE).as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"))
        printers = _cli_printers(tree) if module.startswith("cli/") else {}
        prefixes = [prefix for prefix in PRINTED_BY if module.startswith(prefix) and not module.startswith("raw/dng/")]
        by_module = PRINTED_BY[max(prefixes, key=len)] if prefixes else None
        for function, text in _messages(tree):
            for match in OPTION.finditer(text):
                option = match.group(0)
                if option in OTHER_PROGRAMS:  # rpicam-apps' --awbgains, raspistill's --raw, ...
                    continue
                named = _named_command(text, match.start())
                if named is not None:
                    commands = frozenset({named})
                elif module.startswith("cli/"):
                    commands = printers.get(function or "", frozenset())
                else:
                    commands = FUNCTIONS_PRINTED_BY.get((module, function or ""), by_module) or frozenset()
                missing = sorted(c for c in commands if option not in OPTIONS[c])
                checked.update((module, option, command) for command in commands)
                if missing or option not in every:
                    wrong.append(f"{module} {function}: {option} ({', '.join(missing) or 'no command'}): {text!r:.80}")
    assert wrong == []
    # The scan sees the messages of issue 31: a missing black level, in each command that reads raw files.
    assert {("raw/model.py", "--black-level", command) for command in READING} <= checked
    assert ("calibrate.py", "--black", "calibrate") in checked and ("raw/model.py", "--black", "inspect") not in checked
    assert not set(OTHER_PROGRAMS) & every  # an option of another program is never one of picamcal's


def _run(capfd, *argv: object) -> tuple[int, list[str], str]:
    """``picamcal ARGV`` in this process: its exit status, the non-empty lines of stderr, and stdout."""
    with pytest.raises(SystemExit) as exit_:
        main([str(a) for a in argv])
    captured = capfd.readouterr()
    return int(exit_.value.code or 0), [line for line in captured.err.splitlines() if line.strip()], captured.out


@pytest.mark.parametrize("command", ["calibrate", "inspect"])
def test_the_black_level_message_of_a_headless_dump_names_options_of_the_command(command, tmp_path, capfd):
    """A dump of no known sensor and no black level: calibrate refuses it, inspect notes it, each naming options it
    has (inspect has no dark frame option; calibrate's is --black). Before, both said "--black FILE"."""
    white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    dump = tmp_path / "frame.raw"
    dump.write_bytes(pack(white.bayer, 10, 416).tobytes())
    headless = ["--raw-format", "SBGGR10_CSI2P", "--size", "320x240"]
    argv = {
        "calibrate": ["calibrate", "--white", dump, *headless, "--out", tmp_path / "cal.npz"],
        "inspect": ["inspect", dump, *headless],
    }[command]
    code, err, out = _run(capfd, *argv)
    assert code == (2 if command == "calibrate" else 0)
    said = " ".join(err) + out
    named = set(OPTION.findall(said))
    assert "--black-level" in named and named <= OPTIONS[command], named - OPTIONS[command]
    assert ("--black" in named) == (command == "calibrate")


# ---------------------------------------------------------------------------------------------- black levels
@pytest.fixture(scope="module")
def dumps(tmp_path_factory) -> Path:
    """An IMX298 as the user's camera: the simulator's IMX219 at 320x240, dumped as rpicam-raw would (SBGGR10_CSI2P,
    stride 416), a size no registry sensor has."""
    folder = tmp_path_factory.mktemp("imx298")
    camera = make_camera("imx219", size=(320, 240))
    frames = {**simulate_references(camera, seed=4), "target": simulate_target(camera, seed=5)[0]}
    for role, raw in frames.items():
        (folder / f"{role}.raw").write_bytes(pack(raw.bayer, 10, 416).tobytes())
    (folder / "batch").mkdir()
    for k in range(3):
        (folder / "batch" / f"scan{k}.raw").write_bytes((folder / "target.raw").read_bytes())
    return folder


HEADLESS = ("--raw-format", "SBGGR10_CSI2P", "--size", "320x240", "--sensor", "imx298")


@pytest.mark.slow
def test_correct_takes_the_black_level_the_calibration_was_made_with(dumps, tmp_path, capfd, monkeypatch):
    """Calibrated with --black-level 64, the IMX298's dumps are corrected without it, as with it: one warning says
    so, once for a batch of three, with --workers 0 as with a pool."""
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)
    cal = tmp_path / "cal.npz"
    refs = [f"--{role}={dumps / f'{role}.raw'}" for role in ("white", "red", "green", "blue")]
    code, _, _ = _run(capfd, "calibrate", *refs, *HEADLESS, "--black-level", "64", "--out", cal)
    assert code == 0
    code, _, _ = _run(
        capfd, "correct", cal, dumps / "target.raw", *HEADLESS, "--black-level", "64", "--out", tmp_path / "a"
    )
    assert code == 0
    code, err, _ = _run(capfd, "correct", cal, dumps / "target.raw", *HEADLESS, "--out", tmp_path / "b")
    assert code == 0, err
    said = [line for line in err if "give no black level" in line]
    assert said == [
        "picamcal: warning: frames that give no black level are corrected with the calibration's, 64 DN (from its "
        "references): right if they were taken at its settings; else give --black-level"
    ]
    import tifffile

    # The same numbers as with the level given (the same float32 maths on the same inputs: compared exactly).
    np.testing.assert_array_equal(
        tifffile.imread(tmp_path / "b" / "target.tiff"), tifffile.imread(tmp_path / "a" / "target.tiff")
    )
    for workers in ("0", "2"):
        out = tmp_path / f"batch{workers}"
        code, err, _ = _run(capfd, "correct", cal, dumps / "batch", *HEADLESS, "--workers", workers, "--out", out)
        assert code == 0 and len(list(out.glob("*.tiff"))) == 3, err
        assert sum("give no black level" in line for line in err) == 1, err


def test_a_1920x1080_sbggr10_dump_may_be_the_imx219s(tmp_path):
    """The IMX219's 1920x1080 mode is a crop of its sensor: its commonest source is among the candidates, with the
    other sensors that have the size and give 10 bits."""
    dump = tmp_path / "hd.raw"
    dump.write_bytes(pack(np.full((1080, 1920), 300, np.uint16), 10, 2400).tobytes())
    with pytest.warns(PicamcalWarning, match="could be from the ov5647, imx219, imx290"):
        raw = read_raw(dump, raw_format="SBGGR10_CSI2P", size=(1920, 1080))
    assert raw.sensor is None and "imx219" in raw.metadata["sensor_candidates"]
    with pytest.raises(picamcal.RawFormatError, match=r"could be from the ov5647, imx219, .*give --sensor NAME"):
        picamcal.raw.model.require_black_level(raw)


# ---------------------------------------------------------------------------------------------- outputs
@pytest.mark.slow
@pytest.mark.parametrize("command", ["calibrate", "export-tuning", "export-lst", "report", "correct"])
def test_out_creates_the_folders_it_lies_in(command, tmp_path, capfd):
    """``--out newdir/sub/NAME`` makes newdir and sub (it failed with "No such file or directory")."""
    from picamcal.simulate import simulate_run

    refs = simulate_run(tmp_path / "sim", "imx219", size=(96, 64), seed=1)
    cal = tmp_path / "cal.npz"
    assert _run(capfd, "calibrate", tmp_path / "sim", "--out", cal)[0] == 0
    out = tmp_path / "new" / "sub" / {"calibrate": "c.npz", "export-lst": "t.npy"}.get(command, "out")
    argv = {
        "calibrate": ["calibrate", tmp_path / "sim"],
        "export-tuning": ["export-tuning", cal],
        "export-lst": ["export-lst", cal],
        "report": ["report", cal],
        "correct": ["correct", cal, refs["target"]],
    }[command]
    code, err, _ = _run(capfd, *argv, "--out", out)
    assert code == 0, err
    assert out.exists()


def test_an_output_whose_folder_cannot_be_made_is_one_line(tmp_path, capfd):
    (tmp_path / "file").write_text("not a folder")
    code, err, _ = _run(capfd, "export-lst", tmp_path / "missing.npz", "--out", tmp_path / "file" / "sub" / "t.npy")
    assert code == 2 and len(err) == 1 and err[0].startswith("picamcal: error: ")
    assert (tmp_path / "file").read_text() == "not a folder"


def test_make_parents_creates_and_never_removes(tmp_path):
    from picamcal._atomic import make_parents

    make_parents(tmp_path / "a" / "b" / "cal.npz")
    (tmp_path / "a" / "keep.txt").write_text("mine")
    make_parents(tmp_path / "a" / "b" / "other.npz")  # exists already: nothing changes
    assert (tmp_path / "a" / "b").is_dir() and (tmp_path / "a" / "keep.txt").read_text() == "mine"
    (tmp_path / "f").write_text("x")
    with pytest.raises(picamcal.errors.OutputError, match=r"cannot create its folder .*: a file is in the way"):
        make_parents(tmp_path / "f" / "cal.npz")


# ---------------------------------------------------------------------------------------------- correct and calibrate
def test_a_frame_76_percent_clipped_is_said_in_one_line_and_a_few_highlights_are_not():
    camera = make_camera("imx219", size=(320, 240))
    cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    target = simulate_target(camera, seed=2)[0]
    bayer = target.bayer.copy()
    bayer[np.random.default_rng(0).random(bayer.shape) < 0.76] = target.white_level
    clipped = dataclasses.replace(target, bayer=bayer, metadata={**target.metadata, "path": "scan.dng"})
    with pytest.warns(PicamcalWarning) as caught:
        picamcal.correct(clipped, cal, binned=True)
    (message,) = [str(w.message) for w in caught]
    assert re.fullmatch(
        r"scan\.dng: 76(\.\d)? % of its pixels are at the white level \(1023\): .*reduce the exposure", message
    )
    bayer = target.bayer.copy()
    bayer.flat[::200] = target.white_level  # 0.5 %: highlights
    with warnings.catch_warnings():
        warnings.simplefilter("error", PicamcalWarning)
        picamcal.correct(dataclasses.replace(target, bayer=bayer), cal, binned=True)


def test_a_dark_frame_at_another_exposure_or_gain_than_the_white_is_warned_of():
    camera = make_camera("imx219", size=(320, 240))
    refs = simulate_references(camera, seed=1)
    white = dataclasses.replace(refs["white"], metadata={**refs["white"].metadata, "exposure_time_s": 0.010})

    def dark(**settings: float) -> RawImage:
        return dataclasses.replace(refs["black"], metadata={**refs["black"].metadata, "path": "dark.dng", **settings})

    with pytest.warns(PicamcalWarning) as caught:
        picamcal.calibrate(white, black=dark(exposure_time_s=0.001))
    assert [str(w.message) for w in caught] == [
        "dark.dng: the dark frame's exposure time, 1 ms, differs from the white's, 10 ms, by more than 10 %: its "
        "black (dark current, offsets) is not the white's; take the dark frame at the white's settings"
    ]
    gains = {"analogue_gain": 1.0}
    white = dataclasses.replace(white, metadata={**white.metadata, **gains})
    with pytest.warns(PicamcalWarning, match="the dark frame's analogue gain, 4, differs from the white's, 1,"):
        picamcal.calibrate(white, black=dark(exposure_time_s=0.010, analogue_gain=4.0))
    with warnings.catch_warnings():  # 5 % apart: within the tolerance
        warnings.simplefilter("error", PicamcalWarning)
        picamcal.calibrate(white, black=dark(exposure_time_s=0.0105, analogue_gain=1.0))


# ---------------------------------------------------------------------------------------------- picamera2
@pytest.mark.parametrize(("packed", "bits"), [(True, 10), (False, 16)])
def test_from_picamera2_knows_a_full_imx219_frame_by_its_size(packed, bits):
    """``from_picamera2(array, camera_configuration()["raw"], metadata)``: no model and no sensor bit depth given,
    the size names the IMX219, and a 16-bit buffer (a Pi 5's SBGGR16, left-justified) holds its 10 bits."""
    mosaic = np.random.default_rng(1).integers(64, 1023, (2464, 3280), dtype=np.uint16)
    raw = RawImage(mosaic, "BGGR", 64, 1023, 10)
    array, config, metadata = to_picamera2(raw, packed=packed)
    stream = dict(config["raw"])
    if bits == 16:  # as a Pi 5 gives it: the 10 bits at the top of 16
        shifted = raw.bayer.astype("<u2") << 6
        stride = -(-2 * 3280 // 64) * 64
        array = np.zeros((2464, stride), np.uint8)
        array[:, : 2 * 3280] = shifted.view(np.uint8).reshape(2464, -1)
        stream = {"format": "SBGGR16", "size": (3280, 2464), "stride": stride, "framesize": stride * 2464}
    with pytest.warns(PicamcalWarning, match="taken as the imx219, the one sensor of that size"):
        got = picamcal.from_picamera2(array, stream, metadata)
    assert (got.sensor, got.bit_depth, got.white_level) == ("imx219", 10, 1023)
    np.testing.assert_array_equal(got.bayer, mosaic)


# ---------------------------------------------------------------------------------------------- inspect
@pytest.fixture
def cli(monkeypatch, capfd):
    def run(*args: object) -> tuple[int, list[str], str]:
        monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)
        monkeypatch.setenv("COLUMNS", "250")
        with pytest.raises(SystemExit) as exit_:
            main([str(arg) for arg in args])
        captured = capfd.readouterr()
        return exit_.value.code, [line for line in captured.err.splitlines() if line.strip()], captured.out

    return run


def test_inspect_shows_the_signal_calls_a_frame_at_black_dark_and_says_a_size_note_once(cli, tmp_path):
    from picamcal.raw.npz import write_npz

    rng = np.random.default_rng(3)
    for name, level in (("dark", 60), ("white", 700), ("grey", 300)):  # the Global Shutter camera's size
        mosaic = rng.integers(level - 3, level + 4, (1088, 1456), dtype=np.uint16)
        write_npz(tmp_path / f"{name}.npz", RawImage(mosaic, "BGGR", 60, 1023, 10))
    code, err, out = cli("inspect", tmp_path)
    assert (code, err) == (0, [])
    rows = {line.split("│")[1].strip(): line for line in out.splitlines() if ".npz" in line and "│" in line}
    assert "0.0 dark" in rows["dark.npz"] and " 640 " in rows["white.npz"] and " 240 " in rows["grey.npz"]
    assert out.count("taken as the imx296") == 1
    assert "dark.npz and 2 more: frames of 1456x1088 that do not name their sensor are taken as the imx296" in out
    code, _, out = cli("inspect", tmp_path, "--json")
    import json

    records = {Path(r["path"]).name: r for r in json.loads(out)}
    assert records["dark.npz"]["dark"] is True and records["white.npz"]["dark"] is False
    assert records["white.npz"]["signal_dn"] == pytest.approx(640, abs=1)  # 700 +- 3 over 60


def test_inspect_shows_the_iso_a_file_gives_in_the_gain_column(cli, tmp_path):
    white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    meta = {k: v for k, v in white.metadata.items() if k != "analogue_gain"}
    picamcal.write_dng(tmp_path / "iso.dng", dataclasses.replace(white, metadata={**meta, "iso": 100}))
    code, _, out = cli("inspect", tmp_path / "iso.dng")
    row = next(line for line in out.splitlines() if "iso.dng" in line)
    assert code == 0 and row.split("│")[-2].strip() == "ISO 100"  # was "-"


@pytest.mark.parametrize("hidden", [False, True])
def test_inspect_of_an_empty_folder_is_one_error_line_as_its_help_says(cli, tmp_path, hidden):
    folder = tmp_path / "captures"
    folder.mkdir()
    if hidden:
        (folder / ".DS_Store").write_bytes(b"\0")
    code, err, out = cli("inspect", folder)
    assert (code, out) == (2, "")
    what = "it holds only hidden files and folders (.DS_Store), which are not read" if hidden else "it is empty"
    assert err == [f"picamcal: error: {folder}: no images in this folder: {what}"]
    group = typer.main.get_command(app)
    help_text = " ".join(group.get_command(click.Context(group), "inspect").help.split())
    assert "A folder that is empty or holds only files that are not images" in help_text
    assert "exit status 2" in help_text


# ---------------------------------------------------------------------------------------------- docs
@pytest.mark.slow
def test_the_full_size_demo_table_of_getting_started_is_the_demo_s(cli, tmp_path):
    """Getting started shows what ``picamcal demo`` prints at full size: the same columns and modes (its figures
    are from a full-size run, which takes minutes; here a small one gives the table's layout)."""
    code, _, out = cli("demo", "--size", "96x64", "--out", tmp_path / "demo")
    assert code == 0
    lines = out.splitlines()
    heading = next(line for line in lines if "┃" in line and "mode" in line)
    columns = [cell.strip() for cell in heading.strip("┃ ").split("┃")]
    modes = [line.split("│")[1].strip() for line in lines if line.startswith("│")]
    text = (Path(__file__).resolve().parents[1] / "docs" / "getting-started.md").read_text(encoding="utf-8")
    section = text[text.index("### At full size") :]
    rows = [line.strip("|").split("|") for line in section.splitlines() if line.startswith("| ")]
    assert [cell.strip() for cell in rows[0]] == columns
    assert [row[0].strip() for row in rows[1:]] == modes == ["uncorrected", "flat", "centre", "pure"]
