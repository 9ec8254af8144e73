"""The NeoPixel illuminator firmware (firmware/neopixel_illuminator): parser, builds, and the running firmware.

Three levels, each skipped with its reason when its tools are missing:

- the protocol parser (protocol.c) compiled by the host's C compiler into a shared library and driven through
  ctypes, against a Python statement of the protocol (needs make and gcc);
- the firmware built with avr-gcc for the Uno (ATmega328P) and the Mega (ATmega2560), and the sketch built the
  Arduino IDE's way by arduino-builder with the Arduino core (Debian: gcc-avr, avr-libc; arduino-builder,
  arduino-core-avr);
- the built firmware running in simavr, its UART on a pseudo-terminal and its LED pin decoded: the protocol
  spoken by the real code, through pyserial and picamcal's SerialIlluminator (Debian: simavr, libsimavr-dev).
"""

from __future__ import annotations

import ctypes
import queue
import re
import shutil
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from picamcal.acquire import serial_illuminator
from picamcal.acquire.serial_illuminator import SerialIlluminator

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware" / "neopixel_illuminator"
HEADER = (FIRMWARE / "protocol.h").read_text()


def header_define(name: str) -> str:
    match = re.search(rf"#define {name} (.+)", HEADER)
    assert match, f"protocol.h defines no {name}"
    value = match.group(1).strip()
    return value[1:-1] if value.startswith('"') else value


LINE_MAX = int(header_define("ILLUMINATOR_LINE_MAX"))
DONE = header_define("ILLUMINATOR_REPLY_DONE")
ID = header_define("ILLUMINATOR_REPLY_ID")
ERROR = header_define("ILLUMINATOR_REPLY_ERROR")
NONE, SET_RGB, IDENTIFY, FAILED = 0, 1, 2, 3

# One CPU cycle of the 16 MHz boards, in nanoseconds.
CYCLE_NS = 62.5


def missing(*tools: str) -> list[str]:
    return [tool for tool in tools if shutil.which(tool) is None]


