"""The encoders of finished codes: PNG (8 and 16 bit, deflated in parallel strips) and JPEG, and the uint16 codes.

Every PNG is decoded by independent readers (Pillow, imagecodecs' libpng, pypng, and pngcheck where it is
installed) to exactly the codes written; every JPEG is compared with Pillow's own writer with the same settings,
and validated by exiftool where it is installed.
"""

from __future__ import annotations

import io
import json
import shutil
import struct
import subprocess
import sys
import threading
import zlib
from pathlib import Path

import numpy as np
import png
import pytest
import tifffile
from PIL import Image, ImageCms

import picamcal.output.encoders as encoders
from picamcal.kernels import encode_codes
from picamcal.output.encoders import encode_jpeg, encode_png, png_strips, write_jpeg, write_png
from picamcal.output.provenance import SOFTWARE
from picamcal.output.tiff import UINT16_WHITE, encode_uint16, uint16_rows_per_strip, write_tiff

imagecodecs = pytest.importorskip("imagecodecs")

DESCRIPTION = json.dumps({"picamcal": {"source": "a.dng", "note": "µm ±"}}, ensure_ascii=False)  # iTXt is UTF-8
#: EXIF's ImageDescription is ASCII: picamcal's writer gives json.dumps's escaped text.
ASCII_DESCRIPTION = json.dumps({"picamcal": {"source": "a.dng", "note": "µm ±"}})
SIZES = [(1, 1), (1, 7), (7, 1), (2, 3), (37, 53), (301, 257)]


def sRGB_profile() -> bytes:
    return ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()


def codes_of(shape: tuple[int, int], dtype: type, seed: int = 0) -> np.ndarray:
    """Noise over the whole range, with 0 and the top code in it (the Average filter's wrap-around), and a ramp."""
    top = np.iinfo(dtype).max
    rng = np.random.default_rng(seed)
    codes = rng.integers(0, top, size=(*shape, 3), dtype=dtype, endpoint=True)
    codes[::3, ::2] = top
    codes[1::3, ::2] = 0
    codes[2::4] = np.linspace(0, top, shape[1] * 3).astype(dtype).reshape(shape[1], 3)
    return codes


def chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    """The PNG's chunks (kind, data), each CRC checked."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    found, at = [], 8
    while at < len(data):
        (length,) = struct.unpack(">I", data[at : at + 4])
        kind, body = data[at + 4 : at + 8], data[at + 8 : at + 8 + length]
        (crc,) = struct.unpack(">I", data[at + 8 + length : at + 12 + length])
        assert crc == zlib.crc32(kind + body), kind
        found.append((kind, body))
        at += 12 + length
    assert at == len(data)
    return found


def read_with_pypng(data: bytes) -> np.ndarray:
    width, height, rows, info = png.Reader(bytes=data).read()
    assert info["planes"] == 3 and not info["alpha"] and not info["greyscale"]
    dtype = np.uint16 if info["bitdepth"] == 16 else np.uint8
    return np.vstack([np.asarray(row, dtype=dtype) for row in rows]).reshape(height, width, 3)


def pngcheck(path: Path) -> None:
    """pngcheck's verdict on the file, when it is installed: it checks every chunk, the zlib stream and its window."""
    if shutil.which("pngcheck") is None:
        return
    result = subprocess.run(["pngcheck", "-v", str(path)], capture_output=True, text=True, check=False)
    assert result.returncode == 0 and "No errors detected" in result.stdout, result.stdout


