"""Regenerate every number and figure of docs/results.md, from scratch.

1. Two Matterport-like datasets (``care sample make --preset matterport-like``) on seeds
   20 and 77, with the generator's statistics and measured first attempts.
2. The full evaluation of each (every strategy, criterion and k, both protocols), with
   the pre-registered tables (``evaluate.report.preregistered``) in ``results.md``.
3. The sweep of perception settings (``research.sweep``) on a third, smaller dataset.
4. ``OUT/results_section.md``: the tables docs/results.md shows, and ``OUT/sweep.png``
   (copy it to ``docs/sweep.png``).

Every step skips what is already done, so an interrupted run resumes. Run it with
``nice``: about 45 minutes on two busy cores with the default sizes.

    python -m research.reproduce OUT [--scenes 4] [--sweep-scenes 2] [--seeds 20 77]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq

from evaluate.job import EvalConfig, Scene, run_eval
from evaluate.report.preregistered import TABLE_NAMES, preregistered_markdown
from research.dataset_stats import MEASURE_DIR
from research.sweep import SweepConfig, run_sweep
from runtime.execution import Execution
from truth.dataset_index import read_index

SIZE = ["--width", "320", "--height", "240", "--jpeg"]


def make(out: Path, scenes: int, seed: int, measure: bool) -> dict:
    """``care sample make --preset matterport-like`` (resumes); returns its index.json."""
    cmd = [sys.executable, "-m", "care_cli.main", "sample", "make", "--out", str(out)]
    cmd += ["--scenes", str(scenes), "--seed", str(seed), "--preset", "matterport-like"]
    cmd += [*SIZE, "--workers", "1", *(["--measure"] if measure else [])]
    subprocess.run(cmd, check=True)
    return json.loads((out / "index.json").read_text())


def evaluate(dataset: Path) -> Path:
    """The full evaluation of a measured dataset's stores into ``dataset/eval``."""
    out = dataset / "eval"
    if not (out / "results.md").is_file():
        scenes = [
            Scene(e.name, dataset / MEASURE_DIR / "stores" / e.name, e.recording.resolve())
            for e in read_index(dataset)
        ]
        run_eval(scenes, EvalConfig(), out, run=Execution(workers=1))
    return out


def section(datasets: dict[int, Path], sweep_png: Path) -> str:
    """The tables of docs/results.md: generator statistics, then per seed the pre-registered tables."""
    lines = [
        "| seed | scenes | rooms | instances (per room) | classes | first attempt: instances (`instance`) | instances (`class`) | grid |"
    ]
    lines.append("|---|---:|---:|---|---:|---:|---:|---:|")
    for seed, ds in datasets.items():
        st = json.loads((ds / "index.json").read_text())["statistics"]
        fa = st.get("first_attempt", {})
        per = st["instances_per_room"]
        lines.append(
            f"| {seed} | {st['scenes']} | {st['rooms']} | {st['instances']} ({per['mean']}, "
            f"{per['min']}-{per['max']}) | {st['classes']} | {fa.get('instances/instance', float('nan')):.1f} "
            f"| {fa.get('instances/class', float('nan')):.1f} | {fa.get('grid', float('nan')):.1f} |"
        )
    out = ["\n".join(lines), ""]
    for seed, ds in datasets.items():
        ev = ds / "eval"
        tables = [pq.read_table(ev / f"{n}.parquet") for n in TABLE_NAMES]
        out += [
            f"### Seed {seed}\n",
            preregistered_markdown(*tables).replace("## Pre-registered", "#### Pre-registered"),
        ]
    out.append(f"![When CARe helps]({sweep_png})\n")
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--scenes", type=int, default=4)
    parser.add_argument("--sweep-scenes", type=int, default=2)
    parser.add_argument("--seeds", type=int, nargs="+", default=[20, 77])
    parser.add_argument("--no-sweep", action="store_true")
    args = parser.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    datasets = {}
    for seed in args.seeds:
        ds = out / f"matterport-like-{seed}"
        make(ds, args.scenes, seed, measure=True)
        evaluate(ds)
        datasets[seed] = ds
    png = out / "sweep.png"
    if not args.no_sweep:
        sweep_ds = out / "sweep-dataset"
        make(sweep_ds, args.sweep_scenes, 5, measure=False)
        run_sweep(sweep_ds, out / "sweep", SweepConfig())
        shutil.copyfile(out / "sweep" / "sweep.png", png)
    text = section(datasets, Path("docs/sweep.png"))
    (out / "results_section.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
