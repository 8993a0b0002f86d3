"""What the geometric consistency check of every ingest costs, beside the ingest it guards.

Two recordings, each ingested without an encoder (the store's own work: decoding, the check,
encoding the store), best of ``--repeat`` runs:

- the bundled sample recording (80 views, the sample world);
- the third-party living-room frames (211 views, ICL-NUIM through Open3D's Redwood folder),
  read in place as a dataset folder.

Side by side in the same run, on the same decoded views:

- the check as ingest runs it (:class:`care_maps.ingest.consistency.GeometrySampler` keeps runs of
  views, :func:`care_maps.geometry.consistency.judge` scores the reading as given and every usual
  mistake on subsampled depth);
- the naive way: every consecutive pair of views, full-resolution depth, the reading as
  given only (no diagnosis).

Run: ``python bench/consistency.py`` (``--repeat 1`` for a quick look).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.docs_section import add_docs_flag, recorded  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "care_maps" / "data" / "sample" / "scene_000.mcap"
LIVING_ROOM = ROOT.parent / "shared" / "data" / "rgbd" / "livingroom1_clean_micro"
REPEAT = 3


def _best(repeat: int, work) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        work()
        times.append(time.perf_counter() - t)
    return min(times)


def _row(name: str, source: Path, repeat: int) -> None:
    from care_maps.geometry.consistency import DepthSample, Hypothesis, agreement, judge
    from care_maps.ingest.consistency import GeometrySampler, source_reading
    from care_maps.ingest.folders.frames import open_frames
    from care_maps.ingest.pipeline import IngestConfig, run_ingest
    from care_maps.ingest.source import ReadOptions
    from care_maps.runtime.execution import Execution

    quiet = Execution(progress=False, overwrite=True)
    with tempfile.TemporaryDirectory() as tmp:
        ingest_s = _best(
            repeat, lambda: run_ingest(source, Path(tmp) / "store", IngestConfig(), run=quiet)
        )
    with open_frames(source, ReadOptions()) as frames:
        views = list(frames)
        reading = source_reading(source, frames, ReadOptions())

    def check() -> None:
        sampler = GeometrySampler()
        for frame in views:
            sampler.add(frame)
        judge(
            [s for run in sampler.samples() for s in run],
            reading.mistakes(),
            runs=[len(r) for r in sampler.samples()],
        )

    def naive() -> None:
        full = [DepthSample(f.depth_m, f.K, f.cam_to_world) for f in views]
        agreement(full, [(i, i + 1) for i in range(len(full) - 1)], Hypothesis("as given"))

    check_s = _best(repeat, check)
    naive_s = _best(repeat, naive)
    print(
        f"| {name} | {len(views)} | {ingest_s:.2f} | {check_s:.2f} | {check_s / ingest_s:.0%} "
        f"| {naive_s:.2f} | x{naive_s / check_s:.1f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=REPEAT)
    add_docs_flag(parser)
    args = parser.parse_args()
    from care_maps.runtime.threads import Work, threads_for

    with (
        recorded("consistency", write=not args.no_docs and args.repeat >= REPEAT),
        threads_for(Work.DEFAULT),
    ):
        print(f"geometric consistency check against ingest (no encoder), best of {args.repeat}")
        print(
            "| recording | views | ingest s (check included) | check s | share of ingest | naive check s (all consecutive pairs, full resolution, no diagnosis) | check faster |"
        )
        print("| --- | --- | --- | --- | --- | --- | --- |")
        _row("sample scene_000.mcap", SAMPLE, args.repeat)
        _row("living room (Redwood folder)", LIVING_ROOM, args.repeat)


if __name__ == "__main__":
    main()