# ------------------------------------------------------------------------------------------------------------ PNG
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("shape", SIZES)
def test_png_decodes_to_exactly_the_codes_in_every_reader(tmp_path, dtype, shape):
    codes = codes_of(shape, dtype)
    path = tmp_path / "c.png"
    write_png(path, codes, description=DESCRIPTION, icc_profile=sRGB_profile())
    data = path.read_bytes()
    back = imagecodecs.png_decode(data)
    assert back.dtype == dtype and back.shape == codes.shape
    np.testing.assert_array_equal(back, codes)
    np.testing.assert_array_equal(read_with_pypng(data), codes)
    with Image.open(path) as image:  # Pillow opens 16-bit colour as 8 bit: the high byte of each code
        assert image.mode == "RGB" and image.size == (shape[1], shape[0])
        np.testing.assert_array_equal(np.asarray(image), codes if dtype == np.uint8 else codes >> 8)
    pngcheck(path)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_png_strips_join_into_one_zlib_stream_with_the_adler32_of_the_whole(monkeypatch, tmp_path, dtype):
    """Many strips, of a size that does not divide the height: one zlib header, one Adler-32, nothing after it."""
    codes = codes_of((53, 29), dtype, seed=3)
    row_bytes = 1 + 3 * codes.itemsize * 29
    monkeypatch.setattr(encoders, "_STRIP_BYTES", 4 * row_bytes)  # 4 rows a strip: 14 strips, the last of 1 row
    strips = png_strips(codes.shape, codes.itemsize)
    assert len(strips) == 14 and strips[-1] == (52, 53)
    data = encode_png(codes, threads=3)
    idat = [body for kind, body in chunks(data) if kind == b"IDAT"]
    assert len(idat) == 14  # a chunk a strip
    stream = b"".join(idat)
    assert stream[:2] == b"\x78\x01" and int.from_bytes(stream[:2], "big") % 31 == 0
    inflater = zlib.decompressobj()
    filtered = inflater.decompress(stream)  # zlib checks the Adler-32 at the end of the stream
    assert inflater.eof and inflater.unused_data == b""
    assert zlib.adler32(filtered) == int.from_bytes(stream[-4:], "big")
    assert len(filtered) == 53 * row_bytes
    assert set(filtered[::row_bytes]) == {3}  # every row the Average filter
    np.testing.assert_array_equal(imagecodecs.png_decode(data), codes)
    path = tmp_path / "strips.png"
    path.write_bytes(data)
    pngcheck(path)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_png_is_the_same_bytes_on_any_number_of_threads(dtype):
    codes = codes_of((1200, 640), dtype, seed=5)  # several strips at the real strip size
    assert len(png_strips(codes.shape, codes.itemsize)) >= 3
    one = encode_png(codes, description=DESCRIPTION, threads=1)
    assert encode_png(codes, description=DESCRIPTION, threads=2) == one
    assert encode_png(codes, description=DESCRIPTION, threads=5) == one
    assert encode_png(codes, description=DESCRIPTION) == one  # every kernel thread
    np.testing.assert_array_equal(imagecodecs.png_decode(one), codes)


def test_png_takes_codes_that_are_not_contiguous():
    wide = codes_of((40, 90), np.uint16, seed=7)
    view = wide[::2, 1::3]
    assert not view.flags.c_contiguous
    np.testing.assert_array_equal(imagecodecs.png_decode(encode_png(view)), view)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_png_metadata_chunks_come_after_IHDR_in_picamcals_order(tmp_path, dtype):
    profile = sRGB_profile()
    path = tmp_path / "m.png"
    write_png(path, codes_of((5, 4), dtype), description=DESCRIPTION, icc_profile=profile)
    found = chunks(path.read_bytes())
    kinds = [kind for kind, _ in found]
    assert kinds[:4] == [b"IHDR", b"iCCP", b"iTXt", b"tEXt"] and kinds[-1] == b"IEND"
    assert set(kinds[4:-1]) == {b"IDAT"}
    width, height, depth, colour, compression, filtering, interlace = struct.unpack(">IIBBBBB", found[0][1])
    assert (width, height, depth, colour, compression, filtering, interlace) == (4, 5, 8 * np.dtype(dtype).itemsize,
                                                                                   2, 0, 0, 0)  # fmt: skip
    name, _, compressed = found[1][1].partition(b"\x00")
    assert name == b"sRGB" and compressed[0] == 0 and zlib.decompress(compressed[1:]) == profile
    assert found[2][1] == b"picamcal\x00\x00\x00\x00\x00" + DESCRIPTION.encode("utf-8")
    assert found[3][1] == b"Software\x00" + SOFTWARE.encode("latin-1")
    with Image.open(path) as image:  # what picamcal's provenance reader and users' tools see
        assert image.info["picamcal"] == DESCRIPTION and image.info["Software"] == SOFTWARE
        assert image.info["icc_profile"] == profile
    pngcheck(path)


