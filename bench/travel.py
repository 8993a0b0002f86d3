"""What travel adds to a dataset evaluation: ``care eval`` with the walks off, from the
recording's first pose, and from seeded free-space starts, side by side in one run.

The stores come from ``care run`` on a dataset (default: the bundled sample, one scene of
three rooms with a 21k-cell grid and 35 instances; ``--dataset DIR`` for another), made
once. Then the whole evaluation (every strategy, criterion, k and seed of the default
config, the report, its plots) runs into a fresh folder for each travel start, serially
(``--workers 1``, in this process), ``--repeat`` times each, interleaved so that a busy
moment of a shared machine falls on all three; the best time counts, wall and CPU (the CPU
time of a serial run is what the machine's other work disturbs least). Also counted: the scipy Dijkstra searches
the walks ran (each from a start or from a goal stood on: most sequences share their first
goals, so few are run) and how much of the time the attempts take against the report.

Run: ``python bench/travel.py`` (``--repeat 1`` for a quick look).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.docs_section import add_docs_flag, recorded  # noqa: E402

STARTS = ("off", "first_pose", "free_space")
"""The travel starts timed (:class:`care_maps.evaluate.config.TravelStart`), in the table's order."""


def _stores(dataset: Path | None, out: Path) -> list[Path]:
    """Fused stores of ``dataset`` (``care run`` with the walks off, in a fresh process)."""
    cmd = [sys.executable, "-m", "care_maps.cli.main", "run", "--out", str(out), "--workers", "1",
           "--travel-start", "off", "--seeds", "1"]  # fmt: skip
    if dataset is not None:
        cmd.insert(4, str(dataset))
    done = subprocess.run(cmd, check=False, cwd=ROOT, capture_output=True, text=True)
    if done.returncode:
        msg = f"{' '.join(cmd)} failed:\n{done.stderr[-2000:]}"
        raise RuntimeError(msg)
    return sorted(p.parent for p in (out / "stores").glob("*/meta.json"))


class _Searches:
    """Counts the sources of scipy's Dijkstra while it is installed."""

    def __init__(self) -> None:
        self.sources = 0

    def __enter__(self) -> _Searches:
        import numpy as np
        import scipy.sparse.csgraph as csgraph

        self._module, self._dijkstra = csgraph, csgraph.dijkstra

        def counted(graph, *args, indices=None, **kw):
            self.sources += 1 if indices is None else int(np.size(indices))
            return self._dijkstra(graph, *args, indices=indices, **kw)

        csgraph.dijkstra = counted
        return self

    def __exit__(self, *exc: object) -> None:
        self._module.dijkstra = self._dijkstra


def _evaluate(stores: list[Path], start: str, out: Path) -> tuple[float, float, float, int, int]:
    """Wall and CPU time of the whole evaluation, CPU time of its attempts alone, the
    searches run and the queries with travel. CPU time (this process; the run is serial) is
    the figure that a shared machine's other work disturbs least."""
    from care_maps.evaluate.config import EvalConfig
    from care_maps.evaluate.job import run_eval, scenes_of
    from care_maps.runtime.execution import Execution

    config = EvalConfig(travel_start=start)
    serial = Execution(workers=1, progress=False)
    with _Searches() as searches:
        t0, c0 = time.perf_counter(), time.process_time()
        report = run_eval(stores, config, out, run=serial)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    from care_maps.evaluate.job import evaluate_scene

    c0 = time.process_time()
    for scene in scenes_of(stores):
        evaluate_scene(scene, config)
    attempts = time.process_time() - c0
    summary = report.summary.to_pylist()
    walked = max((r.get("n_travel") or 0 for r in summary), default=0)
    return wall, cpu, attempts, searches.sources, walked


def run(args: argparse.Namespace) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        stores = _stores(args.dataset, tmp / "run")
        made = time.perf_counter() - t0
        times: dict[str, list[tuple[float, float, float]]] = {s: [] for s in STARTS}
        facts: dict[str, tuple[int, int]] = {}
        for i in range(args.repeat):
            for start in STARTS:
                *took, searches, walked = _evaluate(stores, start, tmp / f"e{i}{start}")
                times[start].append(tuple(took))
                facts[start] = (searches, walked)
    load = os.getloadavg()[0]
    print(
        f"{len(stores)} store(s) from `care run` ({made:.0f} s, not counted); the default "
        f"evaluation, serial, best of {args.repeat}; load average {load:.1f}\n"
    )
    print(
        "| travel start | evaluation wall s | evaluation CPU s | attempts CPU s | report CPU s "
        "| added (CPU) | searches | queries walked |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    base = min(c for _, c, _ in times["off"])
    for start in STARTS:
        wall, cpu, attempts = (min(t[i] for t in times[start]) for i in range(3))
        added = "" if start == "off" else f"{100 * (cpu - base) / base:+.0f}%"
        searches, walked = facts[start]
        print(
            f"| {start} | {wall:.1f} | {cpu:.1f} | {attempts:.1f} | {cpu - attempts:.1f} "
            f"| {added} | {searches} | {walked} |"
        )
    print(
        "\nCPU: this process's (the run is serial); attempts: every scene's attempt "
        "sequences again, alone (evaluate_scene); report: the rest (ground truth, tables, "
        "paired tests, plots); searches: scipy Dijkstra sources the whole evaluation ran"
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--dataset", type=Path, default=None, help="default: the bundled sample")
    parser.add_argument("--repeat", type=int, default=3)
    add_docs_flag(parser)
    args = parser.parse_args()
    with recorded("travel", write=not args.no_docs):
        run(args)


if __name__ == "__main__":
    main()
