"""PiDNG as Raspberry Pi OS ships it, under picamera2: the sensor's name as the DNG's Model, written to a file object.

picamera2 writes DNGs through PiDNG (``picamera2/request.py``, ``Helpers.save_dng``), and since 0.3.28 asks of it
what only the PiDNG of Raspberry Pi OS (``python3-pidng``, PiDNG's source after its 4.0.9 release) does:

- ``Picamera2Camera(config, metadata, model)`` takes a third argument, the camera's ``Model`` property (the
  sensor's name, ``"imx477"``), and writes it as the DNG's Model tag, as rpicam-still does (PiDNG's pull request
  95; picamera2's commit "Save the sensor name as the Model in DNG files");
- ``PICAM2DNG.convert(raw, file=f)`` writes the DNG into an open file object (picamera2's commit "Performance
  improvements writing DNG files", used from picamera2 0.3.32).

The PiDNG on PyPI (4.0.9, the latest there, which the ``virtual-camera`` extra installs) takes two arguments,
writes the Model ``"PiDNG / PiCamera2"``, and converts to a file name or to returned bytes; with it, picamera2's
``capture_file("x.dng", name="raw")``, ``Request.save_dng`` and ``helpers.save_dng`` raise ``TypeError``.

Inside the virtual camera only, the two PiDNG classes that picamera2's ``request`` module sees are these
interfaces over the installed PiDNG (:func:`patch_request_module`, put in place by
:func:`picamcal.virtualcam.kernel.install_hooks`): :func:`with_model` sets the Model tag to the model given, and
:func:`with_file_output` writes the bytes PiDNG returns into the file object given. The DNG itself (raw data,
black level, CFA pattern, colour matrix and every other tag) is the installed PiDNG's. A PiDNG that already takes
the model or the file object is used as it is; neither PiDNG nor picamera2 is changed.

Examples
--------
The shape of PiDNG 4.0.9's classes, and what picamera2 0.3.38 asks of them:

>>> import io
>>> class Tags(dict):  # PiDNG's DNGTags: a tag is set with set(tag, value)
...     set = dict.__setitem__
>>> class Camera:
...     def __init__(self, fmt, metadata):
...         self.tags = Tags(Model="PiDNG / PiCamera2")
>>> class Converter:
...     def __init__(self, camera):
...         self.camera = camera
...     def convert(self, image, filename=""):
...         return bytearray(self.camera.tags["Model"].encode())
>>> camera = with_model(Camera, tag="Model")({}, {}, "imx477")
>>> out = io.BytesIO()
>>> with_file_output(Converter)(camera).convert(None, file=out)
>>> out.getvalue()
b'imx477'
"""

from __future__ import annotations

import inspect
import sys
from typing import Any


def _parameters(function: Any) -> list[inspect.Parameter] | None:
    """The parameters of ``function``, or None where it cannot be read or takes any (``*args``, ``**kwargs``)."""
    try:
        parameters = list(inspect.signature(function).parameters.values())
    except (TypeError, ValueError):
        return None
    if any(p.kind in (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD) for p in parameters):
        return None
    return parameters


def takes_model(camera_class: type) -> bool:
    """Whether a PiDNG ``Picamera2Camera`` takes the camera's model after the configuration and metadata.

    Examples
    --------
    >>> class Two:
    ...     def __init__(self, fmt, metadata): ...
    >>> class Three:
    ...     def __init__(self, fmt, metadata, model="PiDNG / PiCamera2"): ...
    >>> takes_model(Two), takes_model(Three)
    (False, True)
    """
    parameters = _parameters(getattr(camera_class, "__init__", None))
    if parameters is None:
        return True  # it takes anything: left as it is
    positional = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    return sum(p.kind in positional for p in parameters) >= 4  # self, fmt, metadata, model


def takes_file(converter_class: type) -> bool:
    """Whether a PiDNG converter's ``convert`` takes an open file object as ``file``.

    Examples
    --------
    >>> class Old:
    ...     def convert(self, image, filename=""): ...
    >>> class New:
    ...     def convert(self, image, filename="", file=None): ...
    >>> takes_file(Old), takes_file(New)
    (False, True)
    """
    parameters = _parameters(getattr(converter_class, "convert", None))
    return parameters is None or any(p.name == "file" for p in parameters)


def with_model(camera_class: type, tag: Any = None) -> type:
    """PiDNG's ``Picamera2Camera`` taking the camera's model as Raspberry Pi OS's does (see the module).

    Parameters
    ----------
    camera_class : type
        The installed PiDNG's ``pidng.camdefs.Picamera2Camera``.
    tag : optional
        The key of the Model tag in the instance's ``tags``; default PiDNG's ``Tag.Model`` (from the class's module).

    Returns
    -------
    type
        ``camera_class`` itself where it takes the model, else a subclass of it that does: without a model (or with
        an empty one) its tags are the installed PiDNG's.
    """
    if takes_model(camera_class):
        return camera_class
    model_tag = tag if tag is not None else sys.modules[camera_class.__module__].Tag.Model

    class Picamera2Camera(camera_class):
        def __init__(self, fmt: dict, metadata: dict, model: str | None = None) -> None:
            super().__init__(fmt, metadata)
            if model:
                self.tags.set(model_tag, model)

    Picamera2Camera.__qualname__ = camera_class.__qualname__
    Picamera2Camera.__module__ = camera_class.__module__
    return Picamera2Camera


def with_file_output(converter_class: type) -> type:
    """PiDNG's ``PICAM2DNG`` whose ``convert`` writes into a file object given as ``file``, as Raspberry Pi OS's
    does (see the module).

    Parameters
    ----------
    converter_class : type
        The installed PiDNG's ``pidng.core.PICAM2DNG``.

    Returns
    -------
    type
        ``converter_class`` itself where ``convert`` takes ``file``, else a subclass whose ``convert(image, file=f)``
        writes the bytes the installed ``convert(image)`` returns into ``f``; other calls are the installed one's.
    """
    if takes_file(converter_class):
        return converter_class

    class PICAM2DNG(converter_class):
        def convert(self, image: Any, filename: str = "", file: Any = None) -> Any:
            if file is None:
                return super().convert(image, filename)
            file.write(super().convert(image, ""))
            return None

    PICAM2DNG.__qualname__ = converter_class.__qualname__
    PICAM2DNG.__module__ = converter_class.__module__
    return PICAM2DNG


def patch_request_module(module: Any) -> None:
    """Give picamera2's ``request`` module the PiDNG interface of Raspberry Pi OS (:func:`with_model`,
    :func:`with_file_output`)."""
    for name, adapt in (("Picamera2Camera", with_model), ("PICAM2DNG", with_file_output)):
        found = getattr(module, name, None)
        if isinstance(found, type):
            setattr(module, name, adapt(found))
