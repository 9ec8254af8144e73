"""SerialIlluminator against fake illuminators on pseudo-terminals: a thread answers each line per a script.

Every device here lives on a local pty; timeouts are a few tenths of a second and reset_wait is 0, so the
whole module runs in a few seconds.
"""

from __future__ import annotations

import os
import re
import select
import threading
import time
import tty
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from serial.tools.list_ports_common import ListPortInfo

from picamcal.acquire import serial_illuminator
from picamcal.acquire.base import IlluminatorError
from picamcal.acquire.serial_illuminator import (
    SerialIlluminator,
    find_illuminator_port,
    open_serial_illuminator,
)

ERROR_LINE = "Error: command is set_rgb <int> <int> <int>"
ID_LINE = "picamcal-illuminator 1"
FAST = {"timeout": 0.25, "retries": 2, "reset_wait": 0.0}

# An answer is None (stay silent) or (delay in seconds, text).
Answer = tuple[float, str] | None


def protocol_answer(line: str) -> Answer:
    """What the firmware answers: the same rules as firmware/neopixel_illuminator/protocol.c."""
    if line.strip() == "id?":
        return 0.0, ID_LINE
    match = re.fullmatch(r"\s*set_rgb\s+(\d+)\s+(\d+)\s+(\d+)\s*", line)
    if match and all(int(v) <= 255 for v in match.groups()):
        return 0.0, "done."
    return 0.0, ERROR_LINE


class FakeDevice:
    """A fake illuminator: the host opens ``port``; ``answer(line, n)`` scripts the reply to the n-th line."""

    def __init__(self, answer: Callable[[str, int], Answer]) -> None:
        self.answer = answer
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # like a USB serial port: no echo, no newline translation
        self.port = os.ttyname(self.slave)
        self.lines: list[str] = []
        self.raw = bytearray()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        pending = b""
        while not self._stop.is_set():
            if not select.select([self.master], [], [], 0.01)[0]:
                continue
            try:
                data = os.read(self.master, 1024)
            except OSError:
                return
            self.raw += data
            pending += data
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                text = line.decode("ascii", errors="replace")
                self.lines.append(text)
                reply = self.answer(text, len(self.lines))
                if reply is None:
                    continue
                delay, message = reply
                if self._stop.wait(delay):
                    return
                os.write(self.master, (message + "\r\n").encode("ascii"))

    def read_lines(self, count: int, wait: float = 10.0) -> list[str]:
        """The lines read, once there are ``count`` (or ``wait`` seconds have passed): the device's thread reads
        a line the host has already written only after it has finished answering the one before."""
        deadline = time.monotonic() + wait
        while len(self.lines) < count and time.monotonic() < deadline:
            time.sleep(0.01)
        return self.lines

    def unplug(self) -> None:
        """The USB cable is pulled: the device end of the pty disappears."""
        self._stop.set()
        self._thread.join(timeout=2)
        os.close(self.master)
        self.master = -1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        for fd in (self.master, self.slave):
            if fd >= 0:
                os.close(fd)


@pytest.fixture
def make_device() -> Iterator[Callable[[Callable[[str, int], Answer]], FakeDevice]]:
    devices: list[FakeDevice] = []

    def make(answer: Callable[[str, int], Answer]) -> FakeDevice:
        devices.append(FakeDevice(answer))
        return devices[-1]

    yield make
    for device in devices:
        device.close()


def good(line: str, n: int) -> Answer:
    return protocol_answer(line)


def silent(line: str, n: int) -> Answer:
    return None


def test_good_device_sets_colours_and_switches_off_on_close(make_device):
    device = make_device(good)
    light = SerialIlluminator(device.port, **FAST)
    light.set_rgb(255, 0, 0)
    light.set_rgb(0, 128, 7)
    light.close()
    assert device.lines == ["id?", "set_rgb 255 0 0", "set_rgb 0 128 7", "set_rgb 0 0 0"]
    # Exactly the paper's bytes: one command a line, "\n"-terminated, nothing else.
    assert bytes(device.raw) == b"id?\nset_rgb 255 0 0\nset_rgb 0 128 7\nset_rgb 0 0 0\n"