def test_png_needs_no_imagecodecs(monkeypatch):
    codes = codes_of((37, 53), np.uint16)
    with_it = encode_png(codes, description=DESCRIPTION)
    monkeypatch.setitem(sys.modules, "imagecodecs", None)  # import imagecodecs fails, as where it is not installed
    assert encode_png(codes, description=DESCRIPTION) == with_it
    np.testing.assert_array_equal(read_with_pypng(with_it), codes)


def test_png_without_metadata_has_only_the_image():
    data = encode_png(codes_of((3, 3), np.uint8), software=None)
    assert [kind for kind, _ in chunks(data)] == [b"IHDR", b"IDAT", b"IEND"]


def test_png_is_written_to_an_open_file_as_to_a_path(tmp_path):
    codes = codes_of((9, 11), np.uint16)
    buffer = io.BytesIO()
    write_png(buffer, codes, description=DESCRIPTION)
    write_png(tmp_path / "p.png", codes, description=DESCRIPTION)
    assert buffer.getvalue() == (tmp_path / "p.png").read_bytes() == encode_png(codes, description=DESCRIPTION)


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full (a device that is always full)")
def test_a_png_write_that_fails_raises_and_leaves_no_thread_behind():
    codes = codes_of((1200, 640), np.uint8, seed=9)  # several strips, deflated on 2 threads
    before = {thread.name for thread in threading.enumerate()}
    with pytest.raises(OSError, match="No space left on device"):
        write_png("/dev/full", codes, threads=2)
    assert {thread.name for thread in threading.enumerate()} <= before


# ----------------------------------------------------------------------------------------------------------- JPEG
def pillow_jpeg(codes: np.ndarray, quality: int, profile: bytes | None, description: str) -> bytes:
    """The JPEG Pillow writes with picamcal's settings: quality, 4:4:4, the ICC profile and the EXIF IFD0."""
    exif = Image.Exif()
    exif[0x010E], exif[0x0131] = description, SOFTWARE
    exif.update({0x011A: 72.0, 0x011B: 72.0, 0x0128: 2, 0x0213: 1})
    out = io.BytesIO()
    Image.fromarray(codes).save(out, "JPEG", quality=quality, subsampling=0, icc_profile=profile, exif=exif.tobytes())
    return out.getvalue()


def head_segments(data: bytes) -> list[bytes]:
    """The JPEG's segments before the scan, whole (marker, length and payload)."""
    found, at = [], 2
    while data[at + 1] != 0xDA:
        length = int.from_bytes(data[at + 2 : at + 4], "big")
        found.append(data[at : at + 2 + length])
        at += 2 + length
    return found


@pytest.mark.parametrize("backend", ["installed", "pillow"])
@pytest.mark.parametrize("shape", [(1, 1), (37, 53), (64, 96)])
def test_jpeg_is_pillows_jpeg_with_the_same_settings(monkeypatch, backend, shape):
    """Either encoder (imagecodecs' libjpeg-turbo, or Pillow without imagecodecs): Pillow's tables, segments and
    pixels, at quality 95 and 92."""
    if backend == "pillow":
        monkeypatch.setitem(sys.modules, "imagecodecs", None)  # import imagecodecs fails, as where it is not installed
    codes = codes_of(shape, np.uint8, seed=11)
    profile = sRGB_profile()
    for quality in (95, 92):
        ours = encode_jpeg(codes, quality=quality, description=ASCII_DESCRIPTION, icc_profile=profile)
        theirs = pillow_jpeg(codes, quality, profile, ASCII_DESCRIPTION)
        assert head_segments(ours) == head_segments(theirs)  # JFIF, EXIF, ICC, quantisation, frame, Huffman tables
        np.testing.assert_array_equal(
            np.asarray(Image.open(io.BytesIO(ours))), np.asarray(Image.open(io.BytesIO(theirs)))
        )


