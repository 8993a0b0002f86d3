"""Sample-world benchmark: time to generate a dataset, process pool against one process.

Run ``python bench/world.py`` (``--quick`` for 3 small scenes). Prints:

1. the time to make a ``--scenes``-scene dataset (default 10 scenes, 640x480, 25 frames per
   room, MCAP) with ``--workers`` processes (default 2; target under 5 minutes on 2 cores);
2. where one scene's time goes (generate, plan, render, write), measured in this process;
3. the naive way, one process making the scenes one after another, timed on
   ``--naive-scenes`` scenes (default 2) and extrapolated, and the speed-up ratio.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.docs_section import add_docs_flag, recorded
from care_maps.ingest.write import write_recording
from care_maps.truth.formats.native import write_native
from care_maps.world.record import DatasetConfig, make_dataset, scene_config_of
from care_maps.world.render import RenderConfig, Renderer
from care_maps.world.scene import generate_scene
from care_maps.world.trajectory import plan_trajectory


def _dataset(out: Path, scenes: int, workers: int, width: int, height: int) -> float:
    t0 = time.perf_counter()
    make_dataset(
        DatasetConfig(
            out=out, scenes=scenes, width=width, height=height, workers=workers, progress=False
        )
    )
    return time.perf_counter() - t0


def _breakdown(config: DatasetConfig, tmp: Path) -> dict[str, float]:
    times: dict[str, float] = {}
    t = time.perf_counter()
    scene = generate_scene(scene_config_of(config, 0))
    times["generate"] = time.perf_counter() - t
    t = time.perf_counter()
    poses = plan_trajectory(scene)
    times["plan"] = time.perf_counter() - t
    t = time.perf_counter()
    frames = list(
        Renderer(scene, RenderConfig(width=config.width, height=config.height)).render_all(poses)
    )
    times[f"render ({len(frames)} frames)"] = time.perf_counter() - t
    t = time.perf_counter()
    write_recording(tmp / "one.mcap", frames, fmt="mcap", label_names=scene.class_names)
    times["write mcap"] = time.perf_counter() - t
    t = time.perf_counter()
    write_native(scene.ground_truth(), tmp / "one.mcap")
    times["ground truth"] = time.perf_counter() - t
    return times


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--naive-scenes", type=int, default=2)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--quick", action="store_true", help="3 scenes of 320x240")
    add_docs_flag(parser)
    args = parser.parse_args()
    with recorded("world", write=not (args.no_docs or args.quick)):
        if args.quick:
            args.scenes, args.width, args.height, args.naive_scenes = 3, 320, 240, 1
        tmp = Path(tempfile.mkdtemp(prefix="care-bench-world-"))
        try:
            pooled = _dataset(tmp / "pool", args.scenes, args.workers, args.width, args.height)
            print(
                f"dataset of {args.scenes} scenes at {args.width}x{args.height}, {args.workers} workers: "
                f"{pooled:.1f} s ({pooled / args.scenes:.1f} s/scene; target < 300 s for 10 scenes)"
            )
            config = DatasetConfig(out=tmp, width=args.width, height=args.height)
            print("one scene, by step:")
            for step, secs in _breakdown(config, tmp).items():
                print(f"  {step:<24} {secs:6.2f} s")
            naive = _dataset(tmp / "naive", args.naive_scenes, 1, args.width, args.height)
            per_scene = naive / args.naive_scenes
            print(
                f"naive (one process, {args.naive_scenes} scenes): {per_scene:.1f} s/scene -> "
                f"{per_scene * args.scenes:.1f} s for {args.scenes} scenes; "
                f"pool speed-up x{per_scene * args.scenes / pooled:.2f}"
            )
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
