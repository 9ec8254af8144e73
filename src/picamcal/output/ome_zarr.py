"""A chunked float32 OME-Zarr stack of corrected frames, written by many processes at once and resumable.

The stack follows OME-NGFF 0.5 (zarr format 3): a group whose ``ome`` attributes hold one ``multiscales``
entry (one resolution level, axes ``t, c, y, x``) and ``omero`` channel hints; the array ``0`` has shape
(frames, 3, H, W) float32, chunks of one frame and channel and at most 1024 x 1024 pixels, so no chunk is
shared by two frames and concurrent workers never write the same chunk. As a mosaic the frames are the
tiles of one image instead, (1, 3, rows * H, columns * W), one chunk per tile and channel. Frames not (yet)
written read as NaN.

Only the process that plans the stack (:class:`ZarrStack`) writes the group's attributes, among them the
``picamcal`` record of which frames are finished; workers write only their frames' chunks
(:func:`write_frame`). zarr writes each chunk to a temporary name and renames it, so a chunk is whole or
absent.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import has_live_temporary, make_temporary, remove_stale_temporaries
from ..errors import OutputError, PicamcalError

#: The OME-NGFF version of the stack's metadata.
OME_NGFF_VERSION = "0.5"

_ZARR_TILE = 1024
#: The suffix of the temporary that says a run is writing a stack.
_WRITING = ".writing"
_RECORD_INTERVAL_S = 1.0


def require_zarr() -> None:
    """Raise PicamcalError unless zarr 3 or later is installed.

    Examples
    --------
    >>> require_zarr()
    """
    try:
        import zarr
    except ImportError:
        raise PicamcalError("zarr output needs the zarr package (version 3)") from None
    if int(zarr.__version__.split(".")[0]) < 3:
        raise PicamcalError(f"zarr output needs zarr 3 or later (this is {zarr.__version__})")


class ZarrStack:
    """The OME-Zarr stack of a batch: planning (which frames are done), creation, and the record of finished frames.

    While a run writes, a temporary of this process beside the stack says so
    (``.<name>.picamcal-...tmp.writing``, :func:`picamcal._atomic.make_temporary`; beside it, as zarr takes
    whatever is inside for its own), so that another run removes zarr's chunk temporaries (``*.partial``) only
    when they are a killed run's.

    Parameters
    ----------
    path : path-like
        The stack (a folder).
    sources : sequence of str
        The inputs, one frame each, in order: recorded, and compared when a run resumes.
    settings : dict
        What else decides the frames' values (JSON-serialisable): a stack of other sources or settings is
        not resumed.
    calibration : str
        The calibration's file name, recorded.
    mosaic : (columns, rows), optional
        Place the frames as the tiles of one mosaic, row by row.

    Examples
    --------
    >>> stack = ZarrStack("frames.zarr", ["a.dng", "b.dng"], {"mode": "centre"}, "cal.npz")
    >>> stack.plan(overwrite=False)
    [0, 1]
    >>> stack.prepare((240, 320, 3), scale=1, compression=None)
    >>> write_frame("frames.zarr/0", 1, np.ones((240, 320, 3), np.float32), source="b.dng")
    >>> stack.finished(1)
    >>> stack.release()
    >>> ZarrStack("frames.zarr", ["a.dng", "b.dng"], {"mode": "centre"}, "cal.npz").plan(overwrite=False)
    [0]
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        sources: Sequence[str],
        settings: dict[str, Any],
        calibration: str,
        mosaic: tuple[int, int] | None = None,
    ) -> None:
        self.path = Path(path)
        self.sources = list(sources)
        self.signature = settings
        self.calibration = calibration
        self.mosaic = mosaic
        self.done: set[int] = set()
        self.resuming = False
        self.recorded_at = 0.0
        self.group: Any = None
        self.marker: Path | None = None

    def _existing_record(self) -> dict[str, Any] | None:
        try:
            return json.loads((self.path / "zarr.json").read_text())["attributes"]["picamcal"]
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def plan(self, overwrite: bool) -> list[int]:
        """The frames still to write, by index; the others are done (an earlier run of the same stack wrote them).

        Raises
        ------
        OutputError
            The path is not a picamcal stack, or one of other sources or settings (without ``overwrite``).
        """
        require_zarr()
        if self.path.exists():
            if not self.path.is_dir():
                raise OutputError("exists and is not a zarr store (a folder)", self.path)
            record = self._existing_record()
            if record is None and any(self.path.iterdir()):
                raise OutputError("exists and is not a picamcal zarr stack; choose another --zarr", self.path)
            if record is not None and not overwrite:
                differing = (
                    "other inputs"
                    if record.get("sources") != self.sources
                    else _differing(record.get("settings"), self.signature)
                )
                if differing:
                    raise OutputError(
                        f"holds a stack of other inputs or settings: {differing} (use --overwrite to replace it)",
                        self.path,
                    )
                self.done = {int(i) for i in record.get("done", [])}
                self.resuming = True
        return [i for i in range(len(self.sources)) if i not in self.done]

    def prepare(self, frame_shape: tuple[int, ...], scale: int, compression: str | None) -> None:
        """Create the stack (or open the one resumed) for frames of ``frame_shape`` (H, W, 3), and say a run writes it.

        ``scale`` is the frames' pixel size in sensor pixels (the bin size of binned frames), recorded in the
        OME metadata; ``compression`` ``"zstd"`` compresses the chunks.
        """
        import zarr
        from zarr.codecs import ZstdCodec

        height, width = frame_shape[:2]
        try:
            if self.resuming:
                self.group = zarr.open_group(self.path, mode="r+")
                remove_stale_temporaries(self.path.parent)
                self.remove_partials()
            else:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.group = zarr.open_group(self.path, mode="w", zarr_format=3)
                if self.mosaic is None:
                    shape = (len(self.sources), 3, height, width)
                    chunks = (1, 1, min(height, _ZARR_TILE), min(width, _ZARR_TILE))
                else:  # one chunk per tile and channel, so that no two workers ever write the same chunk
                    columns, rows = self.mosaic
                    shape, chunks = (1, 3, rows * height, columns * width), (1, 1, height, width)
                self.group.create_array(
                    "0",
                    shape=shape,
                    chunks=chunks,
                    dtype="float32",
                    fill_value=np.nan,
                    compressors=ZstdCodec() if compression == "zstd" else None,
                    dimension_names=["t", "c", "y", "x"],
                )
                self.group.attrs.update({"ome": ome_metadata(scale), "picamcal": self._record()})
        except OSError as exc:
            raise OutputError(f"cannot write here: {exc.strerror or exc}", self.path) from exc
        self.marker = make_temporary(self.path, suffix=_WRITING)

    def unused(self) -> bool:
        """Whether no run writes the stack now (none holds its marker) and none of its frames is done."""
        return not self.done and not has_live_temporary(self.path, _WRITING)

    def remove_partials(self) -> None:
        """Remove zarr's chunk temporaries (``*.partial``) if no run writes the stack (none holds its marker): a
        killed run, or an interrupted one's killed workers, left them."""
        if not has_live_temporary(self.path, _WRITING):
            for partial in self.path.rglob("*.partial"):
                partial.unlink(missing_ok=True)

    def release(self) -> None:
        """Say that this run no longer writes the stack."""
        if self.marker is not None:
            self.marker.unlink(missing_ok=True)

    def _record(self) -> dict[str, Any]:
        return {
            "calibration": self.calibration,
            "settings": self.signature,
            "sources": self.sources,
            "done": sorted(self.done),
        }

    def finished(self, index: int) -> None:
        """Note that frame ``index`` is written; recorded at most a second later (and by :meth:`write_record`)."""
        self.done.add(index)
        if time.monotonic() - self.recorded_at > _RECORD_INTERVAL_S:
            self.write_record()

    def write_record(self) -> None:
        """Record the finished frames (zarr rewrites the group's zarr.json atomically: temporary name, rename)."""
        try:
            self.group.attrs.update({"picamcal": self._record()})
        except OSError as exc:
            raise OutputError(f"cannot record the finished frames: {exc.strerror or exc}", self.path) from exc
        self.recorded_at = time.monotonic()