def test_describe_names_kind_port_and_firmware(make_device):
    device = make_device(good)
    with SerialIlluminator(device.port, **FAST) as light:
        assert light.describe() == {"kind": "serial", "port": device.port, "baudrate": 9600, "firmware": ID_LINE}


def test_paper_sketch_without_id_is_accepted_with_no_firmware_id(make_device):
    def paper_sketch(line: str, n: int) -> Answer:
        return (0.0, "done.") if line.startswith("set_rgb") else (0.0, ERROR_LINE)

    device = make_device(paper_sketch)
    with SerialIlluminator(device.port, **FAST) as light:
        light.set_rgb(1, 2, 3)
        assert light.describe()["firmware"] is None


def test_numpy_integers_are_accepted(make_device):
    device = make_device(good)
    with SerialIlluminator(device.port, **FAST) as light:
        light.set_rgb(np.uint8(255), np.int64(0), 3)
    assert device.lines[1] == "set_rgb 255 0 3"


@pytest.mark.parametrize("rgb", [(256, 0, 0), (0, -1, 0), (0, 0, 1.5), (True, 0, 0), ("255", 0, 0)])
def test_values_outside_0_255_are_refused_on_the_host(make_device, rgb):
    device = make_device(good)
    with SerialIlluminator(device.port, **FAST) as light:
        with pytest.raises(IlluminatorError, match="0-255"):
            light.set_rgb(*rgb)
    assert [line for line in device.lines if line != "set_rgb 0 0 0"] == ["id?"]  # nothing sent for them


def test_error_answer_becomes_an_illuminator_error_with_the_device_text(make_device):
    def led_fault(line: str, n: int) -> Answer:
        return (0.0, ID_LINE) if line == "id?" else (0.0, "Error: LED supply below 4.5 V")

    device = make_device(led_fault)
    light = SerialIlluminator(device.port, **FAST)
    with pytest.raises(IlluminatorError, match=r"LED supply below 4\.5 V") as caught:
        light.set_rgb(255, 255, 255)
    assert device.port in str(caught.value)
    assert device.lines.count("set_rgb 255 255 255") == 1  # an answer, even an error, is not retried
    with pytest.raises(IlluminatorError, match="LED supply"):
        light.close()


def test_unexpected_answer_is_an_error_naming_it(make_device):
    def modem(line: str, n: int) -> Answer:
        return 0.0, "OK"

    device = make_device(modem)
    with pytest.raises(IlluminatorError, match=r"unexpected answer 'OK'.*is it the illuminator"):
        SerialIlluminator(device.port, **FAST)


def test_late_answer_within_the_timeout_is_waited_for(make_device):
    def slow(line: str, n: int) -> Answer:
        return 0.15, protocol_answer(line)[1]

    device = make_device(slow)
    with SerialIlluminator(device.port, timeout=0.5, retries=0, reset_wait=0.0) as light:
        light.set_rgb(9, 9, 9)
    assert device.lines == ["id?", "set_rgb 9 9 9", "set_rgb 0 0 0"]  # no resend


def test_answer_beyond_the_timeout_is_retried_and_then_succeeds(make_device):
    def late_once(line: str, n: int) -> Answer:
        if n == 2:
            return 0.4, "done."  # the first try's answer comes after the host gave up on it
        if n == 4:
            return 0.0, "Error: LED supply below 4.5 V"
        return protocol_answer(line)

    device = make_device(late_once)
    light = SerialIlluminator(device.port, timeout=0.25, retries=2, reset_wait=0.0)
    light.set_rgb(5, 6, 7)
    assert device.read_lines(3) == ["id?", "set_rgb 5 6 7", "set_rgb 5 6 7"]
    time.sleep(0.2)  # the resend's "done." has arrived too: one answer more than the host read
    # That spare "done." must not pass for the answer to the next command, which is an error.
    with pytest.raises(IlluminatorError, match="LED supply"):
        light.set_rgb(1, 1, 1)
    light.close()


