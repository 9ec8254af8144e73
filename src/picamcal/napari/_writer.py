"""napari's writers of picamcal's outputs (npe2 commands ``picamcal.write_tiff`` and ``picamcal.write_ome_zarr``).

An image layer of linear RGB (a frame the reader opened, a corrected image the Correct widget made) is written as
the command line writes its outputs: the ``uint16-tiff`` of ``picamcal correct --output-format uint16-tiff``
(:func:`picamcal.output.write_corrected`: the white reference at 32768, picamcal's JSON record in the description)
and the OME-Zarr stack of ``picamcal correct --zarr`` (:mod:`picamcal.output.ome_zarr`: float32, axes t, c, y, x;
a stack layer, (N, H, W, 3), gives N frames). The provenance is what the layer's ``metadata["picamcal"]`` carries:
its source file, the calibration and mode of a correction, how the file was read.

The command line's rules hold: the data must be an (H, W, 3) linear RGB image (a raw mosaic is not), and a file
there that picamcal did not write is never replaced (:func:`picamcal._atomic.refuse_foreign`; napari's save dialog
has asked before replacing one of picamcal's). A refusal shows the command line's one line in napari's notification
area and writes nothing: the writer returns no path.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import OutputError, PicamcalError
from ._layers import METADATA_KEY

__all__ = ["provenance", "write_ome_zarr", "write_tiff"]

#: The CLI's output format the TIFF writer writes.
TIFF_FORMAT = "uint16-tiff"


def _record(meta: Mapping[str, Any]) -> Mapping[str, Any]:
    """picamcal's record in a layer's attributes (``metadata["picamcal"]``), empty for another layer."""
    metadata = meta.get("metadata") or {}
    record = metadata.get(METADATA_KEY) if isinstance(metadata, Mapping) else None
    return record if isinstance(record, Mapping) else {}


def _name_of(value: Any) -> str | None:
    """A file's name from a path, or from a value that has one (a Calibration's ``path``)."""
    if value is None:
        return None
    if isinstance(value, (str, os.PathLike)):
        return Path(value).name
    path = getattr(value, "path", None)
    return Path(path).name if path is not None else None


def _sources(meta: Mapping[str, Any]) -> list[str]:
    """The source files of a layer's frames: a stack's ``paths``, else its ``path``; none for a layer of no file."""
    record = _record(meta)
    paths = record.get("paths") or ([record["path"]] if record.get("path") else [])
    return [str(p) for p in paths]


def provenance(meta: Mapping[str, Any]) -> dict[str, Any]:
    """The record an output of a layer carries: what ``picamcal correct`` records (``source``, ``calibration``,
    ``mode``, ``binned``), then the layer's name and kind and how its file was read.

    Examples
    --------
    >>> meta = {"name": "target (centre)", "metadata": {"picamcal": {"path": "/data/target.dng", "mode": "centre",
    ...         "calibration": "/data/cal.npz", "kind": "corrected"}}}
    >>> for key, value in provenance(meta).items():
    ...     print(f"{key}: {value}")
    source: target.dng
    calibration: cal.npz
    mode: centre
    binned: False
    layer: target (centre)
    kind: corrected
    """
    record = _record(meta)
    sources = _sources(meta)
    mode = record.get("mode")
    info: dict[str, Any] = {
        "source": Path(sources[0]).name if len(sources) == 1 else [Path(s).name for s in sources] or None,
        "calibration": _name_of(record.get("calibration_path") or record.get("calibration")),
        "mode": None if mode is None else str(getattr(mode, "value", mode)),
        "binned": bool(record.get("binned", False)),
        "layer": meta.get("name"),
        "kind": record.get("kind"),
    }
    if record.get("kind") == "linear rgb":
        info["linear"] = (
            "the file's linear RGB: black subtracted, white balanced as the file says, 1.0 at the white level"
        )
        info["white_balance"] = record.get("white_balance")
    if record.get("read_options"):
        info["read_options"] = dict(record["read_options"])
    return {key: value for key, value in info.items() if value is not None}


def _linear_rgb(path: Path, data: Any, meta: Mapping[str, Any], *, stacks: bool) -> np.ndarray:
    """The layer's data as linear RGB, (H, W, 3) (or, with ``stacks``, (N, H, W, 3)); else OutputError, one line."""
    array = np.asarray(data)
    record = _record(meta)
    name = meta.get("name") or "the layer"
    is_rgb = array.ndim in ((3, 4) if stacks else (3,)) and array.shape[-1] == 3 and meta.get("rgb", True) is not False
    if is_rgb and array.dtype.kind == "f" and record.get("kind") != "raw mosaic":
        return array
    if record.get("kind") == "raw mosaic":
        what = f"the raw mosaic of {_name_of(record.get('path')) or 'a frame'} ({array.dtype}, one value per pixel)"
    elif is_rgb:
        what = f"{array.dtype} RGB, not linear floating point values"
    elif array.ndim == 4 and array.shape[-1] == 3:
        what = f"a stack of {array.shape[0]} images: save it as OME-Zarr (.zarr), or one frame of it"
    else:
        what = f"an array of shape {array.shape}"
    shape = "(H, W, 3) or (N, H, W, 3)" if stacks else "(H, W, 3)"
    raise OutputError(f"holds a linear RGB image, {shape} floating point: layer {name!r} is {what}", path)