def test_jpeg_carries_the_profile_exif_and_4_4_4(tmp_path):
    profile = sRGB_profile()
    description = json.dumps({"picamcal": {"source": "j.dng", "note": "µm"}})  # json.dumps escapes to ASCII
    path = tmp_path / "j.jpg"
    write_jpeg(path, codes_of((48, 80), np.uint8), quality=95, description=description, icc_profile=profile)
    with Image.open(path) as image:
        assert image.format == "JPEG" and image.mode == "RGB" and image.size == (80, 48)
        assert image.info["icc_profile"] == profile
        exif = image.getexif()
        assert exif[0x010E] == description and json.loads(exif[0x010E])["picamcal"]["note"] == "µm"
        assert exif[0x0131] == SOFTWARE and (exif[0x011A], exif[0x011B], exif[0x0128], exif[0x0213]) == (72, 72, 2, 1)
    frame = next(s for s in head_segments(path.read_bytes()) if s[1] == 0xC0)  # baseline
    assert [frame[11 + 3 * k] for k in range(3)] == [0x11, 0x11, 0x11]  # every component 1x1: no subsampling
    if shutil.which("exiftool"):
        result = subprocess.run(["exiftool", "-validate", "-warning", "-a", str(path)], capture_output=True,
                                text=True, check=True)  # fmt: skip
        assert "Validate                        : OK" in result.stdout, result.stdout
        assert "Warning" not in result.stdout, result.stdout


def test_a_profile_over_one_segment_is_split_as_pillow_splits_it(monkeypatch):
    big = sRGB_profile() + bytes(range(256)) * 300  # 77 kB: two APP2 segments
    codes = codes_of((16, 16), np.uint8)
    ours = encode_jpeg(codes, quality=90, icc_profile=big)
    assert Image.open(io.BytesIO(ours)).info["icc_profile"] == big
    app2 = [s for s in head_segments(ours) if s[1] == 0xE2]
    assert [s[4:18] for s in app2] == [b"ICC_PROFILE\x00\x01\x02", b"ICC_PROFILE\x00\x02\x02"]
    monkeypatch.setitem(sys.modules, "imagecodecs", None)
    assert head_segments(encode_jpeg(codes, quality=90, icc_profile=big)) == head_segments(ours)