def test_answers_always_beyond_the_timeout_fail_clearly_after_the_retries(make_device):
    def too_slow(line: str, n: int) -> Answer:
        return (0.0 if line == "id?" else 0.5), protocol_answer(line)[1]

    device = make_device(too_slow)
    light = SerialIlluminator(device.port, timeout=0.15, retries=1, reset_wait=0.0)
    with pytest.raises(IlluminatorError, match=f"no answer from the illuminator on {device.port} after 2 tries"):
        light.set_rgb(10, 20, 30)
    with pytest.raises(IlluminatorError, match="after 1 try"):
        light.close()


def test_device_that_never_answers_fails_after_the_retries_in_bounded_time(make_device):
    device = make_device(silent)
    start = time.monotonic()
    with pytest.raises(IlluminatorError, match=f"no answer from the illuminator on {device.port} after 3 tries"):
        SerialIlluminator(device.port, timeout=0.2, retries=2, reset_wait=0.0)
    # Three tries of 0.2 s each, no more (how long they took on a busy machine is not the test's business).
    assert time.monotonic() - start >= 0.6
    assert device.lines == ["id?"] * 3


def test_device_that_stops_answering_mid_run_fails_clearly_and_close_is_bounded(make_device):
    def dies_after_two(line: str, n: int) -> Answer:
        return protocol_answer(line) if n <= 2 else None

    device = make_device(dies_after_two)
    light = SerialIlluminator(device.port, timeout=0.2, retries=1, reset_wait=0.0)
    light.set_rgb(255, 0, 0)
    with pytest.raises(IlluminatorError, match=r"no answer .* after 2 tries"):
        light.set_rgb(0, 255, 0)
    sent = len(device.lines)
    with pytest.raises(IlluminatorError, match="after 1 try"):
        light.close()  # one try only: the device is probably why the caller is closing
    assert len(device.lines) == sent + 1  # bounded: one try of 0.2 s (the message says so), no retries
    light.close()  # closed already: nothing to do
    with pytest.raises(IlluminatorError, match="closed"):
        light.set_rgb(1, 2, 3)


def test_context_exit_keeps_the_error_of_the_block(make_device):
    device = make_device(lambda line, n: protocol_answer(line) if n == 1 else None)
    light = SerialIlluminator(device.port, timeout=0.1, retries=0, reset_wait=0.0)
    with pytest.raises(RuntimeError, match="camera failed"), light:
        raise RuntimeError("camera failed")  # close() then fails too, but this is the error that matters
    with pytest.raises(IlluminatorError, match="closed"):
        light.set_rgb(1, 2, 3)


def test_unplugged_device_is_reported_as_gone(make_device):
    device = make_device(good)
    light = SerialIlluminator(device.port, timeout=0.2, retries=1, reset_wait=0.0)
    device.unplug()
    with pytest.raises(IlluminatorError, match=f"the illuminator on {device.port} is gone"):
        light.set_rgb(1, 2, 3)


def test_missing_port_is_a_clear_error():
    with pytest.raises(IlluminatorError, match="cannot open the illuminator's serial port /dev/picamcal-no-such-tty"):
        SerialIlluminator("/dev/picamcal-no-such-tty", **FAST)


@pytest.mark.parametrize("options", [{"timeout": 0}, {"retries": -1}, {"reset_wait": -1.0}])
def test_bad_options_are_refused(options):
    with pytest.raises(IlluminatorError, match="timeout > 0"):
        SerialIlluminator("/dev/null", **{**FAST, **options})


def test_reset_wait_is_waited_after_opening(make_device):
    device = make_device(good)
    start = time.monotonic()
    SerialIlluminator(device.port, timeout=0.2, retries=0, reset_wait=0.3).close()
    assert time.monotonic() - start >= 0.3


# ---- finding the port ---------------------------------------------------------------------------------------


def wrong_device(line: str, n: int) -> Answer:
    return 0.0, "GPS NMEA $GPGGA"