def _differing(recorded: Any, settings: dict[str, Any]) -> str:
    """Which of a stack's recorded settings differ from ``settings``, by name ("other mode, read_options"); an
    empty string if none does."""
    if not isinstance(recorded, dict):
        return "settings not recorded"
    names = sorted(key for key in {*recorded, *settings} if recorded.get(key) != settings.get(key))
    return f"other {', '.join(names)}" if names else ""


def write_frame(
    array_path: str | os.PathLike[str],
    index: int,
    rgb: np.ndarray,
    mosaic: tuple[int, int] | None = None,
    *,
    source: str,
) -> None:
    """Write frame ``index`` (H, W, 3) into the stack's array: its slot, or its tile of a ``mosaic``.

    Raises
    ------
    PicamcalError
        The frame is not of the stack's frame size (naming ``source``).
    OutputError
        The chunks cannot be written.
    """
    import zarr

    array = zarr.open_array(array_path, mode="r+")
    frame = np.moveaxis(np.asarray(rgb, dtype=np.float32), -1, 0)
    tile = array.chunks[2:] if mosaic is not None else array.shape[2:]
    if frame.shape[1:] != tuple(tile):
        raise PicamcalError(f"is {frame.shape[2]}x{frame.shape[1]}, the stack's frames are {tile[1]}x{tile[0]}", source)
    try:
        if mosaic is None:
            array[index] = frame
        else:
            row, column = divmod(index, mosaic[0])
            height, width = tile
            array[0, :, row * height : (row + 1) * height, column * width : (column + 1) * width] = frame
    except OSError as exc:
        raise OutputError(f"cannot write frame {index}: {exc.strerror or exc}", Path(array_path).parent) from exc


def ome_metadata(scale: int) -> dict[str, Any]:
    """OME-NGFF 0.5 ``ome`` attributes: one multiscale level ``0`` with axes t, c, y, x, and RGB channel hints.

    Examples
    --------
    >>> [axis["name"] for axis in ome_metadata(16)["multiscales"][0]["axes"]]
    ['t', 'c', 'y', 'x']
    """
    colours = {"R": "FF0000", "G": "00FF00", "B": "0000FF"}
    return {
        "version": OME_NGFF_VERSION,
        "multiscales": [
            {
                "name": "picamcal",
                "axes": [
                    {"name": "t", "type": "time"},
                    {"name": "c", "type": "channel"},
                    {"name": "y", "type": "space"},
                    {"name": "x", "type": "space"},
                ],
                "datasets": [
                    {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1.0, 1.0, scale, scale]}]}
                ],
            }
        ],
        "omero": {
            "channels": [
                {"label": label, "color": colour, "active": True, "window": {"min": 0, "max": 1, "start": 0, "end": 1}}
                for label, colour in colours.items()
            ],
            "rdefs": {"model": "color"},
        },
    }


__all__ = ["OME_NGFF_VERSION", "ZarrStack", "ome_metadata", "require_zarr", "write_frame"]
