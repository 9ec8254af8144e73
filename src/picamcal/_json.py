"""Reading the JSON files picamcal is given (tuning files, target layouts, manifests, calibration records).

Each reader refuses what it cannot use with its own picamcal error naming the file: a file that is not a regular
file or is too large, bytes that are not UTF-8, text that is not JSON, NaN, infinities and numbers too large for
a float, nesting deeper than :data:`MAX_DEPTH` (which would end in a RecursionError further on), and, through a
:class:`Fields` checker, values of the wrong type, count or range.

libcamera's tuning files are read as libcamera reads them (:func:`read_libcamera_yaml`): with libyaml, the YAML
parser libcamera itself uses, which accepts what strict JSON refuses (trailing commas, comments) and refuses some
of what it accepts (duplicated keys, aliases, a list of 2,000 items).
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from .errors import PicamcalError
from .limits import require_regular_file

#: Deepest nesting of lists and objects accepted: picamcal's own files nest at most 7 levels.
MAX_DEPTH = 32
#: Largest JSON file read: a tuning file is about 50 kB, a manifest or layout a few kB.
MAX_JSON_BYTES = 16 << 20
#: Largest magnitude accepted for a whole number (beyond it a float would lose the value, or overflow).
MAX_INTEGER = 2**53


def read_json(
    path: str | os.PathLike[str], error: type[PicamcalError], what: str, max_bytes: int = MAX_JSON_BYTES
) -> Any:
    """The parsed content of a JSON file, or ``error`` (one line naming the file) for anything it cannot be.

    Parameters
    ----------
    path : path-like
    error : PicamcalError subclass
        Raised for every problem.
    what : str
        What the file should be, for the messages (``"a libcamera tuning file"``).
    max_bytes : int
        Files larger than this are refused unread.

    Examples
    --------
    >>> _ = Path("layout.json").write_text('{"width": 1920, "wheels": []}')
    >>> read_json("layout.json", PicamcalError, "a target layout")["width"]
    1920
    """
    return parse_json(_read_bounded(path, error, what, max_bytes), error, what, path)


def _read_bounded(path: str | os.PathLike[str], error: type[PicamcalError], what: str, max_bytes: int) -> bytes:
    """A regular file's bytes, refused (``error``) when it is larger than ``max_bytes`` or cannot be read."""
    size = require_regular_file(path, error)
    if size > max_bytes:
        raise error(f"is {size / 2**20:.0f} MB, far larger than {what} (at most {max_bytes >> 20} MB)", path)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise error(f"cannot read: {exc.strerror or exc}", path) from None
    return data


def parse_json(
    data: bytes | str, error: type[PicamcalError], what: str, path: str | os.PathLike[str] | None = None
) -> Any:
    """Parse JSON text strictly (see the module docstring), raising ``error`` for anything else.

    Examples
    --------
    >>> parse_json(b'{"a": [1, 2.5]}', PicamcalError, "a layout")
    {'a': [1, 2.5]}
    >>> parse_json(b'{"a": NaN}', PicamcalError, "a layout", "x.json")
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: x.json: not a layout: NaN is not a number JSON allows
    """
    try:
        text = data.decode("utf-8") if isinstance(data, bytes) else data
    except UnicodeDecodeError as exc:
        raise error(f"not {what}: not UTF-8 text (byte {exc.start} is 0x{data[exc.start]:02x})", path) from None
    try:
        value = json.loads(text, parse_constant=_refuse_constant, parse_float=_finite_float)
    except RecursionError:
        raise error(f"not {what}: nested too deeply", path) from None
    except ValueError as exc:
        raise error(f"not {what}: {exc}", path) from None
    if _depth(value) > MAX_DEPTH:
        raise error(f"not {what}: nested more than {MAX_DEPTH} levels deep", path)
    return value


def _refuse_constant(name: str) -> NoReturn:
    raise ValueError(f"{name} is not a number JSON allows")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"the number {text[:20]} is too large")
    return value


