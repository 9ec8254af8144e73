"""The virtual camera's frame rate: does a picamera2 script run about as fast here as on a Raspberry Pi?

Usage: python3 benchmarks/bench_virtualcam.py [--seconds 8] [--repeats 3] [--platform pisp]

Two picamera2 scripts, unchanged from what runs on a Pi, each under ``picamcal virtual-camera`` with the HQ camera
(IMX477, full size) in a process of its own:

- **preview**: a 1332x990 XBGR8888 main stream with its raw stream (picamera2 picks the 2028x1520 binned mode, 40
  frames/s at most), and picamcal's live unmixing (:class:`picamcal.live.LiveUnmixer`) in its ``pre_callback``;
  goal: at least 30 frames/s;
- **stills**: full-resolution 12-megapixel stills (``create_still_configuration()``, 4056x3040, 10 frames/s at
  most) captured back to back; goal: at least 5 frames/s.

Each counts the distinct frames (``SensorTimestamp``) that reach the script in ``--seconds`` after a warm-up, and
the CPU time the whole process spent meanwhile. The baseline, measured in the same run: the sensor mode's own frame
rate (the virtual sensor's frame clock, which the frames cannot beat), so the ratio is the fraction of the camera's
frames the script gets. "cpu ms a frame" is the process's CPU time (all its threads) per frame, and
``1000 / cpu ms x cores`` bounds the frame rate. Each script runs ``--repeats`` times, each in a fresh process, and
is judged on the median run: on a shared machine one run can fall on a slow spell.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import textwrap
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

#: What each script does; both print one JSON line.
MEASURE = """
import json, sys, time
from picamera2 import Picamera2

def measure(picam2, seconds, capture):
    for _ in range(5):
        capture()
    stamps, start, cpu = [], time.perf_counter(), time.process_time()
    while time.perf_counter() - start < seconds:
        stamps.append(capture())
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    frames = len(set(stamps))
    limit = picam2.camera_controls["FrameDurationLimits"][0]
    print(json.dumps({"fps": frames / wall, "cpu_ms": 1e3 * cpu / max(frames, 1), "mode_fps": 1e6 / limit,
                      "mode": list(picam2.camera_configuration()["sensor"]["output_size"])}))
"""

PREVIEW = """
import picamcal
from picamcal.live import LiveUnmixer
from picamcal.simulate import make_camera, simulate_references

picam2 = Picamera2()
picam2.configure(picam2.create_preview_configuration(main={"size": (1332, 990)}, raw={"size": (1332, 990)}))
calibration = picamcal.calibrate(**simulate_references(make_camera("imx477", size=(1014, 760)), seed=1))
config = picam2.camera_config["main"]
unmixer = LiveUnmixer.prepare(calibration, config["size"], config["format"])
picam2.pre_callback = unmixer.callback
picam2.start()
measure(picam2, float(sys.argv[1]), lambda: picam2.capture_metadata()["SensorTimestamp"])
assert unmixer.error is None, unmixer.error
picam2.close()
"""

STILLS = """
picam2 = Picamera2()
picam2.configure(picam2.create_still_configuration())
picam2.start()


def capture():
    with picam2.captured_request() as request:
        request.make_array("main")
        return request.get_metadata()["SensorTimestamp"]


measure(picam2, float(sys.argv[1]), capture)
picam2.close()
"""

GOALS = {"preview": 30.0, "stills": 5.0}


def run(script: str, seconds: float, platform: str) -> dict[str, float]:
    """One script under ``picamcal virtual-camera`` (IMX477, full size); its JSON line."""
    env = dict(os.environ, LIBCAMERA_LOG_LEVELS="*:WARN")
    env["PYTHONPATH"] = os.pathsep.join([str(SRC), *filter(None, [os.environ.get("PYTHONPATH")])])
    command = [sys.executable, "-m", "picamcal", "virtual-camera", f"--platform={platform}", "--sensor=imx477", "--"]
    code = textwrap.dedent(MEASURE) + textwrap.dedent(script)
    done = subprocess.run(
        [*command, sys.executable, "-c", code, str(seconds)], capture_output=True, text=True, env=env, timeout=900
    )
    if done.returncode != 0:
        raise SystemExit(f"the {platform} script failed:\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0, help="how long each script counts frames")
    parser.add_argument("--platform", choices=("pisp", "vc4"), default="pisp", help="the Raspberry Pi emulated")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each script; judged on the median")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    print(f"The virtual camera (IMX477, {args.platform}), {os.cpu_count()} CPUs, {args.seconds:g} s each")
    print(f"{'':40}  {'frames/s':>8}  {'mode fps':>8}  {'ratio':>6}  {'cpu ms a frame':>14}  goal")
    missed = []
    for name, script, label in (
        ("preview", PREVIEW, "preview 1332x990 + raw, live unmixing"),
        ("stills", STILLS, "stills 4056x3040 (12 MP)"),
    ):
        runs = [run(script, args.seconds, args.platform) for _ in range(args.repeats)]
        for i, got in enumerate(runs, 1):
            print(
                f"{label if i == 1 else '':40}  {got['fps']:8.1f}  {got['mode_fps']:8.1f}  "
                f"{got['fps'] / got['mode_fps']:6.2f}  {got['cpu_ms']:14.1f}  run {i}"
            )
        fps = statistics.median(got["fps"] for got in runs)
        goal = GOALS[name]
        verdict = "met" if fps >= goal else f"MISSED by {goal - fps:.1f} frames/s"
        if fps < goal:
            missed.append(name)
        median = f"  median of {len(runs)}"
        print(f"{median:40}  {fps:8.1f}  {'':8}  {'':6}  {'':14}  >= {goal:g} frames/s: {verdict}")
    print("goal: " + ("met" if not missed else f"MISSED ({', '.join(missed)})"))


if __name__ == "__main__":
    main()
