"""The virtual camera's frame rate and CPU cost: does a picamera2 script run about as fast here as on a Raspberry Pi?

Usage: python3 benchmarks/bench_virtualcam.py [--seconds 8] [--repeats 3] [--platform pisp]

Two picamera2 scripts, unchanged from what runs on a Pi, each under ``picamcal virtual-camera`` with the HQ camera
(IMX477, full size) in a process of its own:

- **preview**: a 1332x990 XBGR8888 main stream with its raw stream (picamera2 picks the 2028x1520 binned mode, 40
  frames/s at most), and picamcal's live unmixing (:class:`picamcal.live.LiveUnmixer`) in its ``pre_callback``;
  goals: at least 30 frames/s, and at most 40 ms of CPU a frame (so that a 2-core machine slower than this one
  still keeps 30 frames/s);
- **stills**: full-resolution 12-megapixel stills (``create_still_configuration()``, 4056x3040, 10 frames/s at
  most) captured back to back; goal: at least 5 frames/s.

Each counts the distinct frames (``SensorTimestamp``) that reach the script in ``--seconds`` after a warm-up, and
the CPU time the whole process spent meanwhile (``time.process_time``: every thread of the process). The baseline,
measured in the same run: the sensor mode's own frame rate (the virtual sensor's frame clock, which the frames cannot
beat), so the ratio is the fraction of the camera's frames the script gets. "cpu ms a frame" is the process's CPU
time per frame that reached the script (the goal's measure), and ``1000 / cpu ms x cores`` bounds the frame rate;
"a frame made" is per frame the camera completed (picamera2's count: every frame the ``pre_callback`` saw; a frame
the script asks for too late is made, and costs, but does not reach it). Each script runs ``--repeats`` times, each
in a fresh process, and is judged on the median run: on a shared machine one run can fall on a slow spell.

The breakdown: the virtual camera's timings (:mod:`picamcal.virtualcam.timing`, switched on here by
``PICAMCAL_VIRTUAL_CAMERA_TIMING=1``) give each stage's CPU time, in whichever threads did its work, per frame made:
the sensor's readout with noise, the statistics the IPA takes, the raw stream's encoding (PiSP compression or CSI-2
packing), the ISP's render of the processed streams, the rest of each stage (controls, IPA, metadata, completion)
and, in the preview, the live unmixing in picamera2's thread; what is left of the process's CPU time is picamera2's
and the script's own. Medians of the runs.
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
from typing import Any

SRC = Path(__file__).resolve().parents[1] / "src"

#: What each script does; both print one JSON line.
MEASURE = """
import json, sys, time
from picamera2 import Picamera2
from picamcal.virtualcam import timing

