"""The virtual camera's parts that picamera2 meets first: libcamera's value types and configurations as a Pi 4 and a
Pi 5 give them, the PiSP compression, the stand-in for the kernel's DMA heap, and how the virtual camera is (and is
not) put in place. The runs of the real picamera2 on it are in test_virtualcam_picamera2.py."""

from __future__ import annotations

import ctypes
import mmap
import os
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest

from picamcal.cli import main
from picamcal.raw.picamera2.pisp import pisp_compress, pisp_decompress
from picamcal.virtualcam import Options, VirtualCameraError, shim_directory
from picamcal.virtualcam.buffers import FrameBufferAllocator
from picamcal.virtualcam.camera import CameraManager
from picamcal.virtualcam.config import StreamRole, find_best_mode, output_layout, raw_stride
from picamcal.virtualcam.controls import CONTROLS, controls, properties
from picamcal.virtualcam.kernel import HEAP_PATHS, VIRTUAL_FCNTL, VIRTUAL_OS, installed, kind_of
from picamcal.virtualcam.modes import scaled_spec, sensor_spec
from picamcal.virtualcam.values import ColorSpace, Orientation, PixelFormat, Rectangle, Size, Transform


def manager(platform: str = "pisp", sensor: str = "imx477", size: tuple[int, int] = (640, 480)) -> CameraManager:
    return CameraManager(Options(platform=platform, sensor=sensor, size=size), environ={})


# -- libcamera's value types -------------------------------------------------------------------------------------


def test_sizes_and_rectangles_follow_libcamera_arithmetic():
    # geometry.cpp: aspect-ratio bounds round down, a centred size keeps its top-left in whole pixels.
    assert Size(4056, 3040).bounded_to_aspect_ratio(Size(16, 9)) == Size(4056, 2281)
    assert Size(640, 480).expanded_to_aspect_ratio(Size(16, 9)) == Size(853, 480)
    assert Size(100, 50).centered_to(Rectangle(Size(640, 480)).center) == Rectangle(270, 215, 100, 50)
    assert Rectangle(10, 10, 100, 100).enclosed_in(Rectangle(0, 0, 50, 50)) == Rectangle(0, 0, 50, 50)
    assert Rectangle(8, 4, 40, 20).scaled_by(Size(1, 2), Size(2, 1)) == Rectangle(4, 8, 20, 40)
    # Size orders as libcamera's operator<: both smaller, else by area.
    assert Size(10, 10) < Size(20, 20) and not Size(20, 5) < Size(10, 10) and Size(10, 5) < Size(4, 20)
    with pytest.raises(TypeError):
        hash(Size(1, 1))  # pybind11 makes a class with == and no hash unhashable


def test_transforms_compose_as_libcamera_and_pixel_formats_name_their_codes():
    t = Transform(rotation=90)
    assert (t.hflip, t.vflip, t.transpose) == (False, True, True)
    assert str(t.inverse()) == "<libcamera.Transform 'rot270'>"
    with pytest.raises(ValueError, match="Invalid rotation"):
        Transform(rotation=45)
    assert str(ColorSpace.Sycc()) == "<libcamera.ColorSpace 'sYCC'>"
    assert PixelFormat("SBGGR12_CSI2P") != PixelFormat("SBGGR12")  # the same fourcc, another modifier
    assert PixelFormat("XBGR8888").fourcc == int.from_bytes(b"XB24", "little")
    assert str(PixelFormat("nonsense")) == "<INVALID>"


def test_controls_carry_libcamera_ids_types_and_enums():
    # control_ids_*.yaml numbering and gen-py-controls.py's enum names (the common prefix removed).
    assert (controls.ExposureTime.id, controls.AnalogueGain.type.name, controls.ColourGains.size) == (7, "Float", 2)
    assert controls.draft.NoiseReductionModeEnum.Minimal == 3 and controls.rpi.ScalerCrops.id == 20003
    assert controls.AeMeteringModeEnum.CentreWeighted == 0 and controls.draft.LensShadingMapModeEnum.On == 1
    assert properties.draft.ColorFilterArrangementEnum.MONO == 5
    assert set(CONTROLS) >= {"SensorTimestamp", "ScalerCrop", "FrameDurationLimits", "SyncReady"}