def paper_sketch(line: str, n: int) -> Answer:
    return 0.0, ERROR_LINE


def test_find_port_skips_silent_wrong_and_unopenable_ports(make_device):
    quiet, other, legacy, right = (make_device(a) for a in (silent, wrong_device, paper_sketch, good))
    candidates = ["/dev/picamcal-no-such-tty", quiet.port, other.port, legacy.port, right.port]
    assert find_illuminator_port(timeout=0.15, reset_wait=0.0, candidates=candidates) == right.port
    for device in (quiet, other, legacy, right):
        assert device.lines == ["id?"]  # asked once each, in turn


def test_find_port_lists_what_each_port_did_when_none_is_the_illuminator(make_device):
    quiet, other, legacy = (make_device(a) for a in (silent, wrong_device, paper_sketch))
    with pytest.raises(IlluminatorError) as caught:
        find_illuminator_port(timeout=0.15, reset_wait=0.0, candidates=[quiet.port, other.port, legacy.port])
    message = str(caught.value)
    assert f"{quiet.port} (no answer)" in message
    assert f"{other.port} (answered 'GPS NMEA $GPGGA')" in message
    assert f"{legacy.port} (answered {ERROR_LINE!r}: the paper's sketch without an id? name this port)" in message


def test_find_port_with_no_ports_at_all(monkeypatch):
    monkeypatch.setattr(serial_illuminator.list_ports, "comports", lambda: [])
    with pytest.raises(IlluminatorError, match="no serial ports found"):
        find_illuminator_port(timeout=0.1, reset_wait=0.0)


def port_info(device: str, vid: int | None) -> ListPortInfo:
    info = ListPortInfo(device, skip_link_detection=True)
    info.vid = vid
    return info


def test_ports_are_tried_arduino_like_usb_first_then_usb_then_the_rest():
    ports = [
        port_info("/dev/ttyS0", None),
        port_info("/dev/ttyUSB1", 0x067B),  # Prolific: USB, not an Arduino chip
        port_info("/dev/ttyUSB0", 0x1A86),  # CH340 (Nano clones)
        port_info("/dev/ttyACM0", 0x2341),  # Arduino Uno / Mega
    ]
    assert serial_illuminator._rank_ports(ports) == ["/dev/ttyACM0", "/dev/ttyUSB0", "/dev/ttyUSB1", "/dev/ttyS0"]


def test_auto_detect_prefers_arduino_ports_and_keeps_the_connection(make_device, monkeypatch):
    other, right = make_device(wrong_device), make_device(good)
    ports = [port_info(other.port, None), port_info(right.port, 0x2341)]
    monkeypatch.setattr(serial_illuminator.list_ports, "comports", lambda: ports)
    with SerialIlluminator(**FAST) as light:
        assert light.port == right.port
        assert light.describe()["firmware"] == ID_LINE
        light.set_rgb(0, 0, 255)
    assert other.lines == []  # the Arduino-like port answered first, so the other was never disturbed
    assert right.lines == ["id?", "set_rgb 0 0 255", "set_rgb 0 0 0"]  # opened (and reset) once


# ---- the command-line spec ----------------------------------------------------------------------------------


def test_spec_with_a_port(make_device):
    device = make_device(good)
    with open_serial_illuminator(f"serial:{device.port}", **FAST) as light:
        assert light.port == device.port


def test_spec_without_a_port_searches(make_device, monkeypatch):
    device = make_device(good)
    monkeypatch.setattr(serial_illuminator.list_ports, "comports", lambda: [port_info(device.port, 0x2341)])
    with open_serial_illuminator("serial", **FAST) as light:
        assert light.port == device.port


@pytest.mark.parametrize(
    ("spec", "message"), [("serial:", "no port after 'serial:'"), ("gpio:D18", "not a serial illuminator")]
)
def test_bad_specs_are_refused(spec, message):
    with pytest.raises(IlluminatorError, match=message):
        open_serial_illuminator(spec, **FAST)