def _depth(value: Any) -> int:
    """Nesting depth of lists and dicts, without recursion."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, (list, dict)):
            deepest = max(deepest, depth)
            if depth <= MAX_DEPTH:
                stack.extend((child, depth + 1) for child in (item.values() if isinstance(item, dict) else item))
    return deepest


#: libcamera's YAML parser reads at most this many items into one list or mapping (src/libcamera/yaml_parser.cpp:
#: a sentinel of 2,000 parser events per collection, the last of which must close it).
LIBCAMERA_MAX_ITEMS = 1999
# The texts libcamera's value accessors (src/libcamera/value_node.cpp) read as numbers: a whole number for
# std::from_chars (an optional minus, digits) and a decimal one for strtod. Anything else stays text.
_WHOLE = re.compile(r"-?[0-9]+")
_DECIMAL = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")


def read_libcamera_yaml(
    path: str | os.PathLike[str], error: type[PicamcalError], what: str, max_bytes: int = MAX_JSON_BYTES
) -> Any:
    """The content of a file libcamera reads with its YAML parser (a tuning file), or ``error`` naming the file.

    As :func:`read_json` for the file itself; the text as :func:`parse_libcamera_yaml`.

    Examples
    --------
    >>> _ = Path("tuning.json").write_text('{"version": 2.0, "algorithms": [{"rpi.black_level": {}},],}')
    >>> read_libcamera_yaml("tuning.json", PicamcalError, "a tuning file")["algorithms"]  # a trailing comma
    [{'rpi.black_level': {}}]
    """
    return parse_libcamera_yaml(_read_bounded(path, error, what, max_bytes), error, what, path)


def parse_libcamera_yaml(
    data: bytes | str, error: type[PicamcalError], what: str, path: str | os.PathLike[str] | None = None
) -> Any:
    """Parse text as libcamera's ``YamlParser`` does (src/libcamera/yaml_parser.cpp), raising ``error`` where it fails.

    libcamera parses tuning files with libyaml, so a JSON file may have trailing commas or ``#`` comments, and any
    YAML 1.1 a single document of lists, mappings and plain values holds. Like libcamera, this refuses a text
    libyaml cannot parse (naming the line and column), an empty one or several documents, an alias (``*name``),
    a key that is a list or mapping, a key given twice in one mapping, and a list or mapping of more than
    :data:`LIBCAMERA_MAX_ITEMS` items; it also refuses nesting deeper than :data:`MAX_DEPTH`.

    libcamera keeps every value as text and converts it when an algorithm asks; here ``true`` and ``false``
    become booleans, ``null`` None, whole numbers ints and other finite decimal numbers floats (as JSON would
    read them, and whether quoted or not, as libcamera ignores quoting); everything else stays a string.
    Parsed with libyaml's C parser where PyYAML has it (its wheels do); PyYAML's pure-Python parser, the
    fallback, refuses tabs that libyaml takes between tokens (15 of Raspberry Pi's files have one), so for it tabs
    become spaces first (lines and columns stay those of the file).

    Examples
    --------
    >>> parse_libcamera_yaml(b'{"a": [1, 2.5, "3"], # a comment\\n "b": true,}', PicamcalError, "a tuning file")
    {'a': [1, 2.5, 3], 'b': True}
    >>> parse_libcamera_yaml(b'{"a": 1,\\n "a": 2}', PicamcalError, "a tuning file", "t.json")
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: t.json: not a tuning file: the key 'a' appears twice in one mapping (line 2); \
libcamera refuses that
    """
    import yaml

    if isinstance(data, str):
        data = data.encode("utf-8")
    loader_class = getattr(yaml, "CSafeLoader", None)
    if loader_class is None:
        loader_class, data = yaml.SafeLoader, data.replace(b"\t", b" ")
    loader = loader_class(data)
    try:
        return _compose(loader, yaml, error, what, path)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        context = f" ({exc.context})" if exc.context else ""
        raise error(f"not {what}: {exc.problem}{where}{context}", path) from None
    except yaml.YAMLError as exc:  # bytes that are not text (libyaml reads UTF-8 and UTF-16)
        raise error(f"not {what}: {' '.join(str(exc).split())}", path) from None
    finally:
        loader.dispose()


def _compose(loader: Any, yaml: Any, error: type[PicamcalError], what: str, path: Any) -> Any:
    """Build the value from libyaml's events, by the rules of libcamera's ``YamlParserContext::parseContent``."""

    def fail(problem: str, event: Any) -> NoReturn:
        raise error(f"not {what}: {problem} (line {event.start_mark.line + 1}); libcamera refuses that", path)

    events = iter(loader.get_event, None)
    next(events)  # the stream's start
    event = next(events)
    if not isinstance(event, yaml.DocumentStartEvent):
        raise error(f"not {what}: the file is empty", path)
    root: list[Any] = []
    # Open lists and mappings: [container, the pending key of a mapping, the line it started on].
    stack: list[list[Any]] = []
    parent: list[Any] = [root, None, 0]
    for event in events:
        if isinstance(event, yaml.DocumentEndEvent):
            break
        if isinstance(event, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            parent = stack.pop()
            continue
        if isinstance(event, yaml.AliasEvent):
            fail(f"an alias (*{event.anchor})", event)
        container, key = parent[0], parent[1]
        if isinstance(container, dict) and key is None:
            if not isinstance(event, yaml.ScalarEvent):
                fail("a key that is a list or a mapping", event)
            if event.value in container:
                fail(f"the key {event.value[:40]!r} appears twice in one mapping", event)
            parent[1] = event.value
            continue
        if len(container) >= LIBCAMERA_MAX_ITEMS:
            fail(f"a list or mapping of more than {LIBCAMERA_MAX_ITEMS} items", event)
        if isinstance(event, yaml.ScalarEvent):
            value = _libcamera_value(event.value)
        else:
            value = {} if isinstance(event, yaml.MappingStartEvent) else []
            if len(stack) >= MAX_DEPTH:
                raise error(f"not {what}: nested more than {MAX_DEPTH} levels deep", path)
        if isinstance(container, dict):
            container[key] = value
            parent[1] = None
        else:
            container.append(value)
        if not isinstance(event, yaml.ScalarEvent):
            stack.append(parent)
            parent = [value, None, event.start_mark.line]
    if loader.check_event(yaml.DocumentStartEvent):
        raise error(f"not {what}: holds more than one YAML document, and libcamera reads one", path)
    loader.get_event()  # the stream's end: libyaml has checked there is nothing else
    return root[0]


def _libcamera_value(text: str) -> Any:
    """A plain value as JSON would hold it: libcamera's booleans, whole and decimal numbers (see above)."""
    if _WHOLE.fullmatch(text) and len(text) < 4000:  # Python refuses to convert longer ones
        return int(text)
    if _DECIMAL.fullmatch(text):
        value = float(text)
        return value if math.isfinite(value) else text  # out of a double's range: libcamera's strtod refuses it
    return {"true": True, "false": False, "null": None}.get(text, text)


class Fields:
    """Checks of the values read from one JSON file; every failure is ``error``, one line naming the file.

    Each check takes the value and where it is (``"wheels[2].radius"``) and returns the value, converted where
    that helps (numbers to ``int`` or ``float``).

    Examples
    --------
    >>> fields = Fields("layout.json", PicamcalError, "a target layout", "write it again with picamcal target")
    >>> fields.number(3, "width", integer=True, positive=True)
    3
    >>> fields.number(-2.5, "wheels[0].radius", positive=True)
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: layout.json: not a target layout: wheels[0].radius must be a positive \
number, not -2.5 (write it again with picamcal target)
    """

    def __init__(
        self, path: str | os.PathLike[str] | None, error: type[PicamcalError], what: str, fix: str = ""
    ) -> None:
        self.path, self.error, self.what, self.fix = path, error, what, fix

    def fail(self, where: str, problem: str) -> NoReturn:
        """Raise the error: ``not WHAT: WHERE PROBLEM (FIX)``."""
        fix = f" ({self.fix})" if self.fix else ""
        subject = f"{where} " if where else ""
        raise self.error(f"not {self.what}: {subject}{problem}{fix}", self.path)

    def mapping(self, value: Any, where: str, required: Iterable[str] = ()) -> dict[str, Any]:
        """``value`` as a JSON object that has every key of ``required``."""
        if not isinstance(value, dict):
            self.fail(where, f"must be an object, not {_describe(value)}")
        missing = [key for key in required if key not in value]
        if missing:
            self.fail(where, f"lacks {', '.join(repr(k) for k in missing)}")
        return value

    def items(self, value: Any, where: str, *, minimum: int = 0, maximum: int | None = None) -> list[Any]:
        """``value`` as a list of ``minimum`` to ``maximum`` items."""
        if not isinstance(value, list):
            self.fail(where, f"must be a list, not {_describe(value)}")
        if len(value) < minimum or (maximum is not None and len(value) > maximum):
            wanted = f"{minimum}" if maximum == minimum else f"{minimum} to {maximum}" if maximum else f"{minimum}+"
            self.fail(where, f"must hold {wanted} items, not {len(value)}")
        return value

    def text(self, value: Any, where: str, choices: Sequence[str] | None = None) -> str:
        """``value`` as a string, one of ``choices`` if given."""
        if not isinstance(value, str):
            self.fail(where, f"must be a string, not {_describe(value)}")
        if choices is not None and value not in choices:
            self.fail(where, f"must be one of {', '.join(choices)}, not {value[:40]!r}")
        return value

    def number(
        self,
        value: Any,
        where: str,
        *,
        integer: bool = False,
        positive: bool = False,
        minimum: float | None = None,
        maximum: float | None = None,
    ) -> Any:
        """``value`` as a finite number (an ``int`` if ``integer``), positive or within the bounds if asked."""
        kind = "whole number" if integer else "number"
        kind = f"positive {kind}" if positive else kind
        if isinstance(value, (np.integer, np.floating)):
            value = value.item()
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
            self.fail(where, f"must be a {kind}, not {_describe(value)}")
        if isinstance(value, float) and not math.isfinite(value):
            self.fail(where, f"must be a finite {kind}, not {value!r}")
        if isinstance(value, int) and abs(value) > MAX_INTEGER:
            self.fail(where, f"is out of range ({_describe(value)})")
        if positive and not value > 0:
            self.fail(where, f"must be a {kind}, not {value!r}")
        if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
            bounds = (
                f"{minimum:g} to {maximum:g}"
                if minimum is not None and maximum is not None
                else (f"at least {minimum:g}" if minimum is not None else f"at most {maximum:g}")
            )
            self.fail(where, f"must be {bounds}, not {value!r}")
        return value

    def numbers(self, value: Any, where: str, count: int | None = None, **bounds: Any) -> list[Any]:
        """``value`` as a list of ``count`` numbers (any count if None), each checked as :meth:`number`."""
        values = self.items(value, where, minimum=count or 0, maximum=count)
        return [self.number(v, f"{where}[{i}]", **bounds) for i, v in enumerate(values)]


def _describe(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int) and abs(value) > MAX_INTEGER:
        return f"a number of about {int(value.bit_length() * math.log10(2)) + 1} digits"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return f"the string {value[:40]!r}"
    kinds: dict[type, str] = {list: "a list", dict: "an object"}
    return kinds.get(type(value), type(value).__name__)