# -- configurations, as each platform gives them -------------------------------------------------------------------


def test_strides_are_the_drivers():
    # Unicam aligns rows to 32 bytes, the PiSP front end to 64; bcm2835-isp aligns 24-bit rows to 32 pixels.
    assert raw_stride("SBGGR12_CSI2P", 4056, "vc4") == 6112 and raw_stride("SBGGR12", 4056, "vc4") == 8128
    assert raw_stride("SBGGR16", 4056, "pisp") == 8128 and raw_stride("BGGR_PISP_COMP1", 4056, "pisp") == 4096
    assert output_layout("RGB888", Size(1332, 990), 0, "vc4").stride == 1344 * 3
    assert output_layout("XBGR8888", Size(1332, 990), 0, "pisp").stride == 5376
    layout = output_layout("YUV420", Size(1332, 990), 0, "pisp")
    assert (layout.stride, layout.frame_size) == (1408, 1408 * 990 * 3 // 2)


def test_modes_are_chosen_as_libcamera_scores_them():
    modes = sensor_spec("imx477").modes
    best = find_best_mode(modes, 640, 480, 12)
    assert (best.width, best.height, round(best.max_fps, 2)) == (2028, 1520, 40.01)
    assert (find_best_mode(modes, 1332, 990, 10).width, find_best_mode(modes, 4056, 3040, 12).width) == (1332, 4056)


@pytest.mark.parametrize(
    ("platform", "asked", "given"),
    [
        ("vc4", "SRGGB12", "SBGGR12"),  # the Pi 4 keeps the sensor's depth, unpacked
        ("vc4", "SRGGB12_CSI2P", "SBGGR12_CSI2P"),
        ("pisp", "SRGGB12", "SBGGR16"),  # the Pi 5 writes unpacked as 16 bits
        ("pisp", "SRGGB12_CSI2P", "BGGR_PISP_COMP1"),  # and packed as its compressed format
    ],
)
def test_raw_formats_follow_the_platform_and_the_flips(platform, asked, given):
    # The HQ camera is mounted rotated 180: libcamera flips it, so its native RGGB reads BGGR.
    camera = manager(platform).cameras[0]
    camera.acquire()
    config = camera.generate_configuration([StreamRole.Viewfinder, StreamRole.Raw])
    config.at(1).pixel_format = PixelFormat(asked)
    assert config.validate() == config.Status.Adjusted
    assert str(config.at(1).pixel_format) == given and config.validate() == config.Status.Valid
    assert str(config.at(0).pixel_format) == "XRGB8888"
    config.orientation = Orientation.Rotate180  # no flips then: the native order
    config.validate()
    assert str(config.at(1).pixel_format).replace("S", "", 1).startswith("RGGB")
    config.orientation = Orientation.Rotate90  # needs a transpose the sensor cannot do
    assert config.validate() == config.Status.Adjusted and config.orientation == Orientation.Rotate180


def test_impossible_configurations_are_invalid_and_sizes_are_adjusted():
    camera = manager("vc4").cameras[0]
    camera.acquire()
    config = camera.generate_configuration([StreamRole.Raw, StreamRole.Raw])
    assert config.validate() == config.Status.Invalid  # one raw stream at most
    config = camera.generate_configuration([StreamRole.Viewfinder, StreamRole.Raw])
    config.at(1).size = Size(1000, 1000)  # no such mode: the nearest one
    assert config.validate() == config.Status.Adjusted and config.at(1).size in [
        Size(m.width, m.height) for m in scaled_spec(sensor_spec("imx477"), (640, 480)).modes
    ]
    with pytest.raises(RuntimeError, match="Failed to start camera: Permission denied"):
        camera.start()


# -- the Pi 5's compressed raw format ------------------------------------------------------------------------------


def test_pisp_compression_decodes_with_both_decoders_within_its_quantisation():
    rng = np.random.default_rng(3)
    for level, step in ((3000, 16), (20000, 64), (60000, 128)):  # mode 0, 1 and 2 quantisation steps
        mosaic = rng.normal(level, 4 * np.sqrt(level), (8, 64)).clip(0, 65535).astype(np.uint16)
        rows = pisp_compress(mosaic, 64)
        decoded = pisp_decompress(rows, 64).astype(int)
        # Within half a step of the mode a smooth patch uses (a sample at the end of a step may round to the next).
        assert np.abs(decoded - mosaic.astype(int)).max() <= step


def test_the_compiled_pisp_compressor_writes_the_numpy_paths_words(monkeypatch):
    # The compiled compressor makes every word in all three modes without branches; the numpy path is the reference.
    # Random samples over the whole range reach mode 2 and each of its clamps; a smooth ramp with noise, the modes'
    # edges; rows of a width that is no multiple of 8, the padding.
    pytest.importorskip("numba")
    from picamcal.raw.picamera2 import pisp

    rng = np.random.default_rng(9)
    mosaics = []
    for shift, top in ((0, 65536), (4, 4096), (6, 1024)):
        ramp = np.linspace(0, top - 1, 70)[None, :] + rng.normal(0, top / 400, (200, 70))
        mosaics.append((shift, rng.integers(0, top, (200, 70)).astype(np.uint16)))
        mosaics.append((shift, ramp.clip(0, top - 1).astype(np.uint16)))
    compiled = [pisp_compress(mosaic, 80, shift=shift) for shift, mosaic in mosaics]
    monkeypatch.setattr(pisp, "_compiled_words", lambda: None)
    for (shift, mosaic), words in zip(mosaics, compiled, strict=True):
        np.testing.assert_array_equal(words, pisp_compress(mosaic, 80, shift=shift))


def test_the_compiled_kernels_write_the_numpy_paths_bytes(monkeypatch):
    # The compiled render goes from the raw frame straight to the output's pixels, row block by row block (a block's
    # first row made afresh, the rows that repeat it copied); numpy develops the sampled quads and then writes them.
    # A stock tuning's lens shading makes each site's gains differ, so a site or quad taken for another shows.
    pytest.importorskip("numba")
    from picamcal.export.isp import SensorMode
    from picamcal.export.tuning import load_tuning, stock_tuning_path
    from picamcal.raw.picamera2 import pisp
    from picamcal.virtualcam import isp

    frame = np.random.default_rng(5).integers(0, 4096, (96, 140)).astype(np.uint16)
    frame[:, :20] //= 40  # dark columns, for the finer PiSP quantisation modes
    ccm = np.array([[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [0.0, -0.5, 1.5]])
    outputs = [
        ("XRGB8888", 200, 150, 832),  # larger than the quads: rows and columns repeated, over two row blocks
        ("XBGR8888", 48, 30, 256),
        ("BGR888", 20, 12, 64),
        ("RGB888", 180, 140, 576),
        ("RGB161616", 33, 21, 208),
        ("YUV420", 32, 24, 32),
        ("NV21", 150, 130, 160),
    ]
    raws = [("SGRBG12_CSI2P", 224), ("SGRBG10_CSI2P", 192), ("GRBG_PISP_COMP1", 192)]
    tuning = load_tuning(stock_tuning_path("imx477", "pisp"))

    def run() -> list[np.ndarray]:
        stage = isp.Isp(tuning, SensorMode.full(140, 96), "GRBG", 12, 4096, None)
        written = []
        for name, width, height, stride in outputs:
            rows, cols = isp.sample_indices((8, 4, 120, 88), width, height, (70, 48))
            plan = isp.OutputPlan(isp.Layout(name, width, height, stride, 2 * stride * height), None, rows, cols)
            dest = np.full(2 * stride * height, 7, dtype=np.uint8)
            stage.render(frame, 5000.0, plan, (1.8, 1.4), 1.2, ccm, dest)
            written.append(dest)
        for name, stride in raws:
            dest = np.full((96, stride), 7, dtype=np.uint8)
            isp.encode_raw(frame >> (2 if "10" in name else 0), isp.Layout(name, 140, 96, stride, 96 * stride),
                           10 if "10" in name else 12, dest)  # fmt: skip
            written.append(dest)
        return written

    compiled = run()
    for getter in ("_compiled_render", "_compiled_pack"):
        monkeypatch.setattr(isp, getter, lambda: None)
    monkeypatch.setattr(pisp, "_compiled_words", lambda: None)
    for fast, slow in zip(compiled, run(), strict=True):
        np.testing.assert_array_equal(fast, slow)
    pixels = compiled[0].reshape(-1, 832)[:150, :800].view("<u4")
    assert len(np.unique(pixels)) > 1000 and np.all(pixels >> 24 == 255)  # varied colours; the X bytes 255


@pytest.mark.parametrize("width", [140, 139, 138, 137])
@pytest.mark.parametrize("bits", [10, 12])
def test_the_compiled_packer_writes_packs_bytes_for_any_width(width, bits):
    # A row's whole groups take the vectorised loop; a group the row's end cuts short is padded with zeros, and the
    # stride's padding is zero, as pack writes them.
    pytest.importorskip("numba")
    from picamcal.raw.packing import pack
    from picamcal.virtualcam import isp

    frame = np.random.default_rng(width).integers(0, 1 << bits, (6, width)).astype(np.uint16)
    dest = np.full((6, 256), 7, np.uint8)
    isp.encode_raw(frame, isp.Layout(f"SGRBG{bits}_CSI2P", width, 6, 256, 6 * 256), bits, dest)
    np.testing.assert_array_equal(dest, pack(frame, bits, 256))


def test_a_raw_buffer_too_short_for_a_packed_row_is_refused_by_both_paths(monkeypatch):
    # The compiled packer writes whole rows with no bounds check: a stride short of a row would write past the buffer
    # (memory corruption); both paths refuse it, as pack does.
    from picamcal.virtualcam import isp

    frame = np.zeros((4, 140), np.uint16)  # a 12-bit packed row of 140 pixels is 210 bytes
    for compiled in (True, False):
        if not compiled:
            monkeypatch.setattr(isp, "_compiled_pack", lambda: None)
        with pytest.raises(ValueError, match="stride 192 is shorter than the 210 bytes of a row"):
            isp.encode_raw(frame, isp.Layout("SGRBG12_CSI2P", 140, 4, 192, 768), 12, np.zeros((4, 192), np.uint8))


def test_the_statistics_from_the_raw_frame_are_those_of_the_isps_planes():
    # The IPA's statistics come from the raw frame (the sensor's stage), so that the ISP can process a frame while
    # the next is read out: they are the clipped means of the linear planes on the same coarse grid, to the bit.
    from picamcal.export.isp import SensorMode
    from picamcal.export.tuning import load_tuning, stock_tuning_path
    from picamcal.virtualcam import isp

    frame = np.random.default_rng(8).integers(0, 4096, (300, 410)).astype(np.uint16)
    frame[:40] = 4095  # saturated rows, for the clipping
    tuning = load_tuning(stock_tuning_path("imx477", "pisp"))  # its lens shading: gains up to 1.58
    for order in ("GRBG", "BGGR"):
        stage = isp.Isp(tuning, SensorMode.full(410, 300), order, 12, 4096, None)
        planes = stage.linear_planes(frame, 4000.0)
        step = max(1, min(planes[0].shape) // 64)
        means = [[], [], []]
        for site, channel in enumerate(stage.channels):
            means[channel].append(float(np.clip(planes[site][::step, ::step], 0, 1).mean()))
        assert stage.statistics(frame, 4000.0) == tuple(sum(m) / len(m) for m in means)


# -- the kernel's part ---------------------------------------------------------------------------------------------


class _Allocation(ctypes.Structure):  # linux/dma-heap.h dma_heap_allocation_data, as picamera2 declares it
    _fields_ = [
        ("len", ctypes.c_uint64),
        ("fd", ctypes.c_uint32),
        ("fd_flags", ctypes.c_uint32),
        ("heap_flags", ctypes.c_uint64),
    ]


def test_the_dma_heap_gives_memfd_buffers_that_map():
    heap = VIRTUAL_OS.open(HEAP_PATHS[0], os.O_RDWR | os.O_CLOEXEC)
    try:
        assert kind_of(heap) == "heap"
        request = (3 << 30) | (ctypes.sizeof(_Allocation) << 16) | (ord("H") << 8)  # _IOWR('H', 0, ...)
        allocation = _Allocation(len=12345)
        assert VIRTUAL_FCNTL.ioctl(heap, request, allocation) == 0
        assert kind_of(allocation.fd) == "buffer" and os.fstat(allocation.fd).st_size == 12345
        assert VIRTUAL_FCNTL.ioctl(allocation.fd, (1 << 30) | (8 << 16) | (ord("b") << 8), b"\0" * 8) == 0  # sync
        with mmap.mmap(allocation.fd, 12345) as memory:
            memory[:3] = b"abc"
        os.close(allocation.fd)
    finally:
        os.close(heap)
    assert kind_of(1) is None  # any other descriptor is left to the real kernel
    assert installed("/usr/share/libcamera/ipa/rpi/pisp/imx477.json") != "/usr/share/libcamera/ipa/rpi/pisp/imx477.json"


# -- putting it in place -------------------------------------------------------------------------------------------


def python(code: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120, env=env
    )


def test_the_shim_is_not_importable_without_install():
    result = python("import libcamera")
    assert result.returncode == 1 and "No module named 'libcamera'" in result.stderr
    assert (shim_directory() / "libcamera" / "__init__.py").is_file()


@pytest.mark.slow
def test_install_refuses_when_a_real_libcamera_is_importable(tmp_path):
    real = tmp_path / "libcamera"
    real.mkdir()
    (real / "__init__.py").write_text("")
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    code = """
        from picamcal.virtualcam import VirtualCameraError, install
        try:
            install(sensor="imx219", size=(640, 480))
        except VirtualCameraError as exc:
            print("refused:", exc)
        install(sensor="imx219", size=(640, 480), force=True)
        import libcamera
        print(libcamera.__file__)
    """
    result = python(code, env)
    assert result.returncode == 0, result.stderr
    refused, used = result.stdout.splitlines()
    assert refused.startswith(f"refused: a real libcamera is importable ({real / '__init__.py'})")
    assert used == str(shim_directory() / "libcamera" / "__init__.py")


def test_the_cli_refuses_bad_use_in_one_line(capsys):
    for args, message in (
        ([], "give the command to run after --"),
        (["--", "no-such-command-here"], "no-such-command-here: command not found"),
        (["--sensor", "imx2l9", "--", "true"], "unknown sensor 'imx2l9'; did you mean imx219?"),
        (["--sensor", "imx296_mono", "--", "true"], "monochrome sensor"),
        (["--size", "9000x9000", "--", "true"], "at most 4056x3040"),
    ):
        with pytest.raises(SystemExit) as exit_:
            main(["virtual-camera", *args])
        lines = capsys.readouterr().err.strip().splitlines()
        assert exit_.value.code == 2 and len(lines) == 1 and message in lines[0], lines


def test_a_tuning_file_of_the_other_platform_registers_no_camera(capfd):
    from picamcal.export.tuning import stock_tuning_path

    pisp = str(stock_tuning_path("imx477", "pisp"))
    camera_manager = CameraManager(
        Options(platform="vc4", size=(640, 480)), environ={"LIBCAMERA_RPI_TUNING_FILE": pisp}
    )
    assert camera_manager.cameras == []  # as on a Pi 4: the IPA fails, the camera is not registered
    assert 'Tuning data file target returned "pisp", expected "bcm2835"' in capfd.readouterr().err  # on descriptor 2
    with pytest.raises(VirtualCameraError, match='expected "bcm2835"'):
        from picamcal.virtualcam import check

        check(Options(platform="vc4"), environ={"LIBCAMERA_RPI_TUNING_FILE": pisp})


def test_row_blocks_run_on_while_the_interpreter_exits():
    # The virtual camera's frame thread (a daemon) goes on making frames while a script's interpreter exits, when
    # concurrent.futures takes no new work: the blocks then run in the frame thread, and no frame fails.
    code = textwrap.dedent(
        """
        import sys, threading, time
        import numpy as np
        from picamcal._rows import in_row_blocks

        rows = np.zeros(4096)

        def fill(start, stop):
            rows[start:stop] += 1

        def frames():
            while True:
                try:
                    in_row_blocks(fill, len(rows))
                except Exception as exc:
                    print("failed:", repr(exc), file=sys.stderr, flush=True)
                    return

        threading.Thread(target=frames, daemon=True).start()
        time.sleep(0.3)
        """
    )
    for _ in range(3):
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0 and "failed" not in done.stderr, done.stderr


def test_a_request_knows_its_camera_by_what_it_needs_of_it():
    """``request`` imports nothing of ``camera`` (not even for the type checker): a request takes its owner's
    controls, and the camera tells its own requests by their owner (the next test)."""
    import ast

    from picamcal.virtualcam import request

    tree = ast.parse(open(request.__file__, encoding="utf-8").read())
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert "camera" not in imported and "picamcal.virtualcam.camera" not in imported


@pytest.mark.slow
def test_a_camera_refuses_another_cameras_request():
    """camera.cpp queueRequest: a request made by another camera is refused (-EXDEV)."""
    cameras = []
    for _ in range(2):
        camera = manager().cameras[0]
        camera.acquire()
        config = camera.generate_configuration([StreamRole.Raw])
        config.validate()
        camera.configure(config)
        cameras.append(camera)
    camera, other = cameras
    camera.start()
    try:
        with pytest.raises(RuntimeError, match="Failed to queue request: Invalid cross-device link"):
            camera.queue_request(other.create_request())
    finally:
        camera.stop()


def test_a_frame_completing_as_the_camera_stops_is_signalled_before_stop_returns(monkeypatch):
    """camera.cpp stop(): every request completes before ``Camera::stop()`` returns, and none after. A frame whose
    completion is under way as the camera stops (its thread descheduled on a busy machine; here a hook holds it half a
    second) is signalled before stop() returns. picamera2 flushes the completed requests right after stopping: one
    signalled later came back to it as a frame of the next configuration, failed its event loop and left every
    request held (the next test shows it through picamera2)."""
    completing = threading.Event()
    original = CameraManager._complete

    def descheduled(self, request):
        if threading.current_thread().name.endswith("ISP"):
            completing.set()
            time.sleep(0.5)
        original(self, request)

    monkeypatch.setattr(CameraManager, "_complete", descheduled)
    cameras = manager(size=(320, 240))
    camera = cameras.cameras[0]
    camera.acquire()
    config = camera.generate_configuration([StreamRole.Raw])
    config.validate()
    camera.configure(config)
    stream = config.at(0).stream
    allocator = FrameBufferAllocator(camera)
    allocator.allocate(stream)
    requests = []
    for i, buffer in enumerate(allocator.buffers(stream)):
        request = camera.create_request(i)
        request.add_buffer(stream, buffer)
        requests.append(request)
    camera.start()
    for request in requests:
        camera.queue_request(request)
    assert completing.wait(30)
    camera.stop()
    signalled = cameras.get_ready_requests()
    time.sleep(1.0)
    assert cameras.get_ready_requests() == []  # nothing after stop() returned
    assert sorted(r.cookie for r in signalled) == list(range(len(requests)))
    assert any(r.status == r.Status.Complete for r in signalled)  # the frame under way, complete
    camera.release()