def make(*args: str) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(["make", "-C", str(FIRMWARE), *args], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    return result


def test_firmware_replies_are_the_papers_and_the_hosts():
    formats = (ROOT / "tests" / "data" / "FORMATS.md").read_text()  # a copy of ../shared/reference/FORMATS.md
    assert f"`{ERROR}`" in formats and f"`{DONE}`" in formats
    assert DONE == serial_illuminator.DONE_REPLY
    assert ID.startswith(serial_illuminator.FIRMWARE_ID_PREFIX + " ")
    assert ERROR.startswith(serial_illuminator.ERROR_PREFIX)


# ---- the parser on the host -----------------------------------------------------------------------------------


class Parser(ctypes.Structure):
    _fields_ = [("line", ctypes.c_char * (LINE_MAX + 1)), ("length", ctypes.c_uint8), ("discard", ctypes.c_uint8)]


@pytest.fixture(scope="module")
def protocol(tmp_path_factory) -> ctypes.CDLL:
    if absent := missing("make", "gcc"):
        pytest.skip(f"the host parser test needs {' and '.join(absent)}")
    build = tmp_path_factory.mktemp("host")
    make("protocol-lib", f"HOST_BUILD={build}")
    library = ctypes.CDLL(str(build / "libilluminator_protocol.so"))
    library.illuminator_parser_feed.argtypes = [ctypes.POINTER(Parser), ctypes.c_char, ctypes.POINTER(ctypes.c_uint8)]
    library.illuminator_parser_feed.restype = ctypes.c_int
    library.illuminator_reply.argtypes = [ctypes.c_int]
    library.illuminator_reply.restype = ctypes.c_char_p
    return library


def feed(protocol: ctypes.CDLL, stream: bytes) -> list[tuple[int, tuple[int, int, int] | None]]:
    """Every command the parser completes while reading ``stream``, with its colour for set_rgb."""
    parser = Parser()
    protocol.illuminator_parser_init(ctypes.byref(parser))
    rgb = (ctypes.c_uint8 * 3)(7, 7, 7)
    commands = []
    for byte in stream:
        command = protocol.illuminator_parser_feed(ctypes.byref(parser), bytes([byte]), rgb)
        if command != NONE:
            commands.append((command, tuple(rgb) if command == SET_RGB else None))
    return commands


@pytest.mark.parametrize(
    ("stream", "expected"),
    [
        (b"set_rgb 255 128 0\n", [(SET_RGB, (255, 128, 0))]),
        (b"set_rgb 1 2 3\r\n", [(SET_RGB, (1, 2, 3))]),  # the "\r\n" leaves an empty line: ignored
        (b"set_rgb 1 2 3\r", [(SET_RGB, (1, 2, 3))]),
        (b" \tset_rgb\t0   0 0  \n", [(SET_RGB, (0, 0, 0))]),
        (b"set_rgb 007 010 00255\n", [(SET_RGB, (7, 10, 255))]),
        (b"id?\n", [(IDENTIFY, None)]),
        (b"  id?  \r\n", [(IDENTIFY, None)]),
        (b"\n\r\n\r\r", []),
        (b"set_rgb 1 2 3", []),  # no line end yet
        (b"id?\nset_rgb 9 8 7\nnonsense\n", [(IDENTIFY, None), (SET_RGB, (9, 8, 7)), (FAILED, None)]),
    ],
)
def test_parser_accepts_the_protocol(protocol, stream, expected):
    assert feed(protocol, stream) == expected


@pytest.mark.parametrize(
    "line",
    [
        b"set_rgb 256 0 0",
        b"set_rgb 0 0 1000",
        b"set_rgb 99999999999999999999 0 0",  # would overflow a 16-bit or 32-bit accumulator
        b"set_rgb 0 0",
        b"set_rgb 0 0 0 0",
        b"set_rgb -1 0 0",
        b"set_rgb +1 0 0",
        b"set_rgb 1a 0 0",
        b"set_rgb 1.0 0 0",
        b"set_rgb 0x10 0 0",
        b"set_rgbx 1 2 3",
        b"set_rgb1 2 3",
        b"SET_RGB 1 2 3",
        b"set_rgb",
        b"id? 1",
        b"id",
        b"hello",
        b" ",
        b"set_rgb 1 2 3\x00",  # a NUL must not end the line early
        b"set_rgb 1 2 3\xff",
        b"set_rgb 1 2 \x1b3",
    ],
)
def test_parser_answers_the_error_line_to_anything_else(protocol, line):
    assert feed(protocol, line + b"\n") == [(FAILED, None)]


def test_parser_takes_lines_up_to_its_buffer_and_refuses_longer_ones(protocol):
    longest = b"set_rgb" + b" " * (LINE_MAX - len(b"set_rgb1 2 3")) + b"1 2 3"
    assert len(longest) == LINE_MAX
    assert feed(protocol, longest + b"\n") == [(SET_RGB, (1, 2, 3))]
    assert feed(protocol, b" " + longest + b"\n") == [(FAILED, None)]


def test_parser_recovers_after_an_overlong_line(protocol):
    stream = b"set_rgb " + b"0" * 500 + b" 0 0\nset_rgb 4 5 6\n"
    assert feed(protocol, stream) == [(FAILED, None), (SET_RGB, (4, 5, 6))]


def test_parser_leaves_the_colour_alone_on_errors(protocol):
    # feed() starts from (7, 7, 7): a refused line must not have written any part of it
    parser = Parser()
    rgb = (ctypes.c_uint8 * 3)(7, 7, 7)
    for byte in b"set_rgb 1 2 300\n":
        protocol.illuminator_parser_feed(ctypes.byref(parser), bytes([byte]), rgb)
    assert tuple(rgb) == (7, 7, 7)


def test_replies_are_the_protocols(protocol):
    assert protocol.illuminator_reply(SET_RGB) == DONE.encode()
    assert protocol.illuminator_reply(IDENTIFY) == ID.encode()
    assert protocol.illuminator_reply(FAILED) == ERROR.encode()
    assert protocol.illuminator_reply(NONE) is None


def reference(line: bytes) -> tuple[int, tuple[int, int, int] | None]:
    """The protocol in Python: what the firmware must answer to one complete line."""
    if len(line) > LINE_MAX or any(not (32 <= b <= 126 or b == 9) for b in line):
        return FAILED, None
    text = line.decode("ascii")
    if re.fullmatch(r"[ \t]*id\?[ \t]*", text):
        return IDENTIFY, None
    match = re.fullmatch(r"[ \t]*set_rgb[ \t]+([0-9]+)[ \t]+([0-9]+)[ \t]+([0-9]+)[ \t]*", text)
    if match and all(int(v) <= 255 for v in match.groups()):
        return SET_RGB, tuple(int(v) for v in match.groups())
    return FAILED, None


protocol_words = st.sampled_from([b"set_rgb", b"id?", b" ", b"\t", b"0", b"00", b"7", b"255", b"256", b"-", b"x"])
lines = st.one_of(
    st.lists(protocol_words, max_size=14).map(b"".join),
    st.binary(max_size=60),
).map(lambda line: line.replace(b"\n", b"").replace(b"\r", b""))


@settings(max_examples=400, deadline=None)
@given(line=lines)
def test_parser_matches_the_protocol_for_any_line(protocol, line):
    expected = [] if line == b"" else [reference(line)]
    assert feed(protocol, line + b"\n") == expected


# ---- the AVR builds -------------------------------------------------------------------------------------------

# Flash the bootloader leaves to a sketch, and RAM, per Arduino's boards.txt.
BOARDS = {"atmega328p": {"flash": 32256, "ram": 2048}, "atmega2560": {"flash": 253952, "ram": 8192}}


@pytest.fixture(scope="module")
def avr_builds(tmp_path_factory) -> dict[str, Path]:
    if absent := missing("make", "avr-gcc", "avr-objcopy", "avr-size"):
        pytest.skip(f"building the firmware needs {', '.join(absent)} (Debian: gcc-avr binutils-avr avr-libc)")
    builds = {}
    for mcu in BOARDS:
        build = tmp_path_factory.mktemp(mcu)
        make(f"MCU={mcu}", f"BUILD={build}")
        builds[mcu] = build
    return builds


def intel_hex_bytes(path: Path) -> int:
    """The number of data bytes in an Intel HEX file, checking every record's checksum."""
    total = 0
    for line in path.read_text().split():
        assert line.startswith(":"), line
        record = bytes.fromhex(line[1:])
        assert sum(record) % 256 == 0, f"bad checksum in {line}"
        if record[3] == 0:
            total += record[0]
    return total


@pytest.mark.parametrize("mcu", list(BOARDS))
def test_firmware_builds_and_fits(avr_builds, mcu):
    hex_file = avr_builds[mcu] / "neopixel_illuminator.hex"
    program = intel_hex_bytes(hex_file)
    sizes = subprocess.run(
        ["avr-size", "-A", str(avr_builds[mcu] / "neopixel_illuminator.elf")], capture_output=True, text=True
    ).stdout
    section = {m.group(1): int(m.group(2)) for m in re.finditer(r"^\.(\w+)\s+(\d+)", sizes, re.MULTILINE)}
    assert program == section["text"] + section.get("data", 0)
    # About 1.2 kB of flash: far inside what the bootloader leaves (and than Adafruit's library would take).
    assert 500 < program < 4096 < BOARDS[mcu]["flash"]
    # Static RAM (line buffer, receive buffer, reply strings), about 200 bytes: at most a quarter of the RAM,
    # leaving the rest of the Uno's 2 kB to the stack.
    assert section.get("data", 0) + section.get("bss", 0) <= BOARDS[mcu]["ram"] // 4


@pytest.fixture(scope="module")
def arduino_builds(tmp_path_factory) -> dict[str, Path]:
    hardware = Path("/usr/share/arduino/hardware")
    if absent := missing("arduino-builder", "avr-gcc"):
        pytest.skip(f"building the sketch the IDE's way needs {', '.join(absent)} (Debian: arduino-builder gcc-avr)")
    if not (hardware / "arduino" / "avr" / "cores" / "arduino" / "main.cpp").is_file():
        pytest.skip("building the sketch the IDE's way needs the Arduino AVR core (Debian: arduino-core-avr)")
    builds = {}
    for mcu, fqbn in {"atmega328p": "arduino:avr:uno", "atmega2560": "arduino:avr:mega:cpu=atmega2560"}.items():
        build = tmp_path_factory.mktemp(f"arduino-{mcu}")
        command = [
            "arduino-builder",
            *("-hardware", "/usr/share/arduino-builder", "-hardware", str(hardware)),
            *("-tools", "/usr/share/arduino-builder", "-fqbn", fqbn, "-ide-version", "10819"),
            # Debian's core (1.8.7) uses DECIMAL_DIG, which Debian's avr-gcc 5.4 does not give C++: the IDE's own
            # toolchain does. It is the core's problem, not the sketch's, so define it for the core's String.
            *("-prefs", "compiler.cpp.extra_flags=-DDECIMAL_DIG=17", "-warnings", "all"),
            *("-build-path", str(build), str(FIRMWARE / "neopixel_illuminator.ino")),
        ]
        result = subprocess.run(command, capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, result.stdout + result.stderr
        ours = [line for line in result.stderr.splitlines() if "warning" in line and "/sketch/" in line]
        assert ours == [], "\n".join(ours)
        builds[mcu] = build
    return builds


@pytest.mark.slow
@pytest.mark.parametrize("mcu", list(BOARDS))
def test_sketch_builds_with_the_arduino_core(arduino_builds, mcu):
    hex_file = arduino_builds[mcu] / "neopixel_illuminator.ino.hex"
    assert 500 < intel_hex_bytes(hex_file) < 4096


# ---- the firmware running in simavr ---------------------------------------------------------------------------


class Simulation:
    """The firmware running in simavr (sim/illuminator_sim.c): its UART on ``port``, its LED frames in a queue."""

    def __init__(self, harness: Path, mcu: str, elf: Path) -> None:
        self.process = subprocess.Popen(
            [str(harness), mcu, str(elf), "120"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.frames: queue.Queue[dict[str, tuple[int, ...]]] = queue.Queue()
        ready: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, args=(ready,), daemon=True).start()
        try:
            self.port = ready.get(timeout=10)
        except queue.Empty:
            self.close()
            pytest.fail(f"the simulator did not start: {self.process.stderr.read()}")

    def _read(self, ready: queue.Queue[str]) -> None:
        for line in self.process.stdout:
            if line.startswith("pty "):
                ready.put(line.split()[1])
            elif line.startswith("frame "):
                fields = dict(field.split("=") for field in line.split()[1:])
                self.frames.put({key: tuple(int(v) for v in value.split(",")) for key, value in fields.items()})

    def next_frame(self, timeout: float = 5.0) -> dict[str, tuple[int, ...]]:
        return self.frames.get(timeout=timeout)

    def close(self) -> None:
        self.process.stdin.close()  # the harness ends when its input closes
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


@pytest.fixture(scope="module")
def harness(tmp_path_factory) -> Path:
    if absent := missing("make", "gcc"):
        pytest.skip(f"the simulator harness needs {' and '.join(absent)}")
    if not Path("/usr/include/simavr/sim_avr.h").is_file():
        pytest.skip("running the firmware needs simavr's library (Debian: simavr libsimavr-dev)")
    build = tmp_path_factory.mktemp("sim")
    make("sim", f"HOST_BUILD={build}")
    return build / "illuminator-sim"


@pytest.fixture(scope="module")
def arduino_builds_or_none(request) -> dict[str, Path] | None:
    try:
        return request.getfixturevalue("arduino_builds")
    except pytest.skip.Exception:
        return None


@pytest.fixture(
    scope="module",
    params=[("atmega328p", "make"), ("atmega2560", "make"), ("atmega328p", "arduino"), ("atmega2560", "arduino")],
    ids=lambda p: f"{p[0]}-{p[1]}",
)
def simulation(request, harness, avr_builds, arduino_builds_or_none) -> Iterator[Simulation]:
    mcu, how = request.param
    if how == "make":
        elf = avr_builds[mcu] / "neopixel_illuminator.elf"
    elif arduino_builds_or_none is None:
        pytest.skip("no build with the Arduino core (see test_sketch_builds_with_the_arduino_core)")
    else:
        elf = arduino_builds_or_none[mcu] / "neopixel_illuminator.ino.elf"
    sim = Simulation(harness, mcu, elf)
    assert sim.next_frame()["bytes"] == (0, 0, 0)  # the LED is switched off at start-up
    yield sim
    sim.close()


@pytest.fixture
def port(simulation) -> Iterator[serial.Serial]:
    with serial.Serial(simulation.port, 9600, timeout=2) as connection:
        yield connection


def ask(port: serial.Serial, line: bytes) -> bytes:
    port.write(line)
    return port.readline()


def test_running_firmware_answers_the_id_query(port):
    assert ask(port, b"id?\n") == ID.encode() + b"\r\n"


def test_running_firmware_sets_the_led_in_grb_order_with_ws2812_timing(port, simulation):
    assert ask(port, b"set_rgb 255 16 1\n") == b"done.\r\n"
    frame = simulation.next_frame()
    assert frame["bytes"] == (16, 255, 1) and frame["bits"] == (24,)  # one LED: green, red, blue
    # The loop is cycle-counted (ws2812.c) and simavr counts cycles exactly: 6 and 13 cycles high, 20 a bit,
    # 25 where the next byte is loaded.
    assert frame["t0h"] == (6, 6) and frame["t1h"] == (13, 13) and frame["period"] == (20, 25)
    # Against the datasheets: T0H 400 +- 150 ns (WS2812B) and 350 +- 150 ns (WS2812); T1H 800 +- 150 ns and
    # 700 +- 150 ns, so 650-850 ns for both; a bit 1.25 us +- 600 ns.
    assert all(250 <= cycles * CYCLE_NS <= 500 for cycles in frame["t0h"])
    assert all(650 <= cycles * CYCLE_NS <= 850 for cycles in frame["t1h"])
    assert all(650 <= cycles * CYCLE_NS <= 1850 for cycles in frame["period"])


@pytest.mark.parametrize(
    "line",
    [b"garbage\n", b"set_rgb 256 0 0\n", b"set_rgb 1 2\n", b"set_rgb a b c\n", b"set_rgb " + b"9" * 80 + b" 0 0\n"],
    ids=["garbage", "above-255", "two-values", "not-numbers", "overlong"],
)
def test_running_firmware_answers_the_error_line_and_leaves_the_led(port, simulation, line):
    assert ask(port, line) == ERROR.encode() + b"\r\n"
    with pytest.raises(queue.Empty):
        simulation.next_frame(timeout=0.1)


def test_running_firmware_takes_crlf_and_commands_sent_back_to_back(port, simulation):
    port.write(b"set_rgb 1 2 3\r\nset_rgb 4 5 6\r\nid?\r\n")
    assert [port.readline() for _ in range(3)] == [b"done.\r\n", b"done.\r\n", ID.encode() + b"\r\n"]
    assert [simulation.next_frame()["bytes"] for _ in range(2)] == [(2, 1, 3), (5, 4, 6)]


def test_serial_illuminator_drives_the_running_firmware(simulation):
    light = SerialIlluminator(simulation.port, timeout=2.0, retries=0, reset_wait=0.0)
    assert light.describe() == {"kind": "serial", "port": simulation.port, "baudrate": 9600, "firmware": ID}
    for rgb in [(255, 255, 255), (255, 0, 0), (0, 255, 0), (0, 0, 255)]:
        light.set_rgb(*rgb)
        assert simulation.next_frame()["bytes"] == (rgb[1], rgb[0], rgb[2])
    light.close()
    assert simulation.next_frame()["bytes"] == (0, 0, 0)