def measure(picam2, seconds, capture):
    for _ in range(5):
        capture()
    timing.TIMINGS.reset()
    made = picam2.frames
    stamps, start, cpu = [], time.perf_counter(), time.process_time()
    while time.perf_counter() - start < seconds:
        stamps.append(capture())
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    stages = timing.TIMINGS.snapshot()
    frames, made = len(set(stamps)), max(picam2.frames - made, 1)
    limit = picam2.camera_controls["FrameDurationLimits"][0]
    print(json.dumps({"fps": frames / wall, "cpu_ms": 1e3 * cpu / max(frames, 1), "cpu_ms_made": 1e3 * cpu / made,
                      "made": made, "mode_fps": 1e6 / limit,
                      "stages": {name: 1e3 * seconds / made for name, (seconds, _) in stages.items()},
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


def unmix(request):
    with timing.stage(UNMIXING):
        unmixer.callback(request)


picam2.pre_callback = unmix
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

#: The preview's stage of live unmixing, timed in the script (picamera2's thread).
UNMIXING = "live unmixing (pre_callback)"
#: The stages in the order a frame goes through them (``picamcal.virtualcam.camera``), then the unmixing.
STAGES = (
    "readout",
    "statistics",
    "raw stream",
    "sensor stage: controls, IPA, metadata",
    "ISP render",
    "ISP stage: completion",
    UNMIXING,
)
GOALS = {"preview": 30.0, "stills": 5.0}
#: At most this much CPU a frame (ms, all threads): the preview keeps 30 frames/s on a 2-core machine slower than this.
CPU_GOALS = {"preview": 40.0}


def run(script: str, seconds: float, platform: str) -> dict[str, Any]:
    """One script under ``picamcal virtual-camera`` (IMX477, full size), with the timings on; its JSON line."""
    env = dict(os.environ, LIBCAMERA_LOG_LEVELS="*:WARN", PICAMCAL_VIRTUAL_CAMERA_TIMING="1")
    env["PYTHONPATH"] = os.pathsep.join([str(SRC), *filter(None, [os.environ.get("PYTHONPATH")])])
    command = [sys.executable, "-m", "picamcal", "virtual-camera", f"--platform={platform}", "--sensor=imx477", "--"]
    code = textwrap.dedent(MEASURE) + f"UNMIXING = {UNMIXING!r}\n" + textwrap.dedent(script)
    done = subprocess.run(
        [*command, sys.executable, "-c", code, str(seconds)], capture_output=True, text=True, env=env, timeout=900
    )
    if done.returncode != 0:
        raise SystemExit(f"the {platform} script failed:\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def breakdown(runs: list[dict[str, Any]]) -> None:
    """Where a frame's CPU time goes: each stage's median ms per frame made, and its share."""
    total = statistics.median(got["cpu_ms_made"] for got in runs)
    names = [name for name in STAGES if any(name in got["stages"] for got in runs)]
    names += sorted({name for got in runs for name in got["stages"]} - set(names))
    rest = statistics.median(got["cpu_ms_made"] - sum(got["stages"].values()) for got in runs)
    print(f"    {'CPU a frame made, by stage (median of the runs)':52}  {'ms':>6}  {'share':>6}")
    for name in names:
        ms = statistics.median(got["stages"].get(name, 0.0) for got in runs)
        print(f"    {name:52}  {ms:6.1f}  {ms / total:6.0%}")
    print(f"    {'the rest: picamera2, the script, Python':52}  {rest:6.1f}  {rest / total:6.0%}")
    print(f"    {'the process, all threads':52}  {total:6.1f}  {1:6.0%}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0, help="how long each script counts frames")
    parser.add_argument("--platform", choices=("pisp", "vc4"), default="pisp", help="the Raspberry Pi emulated")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each script; judged on the median")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    print(f"The virtual camera (IMX477, {args.platform}), {os.cpu_count()} CPUs, {args.seconds:g} s each")
    print(
        f"{'':40}  {'frames/s':>8}  {'mode fps':>8}  {'ratio':>6}  {'cpu ms a frame':>14}  {'a frame made':>12}  goal"
    )
    missed = []
    for name, script, label in (
        ("preview", PREVIEW, "preview 1332x990 + raw, live unmixing"),
        ("stills", STILLS, "stills 4056x3040 (12 MP)"),
    ):
        runs = [run(script, args.seconds, args.platform) for _ in range(args.repeats)]
        for i, got in enumerate(runs, 1):
            print(
                f"{label if i == 1 else '':40}  {got['fps']:8.1f}  {got['mode_fps']:8.1f}  "
                f"{got['fps'] / got['mode_fps']:6.2f}  {got['cpu_ms']:14.1f}  {got['cpu_ms_made']:12.1f}  run {i}"
            )
        fps = statistics.median(got["fps"] for got in runs)
        cpu = statistics.median(got["cpu_ms"] for got in runs)
        made = statistics.median(got["cpu_ms_made"] for got in runs)
        goal = GOALS[name]
        verdicts = ["met" if fps >= goal else f"MISSED by {goal - fps:.1f} frames/s"]
        if fps < goal:
            missed.append(f"{name} frames/s")
        goals = f">= {goal:g} frames/s"
        if name in CPU_GOALS:
            goals += f", <= {CPU_GOALS[name]:g} cpu ms"
            over = cpu - CPU_GOALS[name]
            verdicts.append("met" if over <= 0 else f"MISSED by {over:.1f} ms")
            if over > 0:
                missed.append(f"{name} cpu ms")
        median = f"  median of {len(runs)}"
        print(f"{median:40}  {fps:8.1f}  {'':8}  {'':6}  {cpu:14.1f}  {made:12.1f}  {goals}: {', '.join(verdicts)}")
        breakdown(runs)
    print("goal: " + ("met" if not missed else f"MISSED ({', '.join(missed)})"))


if __name__ == "__main__":
    main()
