"""The accuracy of each workflow on the spectral simulator: the table of docs/accuracy.md, and the rows the report
compares test images with (src/picamcal/data/accuracy.json).

Usage: python3 benchmarks/accuracy.py [--size 1280x960] [--json src/picamcal/data/accuracy.json]

Each workflow calibrates as a user would, photographs the colour-wheel target and scores the corner wheels
against the centre wheel (CIEDE2000), in every mode and for the floor (the best any per-bin 3 x 3 can do):
picamcal.simulate.spectral_accuracy. About 30 s at 1280x960.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

from picamcal._atomic import atomic_path
from picamcal.simulate.spectral_accuracy import accuracy_table, format_accuracy_table


def _rounded(value: Any) -> Any:
    """Figures to 3 decimals: CIEDE2000 differences below 0.001 mean nothing."""
    if isinstance(value, float):
        return round(value, 3)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensor", default="imx219")
    parser.add_argument("--size", default="1280x960", help="WIDTHxHEIGHT of the simulated frames")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-noise", action="store_true", help="noiseless frames (the model's error alone)")
    parser.add_argument("--json", help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    options = {"sensor": args.sensor, "size": (width, height), "noise": not args.no_noise, "seed": args.seed}
    rows = _rounded(accuracy_table(**options))  # the table shows what the file holds
    print(format_accuracy_table(rows))
    if args.json:
        record = {"conditions": {**options, "size": [width, height]}, "workflows": rows}
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
