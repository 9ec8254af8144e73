"""The ``picamcal`` command line: a thin skin over the library.

Each command parses its arguments, calls the library and prints. Every PicamcalError becomes one line on stderr
and exit status 2, in :func:`main` and nowhere else. The commands live in modules by what they are for; importing
them registers them on the one ``app``, in the order ``picamcal --help`` lists them.
"""

# The order of these imports is the order of the commands in --help.
from . import calibrating, exporting, inspecting, running, evaluating  # noqa: F401, I001
from . import virtual  # noqa: F401
from ._common import app
from ._session import main

__all__ = ["app", "main"]
