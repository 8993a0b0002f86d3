"""Start-up of the ``care`` program: how much a command pays before its own work.

Each row runs in fresh processes, best of ``--repeat``, side by side with the floor any
Python tool on this stack pays, ``python -c "import numpy, pyarrow"``:

- ``care --help``: the program and its commands registered, no stage imported;
- ``care query STORE chair --map grid`` on a built grid (the sample, every 5th frame,
  ``--encoder labels``): the answer a robot's planner asks for. Its own work (the map's
  columns read, the ranking, the goal and path) is measured apart, as a second call in a
  process that has imported everything already; what is left is start-up.

The target (``docs/architecture.md``, Import cost): each command starts within 2x of the
floor plus its own work.

Run: ``python bench/startup.py`` (``--repeat 1`` for a quick look).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.cold_query import _best as best_run  # noqa: E402
from bench.docs_section import add_docs_flag, recorded  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "care_maps" / "data" / "sample" / "scene_000.mcap"
REPEAT = 5
TARGET = 2.0
"""A command's start-up may be at most this many times the floor's."""

_OWN_WORK = """
import contextlib, io, sys, time
from care_maps.cli import main as cli
cli._register()
args = sys.argv[1:]
def once():
    with contextlib.redirect_stdout(io.StringIO()):
        try:
            cli.build_command()(args, standalone_mode=False)  # as `care` parses them
        except SystemExit:
            pass
once()  # the imports and the kernels' loading: start-up, not work
start = time.perf_counter()
once()
print(time.perf_counter() - start)
"""


def _best(argv: list[str], repeat: int) -> float:
    """Best wall time (s) of ``argv`` in a fresh process, ``repeat`` times (the cold-query
    bench's measure, its peak memory left aside)."""
    return best_run(argv, repeat)[0]


def _own_work(args: list[str], repeat: int) -> float:
    """Best time (s) of the command's second call in one process: its work alone."""
    runs = [
        float(
            subprocess.run(
                [sys.executable, "-c", _OWN_WORK, *args], check=True, capture_output=True, text=True
            ).stdout.split()[-1]
        )
        for _ in range(repeat)
    ]
    return min(runs)


def _store(workdir: Path) -> Path:
    store = workdir / "store"
    care = [sys.executable, "-m", "care_maps.cli.main"]
    subprocess.run(
        [*care, "ingest", SAMPLE, "--out", store, "--encoder", "labels", "--every", "5"],
        check=True, capture_output=True,
    )  # fmt: skip
    subprocess.run([*care, "fuse", "grid", store], check=True, capture_output=True)
    return store


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/care-bench-startup"))
    parser.add_argument("--repeat", type=int, default=REPEAT)
    add_docs_flag(parser)
    args = parser.parse_args()
    args.workdir.mkdir(parents=True, exist_ok=True)
    store = _store(args.workdir)
    care = [sys.executable, "-m", "care_maps.cli.main"]
    query = ["query", str(store), "chair", "--map", "grid"]
    with recorded("startup", write=not args.no_docs and args.repeat >= REPEAT):
        floor = _best([sys.executable, "-c", "import numpy, pyarrow"], args.repeat)
        print(f"fresh processes, best of {args.repeat}; the floor: "
              f"`python -c \"import numpy, pyarrow\"` {floor:.2f} s")  # fmt: skip
        print("| command | seconds | its own work | start-up | start-up / floor | target |")
        print("| --- | --- | --- | --- | --- | --- |")
        rows = [
            ("care --help", ["--help"], 0.0),
            ("care query STORE chair --map grid", query, None),
        ]
        for name, argv, work in rows:
            total = _best([*care, *argv], args.repeat)
            if work is None:
                work = _own_work(argv, args.repeat)
            start = max(total - work, 0.0)
            ok = "met" if start <= TARGET * floor else "not met"
            print(f"| `{name}` | {total:.2f} | {work:.2f} | {start:.2f} | "
                  f"x{start / floor:.2f} | x{TARGET:.0f}: {ok} |")  # fmt: skip


if __name__ == "__main__":
    main()
