"""Live preview with the colour unmixing applied, on a Raspberry Pi (picamera2).

Usage (on the Pi, with a calibration and the tuning file exported from it)::

    picamcal export-tuning cal.npz --target pisp --ccm --out tuning.json   # once (--target vc4 on a Pi 4)
    python3 examples/live_preview.py cal.npz tuning.json   # --size 1332x990 --format XBGR8888 --seconds 0 (forever)
    python3 examples/live_preview.py cal.npz tuning.json --no-preview --seconds 10   # no display: time 10 s of frames

It opens the camera with the exported tuning (adaptive contrast off, so that the tone curve is the file's), freezes
the white balance at the calibration's white (the gains ``picamcal acquire`` froze for the references), prepares a
:class:`picamcal.live.LiveUnmixer` for the preview stream and sets it as picamera2's ``pre_callback``: every frame
is unmixed in place before the preview shows it. docs/live.md says what to install. What does not fit (a tuning for
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


def run() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("calibration", help="calibration file (picamcal calibrate)")
    parser.add_argument("tuning", help="the tuning file exported from it (picamcal export-tuning)")
    parser.add_argument("--size", default="1332x990", help="preview stream size WIDTHxHEIGHT")
    parser.add_argument(
        "--format", default="XBGR8888", help="XBGR8888 or XRGB8888 (what the Qt preview shows), RGB888 or BGR888"
    )
    parser.add_argument("--mode", default="centre", choices=("centre", "pure"))
    parser.add_argument("--seconds", type=float, default=0, help="stop after this long (0: until Ctrl-C)")
    parser.add_argument("--no-preview", action="store_true", help="no window: time the frames only")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))

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
    config = picam2.create_preview_configuration(main={"size": (width, height), "format": args.format})
    picam2.configure(config)
    picam2.set_controls({"AwbEnable": False, "ColourGains": gains})
    if not args.no_preview:
        picam2.start_preview(Preview.QTGL)
    picam2.start()  # uncorrected for the second or so the preparation takes
    # The sensor area the stream shows, in full-sensor pixels, and the colour temperature libcamera picks its
    # tables and colour matrix at, as it reports them for this mode and these gains.
    metadata = picam2.capture_metadata()
    crop = tuple(int(v) for v in metadata["ScalerCrop"])
    unmixer = LiveUnmixer.prepare(
        calibration,
        picam2.camera_config["main"]["size"],
        picam2.camera_config["main"]["format"],
        tuning=tuning,
        mode=args.mode,
        crop=crop,
        ct=metadata.get("ColourTemperature"),
        colour_gains=gains,
    )
    unmixer.check_config(picam2.camera_config)  # a stream the ISP changed (size, format) fails here, not per frame

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
