"""The options of a batch: one frozen value, checked once, when it is made, before any file is touched."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PicamcalError, closest
from ..modes import Mode, parse_mode
from ..output import BATCH_FORMATS, SRGB_FORMATS, TIFF_FORMATS
from ..raw import HEADLESS_SUFFIXES, PATTERNS, PROCESSED_SUFFIXES, RAW_SUFFIXES

#: Output compressions: ``zstd`` (TIFF: with the floating-point predictor; needs imagecodecs).
COMPRESSIONS = ("zstd",)

PathArg = str | os.PathLike[str]


class BatchOptionError(PicamcalError, ValueError):
    """Options that do not go together, or a value out of range: a mistake in the call, found before any work.

    The message names the options as :class:`BatchOptions` fields; a front end shows them under its own
    names with :meth:`message` (the command line says ``--out`` for ``out_dir``).

    Attributes
    ----------
    option : str or None
        The field at fault; None when it is how several go together.
    template : str
        The message, each field in it written ``{field}``.

    Examples
    --------
    >>> error = BatchOptionError("{binned} is for raw images")
    >>> str(error), error.message({"binned": "--binned"})
    ('binned is for raw images', '--binned is for raw images')
    """

    def __init__(self, template: str, option: str | None = None) -> None:
        self.template = template
        self.option = option
        text = self.message()
        super().__init__(text if option is None else f"{option}: {text}")

    def message(self, names: Mapping[str, str] | None = None) -> str:
        """The message with each field under its name in ``names`` (the field's own name where it has none)."""
        return self.template.format_map(_Names(names or {}))


def _did_you_mean(value: str, choices: Sequence[str]) -> str:
    near = closest(value, choices, parts=True)
    return f"; did you mean {near}?" if near else ""


class _Names(dict):
    def __missing__(self, key: str) -> str:
        return key


@dataclass(frozen=True)
class BatchOptions:
    """How :func:`picamcal.batch.run_batch` corrects and writes: where, in which mode and format, with which workers.

    Every check that needs no file is made here, once, when the value is made: the output place (a folder
    or a zarr stack, not both), the mode (:func:`picamcal.modes.parse_mode`; held as a
    :class:`~picamcal.modes.Mode`, or None for the calibration's best), the format and compression, the options
    that go with processed images only or raw images only, the workers and the Bayer pattern. What needs the
    files (the calibration, the tuning file, the white reference) is checked by ``run_batch``, still before any
    work.

    Attributes
    ----------
    out_dir : path-like, optional
        Folder for ``<stem><suffix>`` files in ``output_format`` (:func:`picamcal.output.write_corrected`, the
        suffix from :data:`picamcal.output.OUTPUT_SUFFIXES`). Give either this or ``zarr_path``.
    zarr_path : path-like, optional
        Write one OME-Zarr stack here instead (:mod:`picamcal.output.ome_zarr`).
    mosaic : (columns, rows), optional
        With ``zarr_path``: place the frames side by side as the tiles of one mosaic, in row-major order
        (frame i at row ``i // columns``, column ``i % columns``), instead of stacking them.
    mode : Mode or str, optional
        Correction mode (:class:`picamcal.modes.Mode`; :func:`picamcal.correct`). Default: the best the
        calibration does (:func:`picamcal.correct.choose_mode`: ``centre``, or ``flat`` for a white-only
        calibration), decided by ``run_batch`` when it has loaded the calibration (``BatchResult.mode``).
    binned : bool
        Write the bin-resolution image (raw inputs only).
    processed : bool
        The inputs are ISP-processed images (JPEG, PNG, TIFF), corrected with
        :func:`picamcal.correct.correct_processed`.
    input_encoding : str, optional
        With ``processed``: how to undo the tone curve (:func:`picamcal.raw.processed.linearise`);
        default the ``tuning`` file's curve if given, else ``srgb`` (:attr:`encoding`).
    white : path-like, optional
        With ``processed``: a processed white reference (residual flat field).
    tuning : path-like, optional
        With ``processed``: the libcamera tuning file the camera ran with (its lens shading and CCM,
        :func:`picamcal.export.isp.processed_inputs`). With raw inputs and an sRGB ``output_format``: the
        source of the colour matrix (its ``rpi.ccm``).
    output_format : str
        One of :data:`picamcal.output.BATCH_FORMATS`; a zarr stack is float32 only. The sRGB formats of raw
        inputs use the colour matrix of :func:`picamcal.output.camera_to_srgb` (the ``tuning`` file's, else
        the image's own, else the identity; the identity in ``pure`` mode, whose output is the calibration's
        primaries); processed inputs are in the ISP's sRGB space already.
    compression : {None, "zstd"}
        Compress TIFF files (zstd with a predictor; needs imagecodecs) or zarr chunks; not the PNG and JPEG
        formats, which have their own.
    overwrite : bool
        Replace existing outputs; otherwise they are skipped, which is how an interrupted batch resumes.
    workers : int, optional
        Local worker processes; default one per available core (and no pool for a single file); 0 works in
        the calling process, without a pool. Each worker loads the calibration once.
    scheduler : str, optional
        Address of a running dask.distributed scheduler (``tcp://host:port``) to run on instead (not with
        ``workers``). Its workers need the calibration, inputs and output place at the same paths.
    scheduler_timeout : float
        Seconds to wait for the scheduler (and for it to have a worker).
    pattern, black_level : optional
        Override the raw files' Bayer order and black level (:func:`picamcal.read_raw`).
    raw_format, raw_size, stride, frame, sensor : optional
        Read headless raw dumps (``rpicam-raw``): their libcamera format name, (width, height), row stride in
        bytes, frame number and sensor (:func:`picamcal.read_raw`'s ``raw_format``, ``size``, ...).
    sensor_crop, sensor_mode : optional
        The sensor mode the raw frames come from, for those whose files do not say it
        (:func:`picamcal.raw.model.raw_geometry`): the area of the sensor (x, y, width, height, full-sensor
        pixels) or the registry's mode (``"1920x1080"``, ``"1920x1080:10"``). A frame of any mode inside the
        calibration's crop is corrected with it (:func:`picamcal.correct`).
    place : Path
        Not given but derived: where the outputs go (``zarr_path`` or ``out_dir``).

    Raises
    ------
    BatchOptionError
        Options that do not go together, or out of range (a ``ValueError`` too).
    PicamcalError
        An unknown format, compression or pattern, or a combination no output can hold.
    ValueError
        An unknown mode.

    Examples
    --------
    >>> options = BatchOptions(out_dir="corrected", mode="flat", output_format="uint16-tiff", workers=0)
    >>> options.mode, options.place
    (<Mode.FLAT: 'flat'>, PosixPath('corrected'))
    >>> BatchOptions(out_dir="corrected", binned=True, processed=True)
    Traceback (most recent call last):
    ...
    picamcal.batch.options.BatchOptionError: binned is for raw images
    """

    out_dir: PathArg | None = None
    zarr_path: PathArg | None = None
    mosaic: tuple[int, int] | None = None
    mode: Mode | str | None = None
    binned: bool = False
    processed: bool = False
    input_encoding: str | None = None
    white: PathArg | None = None
    tuning: PathArg | None = None
    output_format: str = "float32-tiff"
    compression: str | None = None
    overwrite: bool = False
    workers: int | None = None
    scheduler: str | None = None
    scheduler_timeout: float = 10.0
    pattern: str | None = None
    black_level: float | Sequence[float] | None = None
    raw_format: str | None = None
    raw_size: tuple[int, int] | None = None
    stride: int | None = None
    frame: int | None = None
    sensor: str | None = None
    sensor_crop: tuple[int, int, int, int] | None = None
    sensor_mode: str | None = None
    place: Path = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.mode is not None:
            object.__setattr__(self, "mode", parse_mode(self.mode))
        if self.output_format not in BATCH_FORMATS:
            raise PicamcalError(
                f"unknown output format {self.output_format!r} (expected one of {', '.join(BATCH_FORMATS)})"
                + _did_you_mean(self.output_format, BATCH_FORMATS)
            )
        if not self.processed and (self.white is not None or self.input_encoding is not None):
            raise BatchOptionError("{white} and {input_encoding} go with {processed}")
        if self.tuning is not None and not self.processed and self.output_format not in SRGB_FORMATS:
            raise BatchOptionError(
                "without {processed} it gives the colour matrix of {output_format} " + ", ".join(SRGB_FORMATS),
                "tuning",
            )
        if self.processed and self.binned:
            raise BatchOptionError("{binned} is for raw images")
        if self.output_format == "dng-gainmap" and (self.processed or self.binned):
            raise BatchOptionError(
                "{output_format} dng-gainmap writes the raw mosaic with the flat field for a raw editor: "
                + ("it needs raw images, not {processed}" if self.processed else "it has no {binned} form")
            )
        if self.output_format == "linear-dng" and self.binned:
            raise BatchOptionError("{output_format} linear-dng is written at full resolution: drop {binned}")
        if self.zarr_path is not None and self.out_dir is None:
            object.__setattr__(self, "place", Path(self.zarr_path))
        elif self.out_dir is not None and self.zarr_path is None:
            object.__setattr__(self, "place", Path(self.out_dir))
        else:
            raise BatchOptionError("give {out_dir} FOLDER for image files, or {zarr_path} STACK.zarr for one stack")
        if self.workers is not None and self.scheduler is not None:
            raise BatchOptionError("not with {scheduler} (the cluster has its own)", "workers")
        if self.mosaic is not None:
            if self.zarr_path is None:
                raise BatchOptionError(
                    "a mosaic is a tiling of one {zarr_path} stack: give {zarr_path} STACK.zarr", "mosaic"
                )
            if len(self.mosaic) != 2 or min(self.mosaic) < 1:
                raise BatchOptionError("give at least one column and one row", "mosaic")
            object.__setattr__(self, "mosaic", (int(self.mosaic[0]), int(self.mosaic[1])))
        if self.workers is not None and self.workers < 0:
            raise BatchOptionError("must be 0 or more", "workers")
        if not (isinstance(self.scheduler_timeout, (int, float)) and 0 < self.scheduler_timeout < math.inf):
            raise BatchOptionError("must be a positive number of seconds", "scheduler_timeout")
        self._check_formats()
        if self.black_level is not None:
            object.__setattr__(self, "black_level", tuple(np.atleast_1d(self.black_level).astype(float).tolist()))

    def _check_formats(self) -> None:
        """The format, compression and pattern: unknown names, and combinations no output can hold."""
        if self.compression is not None and self.compression not in COMPRESSIONS:
            raise PicamcalError(
                f"unknown compression {self.compression!r} (expected one of {', '.join(COMPRESSIONS)})"
                + _did_you_mean(self.compression, COMPRESSIONS)
            )
        if self.zarr_path is not None and self.output_format != "float32-tiff":  # dng formats included
            raise PicamcalError(
                f"a zarr stack holds float32 only: write {self.output_format} files to a folder (--out)"
            )
        if self.compression is not None and self.zarr_path is None and self.output_format not in TIFF_FORMATS:
            raise PicamcalError(
                f"compression {self.compression} is for the TIFF formats: {self.output_format} has its own"
            )
        if self.tuning is not None and not self.processed and self.mode == Mode.PURE:
            raise PicamcalError(
                "mode pure writes the calibration's primaries, to which a camera's colour matrix does not apply "
                "(leave out the tuning file, or use mode centre)",
                self.tuning,
            )
        if self.pattern is not None and self.pattern not in PATTERNS:
            raise PicamcalError(
                f"unknown Bayer pattern {self.pattern!r} (expected one of {', '.join(PATTERNS)})"
                + _did_you_mean(self.pattern, PATTERNS)
            )

    @property
    def encoding(self) -> str:
        """How processed inputs are decoded: ``input_encoding``, else the tuning file's curve, else ``srgb``."""
        if self.input_encoding is not None:
            return self.input_encoding
        return f"tuning:{self.tuning}" if self.tuning is not None and self.processed else "srgb"

    @property
    def input_suffixes(self) -> tuple[str, ...]:
        """The suffixes of the files a folder of inputs gives (:func:`picamcal.batch.expand_inputs`)."""
        if self.processed:
            return PROCESSED_SUFFIXES
        return HEADLESS_SUFFIXES if self.raw_format is not None else RAW_SUFFIXES

    @property
    def read_options(self) -> dict[str, Any]:
        """The keyword arguments of :func:`picamcal.read_raw` these options give (``raw_size`` is its ``size``)."""
        return {
            "pattern": self.pattern,
            "black_level": self.black_level,
            "raw_format": self.raw_format,
            "size": self.raw_size,
            "stride": self.stride,
            "frame": self.frame,
            "sensor": self.sensor,
        }


__all__ = ["COMPRESSIONS", "BatchOptionError", "BatchOptions"]
