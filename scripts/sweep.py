"""When CARe helps: the paired gain of each measure over a grid of perception settings.

Re-encodes a sample-world dataset under each setting of (bias rate, bias noise scale,
view-dependent bias, view noise), builds both maps, plays the paper's pre-registered rules
and max confidence, and writes ``OUT/sweep.parquet`` and ``OUT/sweep.png``
(:mod:`evaluate.sweep`). A re-run resumes: the stores of finished settings are kept.

    python scripts/sweep.py DATASET OUT [--design oat|grid] [--values bias_rate=0.1,0,0.3 ...]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from evaluate.sweep import SweepConfig, run_sweep, settings_of


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("dataset", type=Path, help="A `care sample make` dataset directory.")
    parser.add_argument("out", type=Path, help="Directory of the sweep's stores and results.")
    parser.add_argument("--design", choices=("oat", "grid"), default="oat")
    parser.add_argument("--values", nargs="*", default=[], help="KNOB=v1,v2,... (centre first)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--bootstrap", type=int, default=1000)
    args = parser.parse_args()
    try:
        values = settings_of(args.values)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    config = replace(
        SweepConfig(), design=args.design, workers=args.workers, bootstrap=args.bootstrap, **values
    )
    table = run_sweep(args.dataset, args.out, config)
    print(f"{table.num_rows} rows: {args.out / 'sweep.parquet'}, {args.out / 'sweep.png'}")


if __name__ == "__main__":
    main()
