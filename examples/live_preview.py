"""Live preview with the colour unmixing applied, on a Raspberry Pi (picamera2).

Usage (on the Pi, with a calibration and the tuning file exported from it)::

    picamcal export-tuning cal.npz --target pisp --ccm --out tuning.json   # once (--target vc4 on a Pi 4)
    python3 examples/live_preview.py cal.npz tuning.json   # --size 1332x990 --format XBGR8888 --seconds 0 (forever)
    python3 examples/live_preview.py cal.npz tuning.json --no-preview --seconds 10   # no display: time 10 s of frames
    python3 examples/live_preview.py cal.npz tuning.json --sensor-mode 1640x1232 --zoom 2   # binned mode, 2x zoom

It opens the camera with the exported tuning (adaptive contrast off, so that the tone curve is the file's), freezes
the white balance at the calibration's white (the gains ``picamcal acquire`` froze for the references), prepares a
:class:`picamcal.live.LiveUnmixer` for the preview stream from the running camera (``LiveUnmixer.for_camera``: its
sensor mode, ScalerCrop and colour temperature) and sets it as picamera2's ``pre_callback``: every frame is unmixed
in place before the preview shows it, in any sensor mode, crop and zoom inside the calibration's area (the unmixer
follows ScalerCrop changes). docs/live.md says what to install. What does not fit (a tuning for
the other Raspberry Pi, a stream the unmixer was not prepared for) stops it with one line and exit status 2.
"""

from __future__ import annotations

import argparse
import copy
import sys
import time

from picamcal import PicamcalError, load_calibration
from picamcal.acquire.cameras import check_tuning_target
from picamcal.export.isp import calibration_colour_gains
from picamcal.export.tuning import load_tuning
from picamcal.live import LiveUnmixer


def main() -> None:
    try:
        run()
    except PicamcalError as exc:
        print(f"live_preview: error: {exc}", file=sys.stderr)
        sys.exit(2)


def parse_size(text: str) -> tuple[int, int]:
    width, _, height = text.lower().partition("x")
    if not (width.isdigit() and height.isdigit() and int(width) > 0 and int(height) > 0):
        raise PicamcalError(f"{text!r} is not a size WIDTHxHEIGHT in pixels")
    return int(width), int(height)


def run() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("calibration", help="calibration file (picamcal calibrate)")
    parser.add_argument("tuning", help="the tuning file exported from it (picamcal export-tuning)")
    parser.add_argument("--size", default="1332x990", help="preview stream size WIDTHxHEIGHT")
    parser.add_argument(
        "--format", default="XBGR8888", help="XBGR8888 or XRGB8888 (what the Qt preview shows), RGB888 or BGR888"
    )
    parser.add_argument("--mode", default="centre", choices=("centre", "pure"))
    parser.add_argument("--sensor-mode", help="the sensor mode by its size, WIDTHxHEIGHT (default: picamera2's choice)")
    parser.add_argument("--zoom", type=float, default=1.0, help="digital zoom (2: a centred ScalerCrop half the size)")
    parser.add_argument("--seconds", type=float, default=0, help="stop after this long (0: until Ctrl-C)")
    parser.add_argument("--no-preview", action="store_true", help="no window: time the frames only")
    args = parser.parse_args()
    width, height = parse_size(args.size)
    if not args.zoom >= 1:
        raise PicamcalError(f"--zoom {args.zoom}: give 1 or more (the ScalerCrop cannot be larger than the mode)")

    import picamera2
    from picamera2 import Picamera2, Preview

    calibration = load_calibration(args.calibration)
    tuning = copy.deepcopy(load_tuning(args.tuning))
    for algorithm in tuning["algorithms"]:
        if "rpi.contrast" in algorithm:
            algorithm["rpi.contrast"]["ce_enable"] = 0  # a fixed tone curve, so that it can be undone exactly
    gains = calibration_colour_gains(calibration)
    check_tuning_target(tuning, picamera2, args.tuning)  # not a bare IndexError from picamera2

    picam2 = Picamera2(tuning=tuning)
    raw = {"size": parse_size(args.sensor_mode)} if args.sensor_mode else {}  # picamera2 picks the mode nearest it
    config = picam2.create_preview_configuration(main={"size": (width, height), "format": args.format}, raw=raw)
    picam2.configure(config)
    picam2.set_controls({"AwbEnable": False, "ColourGains": gains})
    if not args.no_preview:
        picam2.start_preview(Preview.QTGL)
    picam2.start()  # uncorrected for the second or so the preparation takes
    # From the running camera: its sensor mode, the sensor area the stream shows (ScalerCrop), the colour temperature
    # libcamera picks its tables and colour matrix at; the stream's size and format are checked against the
    # configuration here, not per frame.
    unmixer = LiveUnmixer.for_camera(picam2, calibration, tuning=tuning, mode=args.mode, colour_gains=gains)
    print(f"unmixing {unmixer.sensor_mode.describe()}, showing the sensor area {unmixer.crop}")
    if args.zoom != 1:
        # Digital zoom: a centred ScalerCrop, the zoom times smaller; the unmixer follows it from the next frames.
        x, y, w, h = picam2.camera_controls["ScalerCrop"][1]
        zw, zh = round(w / args.zoom), round(h / args.zoom)
        picam2.set_controls({"ScalerCrop": (x + (w - zw) // 2, y + (h - zh) // 2, zw, zh)})

    times: list[float] = []

    def callback(request: object) -> None:
        start = time.perf_counter()
        unmixer.callback(request)
        times.append(time.perf_counter() - start)

    picam2.pre_callback = callback
    try:
        end = time.monotonic() + args.seconds if args.seconds else float("inf")
        while time.monotonic() < end:
            time.sleep(min(1.0, max(0.0, end - time.monotonic())))
            if unmixer.error is not None:  # the callback keeps its error: picamera2's thread must not raise
                raise unmixer.error
            if times:
                recent = sorted(times[-30:])
                print(f"unmixing: {1e3 * recent[len(recent) // 2]:.1f} ms a frame (median of the last {len(recent)})")
    except KeyboardInterrupt:
        pass
    finally:
        picam2.stop()
        picam2.close()


if __name__ == "__main__":
    main()
