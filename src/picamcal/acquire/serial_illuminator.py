"""The paper's illuminator: an Arduino driving one NeoPixel, set over a USB serial port (FORMATS.md section 7).

The firmware is ``firmware/neopixel_illuminator`` (or the paper's original sketch). At 9600 baud, one command
a line:

- ``set_rgb R G B`` (0-255 each) sets the LED and answers ``done.``;
- ``id?`` answers ``picamcal-illuminator 1`` (the paper's sketch has no id and answers the error line);
- anything else answers ``Error: command is set_rgb <int> <int> <int>``.

Opening the port resets the Arduino, so the host waits (about 1 s) before the first command. A command whose
answer does not come within the timeout is sent again, up to ``retries`` more times; an answer that arrives
after the host gave up on it is thrown away before the next command is sent.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from types import TracebackType
from typing import Any

import serial
from serial.tools import list_ports

from .base import IlluminatorError, check_rgb

__all__ = [
    "ARDUINO_USB_VIDS",
    "BAUDRATE",
    "FIRMWARE_ID_PREFIX",
    "SerialIlluminator",
    "find_illuminator_port",
    "open_serial_illuminator",
]

BAUDRATE = 9600
DONE_REPLY = "done."
ERROR_PREFIX = "Error"
ID_QUERY = "id?"
#: The start of the answer to ``id?`` (``picamcal-illuminator 1``; the number is the protocol version).
FIRMWARE_ID_PREFIX = "picamcal-illuminator"

#: USB vendor IDs of Arduino boards and of the USB-serial chips on their clones: tried first when searching.
ARDUINO_USB_VIDS: dict[int, str] = {
    0x2341: "Arduino",
    0x2A03: "Arduino (arduino.org)",
    0x1A86: "QinHeng CH340",
    0x0403: "FTDI",
    0x10C4: "Silicon Labs CP210x",
}

# Reads wait in slices this long, so a timeout is kept to within about this much.
_POLL_SECONDS = 0.02


class _Connection:
    """One open serial port speaking the line protocol: send a command, wait for the answer line."""

    def __init__(self, port: str, baudrate: int, timeout: float, reset_wait: float) -> None:
        self.port = port
        self.timeout = timeout
        try:
            self.serial = serial.Serial(
                port, baudrate, timeout=min(_POLL_SECONDS, timeout), write_timeout=timeout, exclusive=True
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise IlluminatorError(f"cannot open the illuminator's serial port {port} ({exc})") from exc
        if reset_wait > 0:
            time.sleep(reset_wait)

    def ask(self, command: str, tries: int) -> str:
        """Send ``command`` until a non-empty line comes back (at most ``tries`` times); return that line."""
        for _ in range(tries):
            try:
                # Drop whatever came before (bootloader noise, or the late answer to an earlier try). Read, not
                # reset_input_buffer(): its tcflush raises termios.error, not OSError, once the device is gone.
                self.serial.read(self.serial.in_waiting)
                self.serial.write(f"{command}\n".encode("ascii"))
            except serial.SerialTimeoutException:
                continue
            except (serial.SerialException, OSError) as exc:
                raise IlluminatorError(f"the illuminator on {self.port} is gone ({exc})") from exc
            answer = self._read_line()
            if answer is not None:
                return answer
        raise IlluminatorError(
            f"no answer from the illuminator on {self.port} after {tries} {'try' if tries == 1 else 'tries'} "
            f"(sent {command!r}, waited {self.timeout:g} s each time)"
        )

    def _read_line(self) -> str | None:
        """The next non-empty line (stripped, without its terminator), or None if none comes within the timeout."""
        deadline = time.monotonic() + self.timeout
        received = bytearray()
        while True:
            lines = received.split(b"\n")
            for line in lines[:-1]:
                text = line.decode("ascii", errors="replace").strip()
                if text:
                    return text
            received = bytearray(lines[-1])
            if time.monotonic() >= deadline:
                return None
            try:
                received += self.serial.read(max(1, self.serial.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise IlluminatorError(f"the illuminator on {self.port} is gone ({exc})") from exc

    def close(self) -> None:
        self.serial.close()


class SerialIlluminator:
    """The paper's Arduino + NeoPixel illuminator on a serial port (USB), behind the ``Illuminator`` interface.

    Parameters
    ----------
    port : str, optional
        The serial port (``/dev/ttyACM0``, ``COM3``). None searches every port for the illuminator's id
        (:func:`find_illuminator_port`), which needs the picamcal firmware (the paper's sketch has no id).
    baudrate : int
        The firmware's speed, 9600.
    timeout : float
        Seconds to wait for each answer.
    retries : int
        How many times a command is sent again when its answer does not come within ``timeout``.
    reset_wait : float
        Seconds to wait after opening the port: opening it resets the Arduino, whose bootloader runs first.

    Attributes
    ----------
    port : str
        The port in use.
    firmware : str or None
        The firmware's answer to ``id?`` (``"picamcal-illuminator 1"``), or None for the paper's original
        sketch, which answers it with its error line.

    Raises
    ------
    IlluminatorError
        The port cannot be opened, nothing answers on it, no port holds an illuminator (``port=None``), or the
        device's answer is not the protocol's.

    Examples
    --------
    With the Arduino plugged in (needs the hardware):

    >>> with SerialIlluminator("/dev/ttyACM0") as light:  # doctest: +SKIP
    ...     light.set_rgb(255, 0, 0)
    ...     light.describe()
    {'kind': 'serial', 'port': '/dev/ttyACM0', 'baudrate': 9600, 'firmware': 'picamcal-illuminator 1'}

    Without it:

    >>> SerialIlluminator("/dev/no-such-port", reset_wait=0)
    Traceback (most recent call last):
    ...
    picamcal.acquire.base.IlluminatorError: cannot open the illuminator's serial port /dev/no-such-port (...)
    """

    def __init__(
        self,
        port: str | None = None,
        *,
        baudrate: int = BAUDRATE,
        timeout: float = 2.0,
        retries: int = 2,
        reset_wait: float = 1.0,
    ) -> None:
        if not timeout > 0 or retries < 0 or reset_wait < 0:
            raise IlluminatorError(
                f"a serial illuminator needs timeout > 0, retries >= 0 and reset_wait >= 0, "
                f"got timeout={timeout}, retries={retries}, reset_wait={reset_wait}"
            )
        self.baudrate = int(baudrate)
        self.timeout = float(timeout)
        self.retries = int(retries)
        self._connection: _Connection | None
        self.firmware: str | None
        if port is None:
            self._connection, self.firmware = _search(
                _candidate_ports(), baudrate=self.baudrate, timeout=self.timeout, reset_wait=reset_wait
            )
            self.port = self._connection.port
        else:
            self.port = port
            self._connection = _Connection(port, self.baudrate, self.timeout, reset_wait)
            try:
                self.firmware = self._identify()
            except IlluminatorError:
                self._connection.close()
                raise

    def _identify(self) -> str | None:
        answer = self._ask(ID_QUERY, self.retries + 1)
        if answer.startswith(FIRMWARE_ID_PREFIX):
            return answer
        if answer.startswith(ERROR_PREFIX):
            return None
        raise IlluminatorError(f"unexpected answer {answer!r} to {ID_QUERY!r} on {self.port}: is it the illuminator?")

    def _ask(self, command: str, tries: int) -> str:
        if self._connection is None:
            raise IlluminatorError(f"the illuminator on {self.port} is closed")
        return self._connection.ask(command, tries)

    def _set(self, rgb: tuple[int, int, int], tries: int) -> None:
        command = "set_rgb {} {} {}".format(*rgb)
        answer = self._ask(command, tries)
        if answer == DONE_REPLY:
            return
        if answer.startswith(ERROR_PREFIX):
            raise IlluminatorError(f"the illuminator on {self.port} answered {answer!r} to {command!r}")
        raise IlluminatorError(f"unexpected answer {answer!r} to {command!r} on {self.port}: is it the illuminator?")

    def set_rgb(self, red: int, green: int, blue: int) -> None:
        """Set the LED (0-255 each) and return once the firmware answers ``done.``.

        Raises
        ------
        IlluminatorError
            A value is not a whole number 0-255 (nothing is sent), the device answers an error or something
            else, or it does not answer after ``retries + 1`` tries.
        """
        self._set(check_rgb(red, green, blue), self.retries + 1)

    def close(self) -> None:
        """Switch the LED off (one try, as the device may be why the caller is closing) and close the port.

        The port is closed even when the LED cannot be switched off; that failure is raised afterwards.
        Closing again does nothing.
        """
        if self._connection is None:
            return
        try:
            self._set((0, 0, 0), tries=1)
        finally:
            self._connection.close()
            self._connection = None

    def describe(self) -> dict[str, Any]:
        """Kind ``serial``, the port, the baud rate and the firmware id (None for the paper's sketch)."""
        return {"kind": "serial", "port": self.port, "baudrate": self.baudrate, "firmware": self.firmware}

    def __enter__(self) -> SerialIlluminator:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        try:
            self.close()
        except IlluminatorError:
            if exc_type is None:
                raise  # otherwise the error that ended the block is the one worth seeing


def _rank_ports(ports: Iterable[Any]) -> list[str]:
    """Port names, Arduino-like USB devices first, then other USB devices, then the rest (each by name)."""

    def rank(port: Any) -> tuple[int, str]:
        vid = getattr(port, "vid", None)
        return (0 if vid in ARDUINO_USB_VIDS else 1 if vid is not None else 2, port.device)

    return [port.device for port in sorted(ports, key=rank)]


def _candidate_ports() -> list[str]:
    return _rank_ports(list_ports.comports())


def _search(candidates: Sequence[str], *, baudrate: int, timeout: float, reset_wait: float) -> tuple[_Connection, str]:
    """Ask each candidate ``id?`` once; return the open connection and id of the first that answers the id."""
    tried = []
    for port in candidates:
        try:
            connection = _Connection(port, baudrate, timeout, reset_wait)
        except IlluminatorError as exc:
            tried.append(f"{port} (cannot open: {exc.__cause__ or exc})")
            continue
        try:
            answer = connection.ask(ID_QUERY, tries=1)
        except IlluminatorError:
            answer = None
        if answer is not None and answer.startswith(FIRMWARE_ID_PREFIX):
            return connection, answer
        connection.close()
        if answer is None:
            tried.append(f"{port} (no answer)")
        elif answer.startswith(ERROR_PREFIX):
            tried.append(f"{port} (answered {answer!r}: the paper's sketch without an id? name this port)")
        else:
            tried.append(f"{port} (answered {answer!r})")
    if not tried:
        raise IlluminatorError("no serial ports found: is the illuminator's Arduino plugged in?")
    raise IlluminatorError(f"no picamcal illuminator found; tried {', '.join(tried)}")


def find_illuminator_port(
    *,
    baudrate: int = BAUDRATE,
    timeout: float = 2.0,
    reset_wait: float = 1.0,
    candidates: Sequence[str] | None = None,
) -> str:
    """Find the serial port whose device answers ``id?`` with the illuminator's id.

    Parameters
    ----------
    baudrate, timeout, reset_wait
        As for :class:`SerialIlluminator`; each port tried costs up to ``reset_wait + timeout`` seconds.
    candidates : sequence of str, optional
        The ports to try, in order. By default every serial port of the system, Arduino-like USB devices
        (:data:`ARDUINO_USB_VIDS`) first, then other USB devices, then the rest.

    Returns
    -------
    str
        The first port that answered the id.

    Raises
    ------
    IlluminatorError
        No port answered the id; the message lists each port tried and what it did.

    Examples
    --------
    >>> find_illuminator_port()  # doctest: +SKIP
    '/dev/ttyACM0'
    >>> find_illuminator_port(candidates=[])
    Traceback (most recent call last):
    ...
    picamcal.acquire.base.IlluminatorError: no serial ports found: is the illuminator's Arduino plugged in?
    """
    ports = _candidate_ports() if candidates is None else list(candidates)
    connection, _ = _search(ports, baudrate=baudrate, timeout=timeout, reset_wait=reset_wait)
    connection.close()
    return connection.port


def open_serial_illuminator(spec: str = "serial", **options: Any) -> SerialIlluminator:
    """Open the serial illuminator named on the command line: ``serial`` (search) or ``serial:PORT``.

    Parameters
    ----------
    spec : str
        ``"serial"`` or ``"serial:/dev/ttyACM0"``.
    **options
        Passed on to :class:`SerialIlluminator` (``timeout``, ``retries``, ``reset_wait``, ``baudrate``).

    Raises
    ------
    IlluminatorError
        The spec is not a serial one, names an empty port, or the illuminator cannot be opened.

    Examples
    --------
    >>> open_serial_illuminator("serial:/dev/ttyACM0").describe()["port"]  # doctest: +SKIP
    '/dev/ttyACM0'
    >>> open_serial_illuminator("serial:")
    Traceback (most recent call last):
    ...
    picamcal.acquire.base.IlluminatorError: no port after 'serial:' in 'serial:' (e.g. serial:/dev/ttyACM0)
    """
    kind, colon, port = spec.partition(":")
    if kind.strip().lower() != "serial":
        raise IlluminatorError(f"not a serial illuminator: {spec!r} (expected serial or serial:PORT)")
    port = port.strip()
    if colon and not port:
        raise IlluminatorError(f"no port after 'serial:' in {spec!r} (e.g. serial:/dev/ttyACM0)")
    return SerialIlluminator(port or None, **options)