def _refused(exc: PicamcalError) -> list[str]:
    from ._reader import show

    show("error", str(exc))
    return []


def write_tiff(path: str, data: Any, meta: dict[str, Any]) -> list[str]:
    """Write an image layer as the command line's ``uint16-tiff`` (:func:`picamcal.output.write_corrected`), with
    its :func:`provenance`; the paths written, or none after a refusal shown in napari's notification area.

    Examples
    --------
    >>> rgb = np.full((4, 6, 3), 0.5, np.float32)
    >>> write_tiff("grey.tif", rgb, {"name": "grey", "rgb": True, "metadata": {"picamcal": {"mode": "flat"}}})
    ['grey.tif']
    >>> import json, tifffile
    >>> with tifffile.TiffFile("grey.tif") as tif:
    ...     int(tif.asarray()[0, 0, 0]), json.loads(tif.pages.first.description)["picamcal"]["mode"]
    (16384, 'flat')
    """
    from ..cli._common import check_output
    from ..output import is_picamcal_output, write_corrected

    target = Path(path)
    try:
        rgb = _linear_rgb(target, data, meta, stacks=False)
        check_output(target, True, is_picamcal_output, "an image picamcal wrote", [Path(s) for s in _sources(meta)])
        write_corrected(target, rgb, TIFF_FORMAT, provenance(meta), overwrite=True)
    except PicamcalError as exc:
        return _refused(exc)
    return [str(path)]


def write_ome_zarr(path: str, data: Any, meta: dict[str, Any]) -> list[str]:
    """Write an image layer as the command line's OME-Zarr stack (``picamcal correct --zarr``): one frame, or each
    frame of an (N, H, W, 3) stack, float32, the group's ``picamcal`` record holding the sources and settings; the
    paths written, or none after a refusal shown in napari's notification area.

    A folder there that is not a picamcal stack is never replaced; one that is is replaced whole.

    Examples
    --------
    >>> rgb = np.full((4, 6, 3), 0.5, np.float32)
    >>> write_ome_zarr("grey.zarr", rgb, {"name": "grey", "rgb": True, "metadata": {"picamcal": {"mode": "flat"}}})
    ['grey.zarr']
    >>> import zarr
    >>> group = zarr.open_group("grey.zarr", mode="r")
    >>> group["0"].shape, group.attrs["picamcal"]["settings"]["mode"], group.attrs["picamcal"]["done"]
    ((1, 3, 4, 6), 'flat', [0])
    """
    from .._atomic import refuse_inputs_as_output
    from ..output.ome_zarr import ZarrStack, require_zarr, write_frame

    target = Path(path)
    try:
        rgb = _linear_rgb(target, data, meta, stacks=True)
        frames = rgb if rgb.ndim == 4 else rgb[np.newaxis]
        require_zarr()
        sources = [str(Path(s).absolute()) for s in _sources(meta)]
        if len(sources) != len(frames):
            sources = [f"{meta.get('name') or 'layer'}[{k}]" for k in range(len(frames))]
        refuse_inputs_as_output(target, _sources(meta))
        info = provenance(meta)
        settings = {key: info.get(key) for key in ("mode", "binned", "layer", "kind", "read_options")}
        stack = ZarrStack(target, sources, settings, info.get("calibration") or "")
        stack.plan(overwrite=True)
        stack.prepare(frames.shape[1:], scale=1, compression=None)
        try:
            for index, frame in enumerate(frames):
                write_frame(target / "0", index, frame, source=sources[index])
                stack.finished(index)
            stack.write_record()
        finally:
            stack.release()
    except PicamcalError as exc:
        return _refused(exc)
    return [str(path)]