# --------------------------------------------------------------------------------------------------- uint16 codes
@pytest.mark.parametrize("c_kernel", ["built", "absent"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_uint16_codes_are_the_kernels_codes_on_any_number_of_threads(dtype, c_kernel, request):
    if c_kernel == "absent":  # float32 images are converted by the C kernel where it is built, else by numpy
        request.getfixturevalue("no_c_kernel")
    rng = np.random.default_rng(2)
    rgb = (rng.random((123, 517, 3)) * 2.2 - 0.1).astype(dtype)
    edges = [np.nan, np.inf, -np.inf, np.finfo(dtype).max, -np.finfo(dtype).max, 0.5 / UINT16_WHITE,
             1.5 / UINT16_WHITE, 65534.5 / UINT16_WHITE, 65535.5 / UINT16_WHITE, -0.0, 1.0, 2.0]  # fmt: skip
    rgb.reshape(-1)[: len(edges)] = edges
    expected = np.empty(rgb.shape, np.uint16)
    with np.errstate(over="ignore"):
        encode_codes(rgb, UINT16_WHITE, expected)
    assert expected.reshape(-1)[: len(edges)].tolist() == [0, 65535, 0, 65535, 0, 0, 2, 65534, 65535, 0, 32768, 65535]
    for threads in (1, 2, 7):
        np.testing.assert_array_equal(encode_uint16(rgb, threads=threads), expected)
    np.testing.assert_array_equal(encode_uint16(rgb[:, ::-2]), expected[:, ::-2])  # a view of the image


@pytest.mark.parametrize("compression", [None, "zstd"])
def test_uint16_tiff_is_tifffiles_file_of_the_codes_from_the_image_or_the_codes(tmp_path, compression):
    """Strips converted and compressed on several threads: the same bytes as tifffile's own write of the codes."""
    rng = np.random.default_rng(4)
    rgb = (rng.random((301, 3001, 3)) * 2.2 - 0.1).astype(np.float32)  # 22 strips of 14 rows, the last of 7
    rgb[0, 0] = [np.nan, np.inf, -1.0]
    codes = encode_uint16(rgb)
    rows = uint16_rows_per_strip(3001)
    assert rows == 14  # 256 kB strips
    info = {"source": "a.dng"}
    written = []
    for name, image, threads in (("float", rgb, 3), ("float1", rgb, 1), ("codes", codes, 2)):
        path = write_tiff(tmp_path / f"{name}.tiff", image, "uint16-tiff", info, compression=compression,
                          threads=threads)  # fmt: skip
        written.append(path.read_bytes())
    with tifffile.TiffFile(tmp_path / "float.tiff") as tif:
        page = tif.pages.first
        assert page.rowsperstrip == rows and len(page.dataoffsets) == -(-301 // rows)
        assert page.compression.name == ("ZSTD" if compression else "NONE") and page.predictor == (2 if compression
                                                                                                    else 1)  # fmt: skip
        np.testing.assert_array_equal(tif.asarray(), codes)
        description = page.description
    tifffile.imwrite(tmp_path / "tifffile.tiff", codes, photometric="rgb", planarconfig="contig",
                     description=description, software=SOFTWARE, metadata=None, compression=compression,
                     predictor=True if compression else None, rowsperstrip=rows)  # fmt: skip
    assert written[0] == written[1] == written[2] == (tmp_path / "tifffile.tiff").read_bytes()


# ------------------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("codes", "message"),
    [
        (np.zeros((4, 4, 3), np.float32), "from uint8 or uint16 codes, not float32"),
        (np.zeros((4, 4, 3), np.int16), "from uint8 or uint16 codes, not int16"),
        (np.zeros((4, 4), np.uint8), r"\(H, W, 3\) codes with H and W at least 1, not \(4, 4\)"),
        (np.zeros((4, 4, 4), np.uint8), r"not \(4, 4, 4\)"),
        (np.zeros((0, 4, 3), np.uint8), r"not \(0, 4, 3\)"),
        (np.zeros((4, 0, 3), np.uint16), r"not \(4, 0, 3\)"),
    ],
)
def test_png_refuses_what_are_not_codes(tmp_path, codes, message):
    with pytest.raises(ValueError, match=message):
        write_png(tmp_path / "x.png", codes)
    assert not (tmp_path / "x.png").exists()  # refused before the file is opened


def test_png_and_jpeg_refuse_bad_settings():
    codes = np.zeros((4, 4, 3), np.uint8)
    for threads in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="threads is a whole number of at least 1"):
            encode_png(codes, threads=threads)
    with pytest.raises(ValueError, match="a JPEG is written from uint8 codes, not uint16"):
        encode_jpeg(codes.astype(np.uint16), quality=95)
    for quality in (0, 101, 9.5, True):
        with pytest.raises(ValueError, match="quality is a whole number from 1 to 100"):
            encode_jpeg(codes, quality=quality)
    with pytest.raises(ValueError, match="at most 65535 pixels wide and high, not 65536x1"):
        encode_jpeg(np.broadcast_to(codes[:1, :1], (1, 65536, 3)), quality=95)
