"""Ingest throughput and peak memory on the 211-frame living-room recording.

Each case runs in its own subprocess so its peak resident memory (``bench.rss``) is its own.
Cases: streamed ingest without encoder and with the ``labels`` encoder; the same
recording repeated 5 times (peak memory must not grow with length); and the naive way
(every message of the bag read into memory first) for the ratio.

    python bench/ingest.py [--frames 211] [--repeat 5] [--workdir DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "rgbd" / "livingroom1_clean_micro"
sys.path.insert(0, str(ROOT))

from bench.docs_section import add_docs_flag, recorded  # noqa: E402

_CHILD = r"""
import json, sys, time
from pathlib import Path
from bench.rss import current_rss_mb, peak_rss_mb
case = json.loads(sys.argv[1])
from runtime.malloc import keep_freed_memory
keep_freed_memory()  # as the care program does
import numpy as np
from ingest.pipeline import IngestConfig, run_ingest
from ingest.readers import open_reader
from runtime.execution import Execution
base = current_rss_mb()
t0 = time.perf_counter()
if case["naive"]:
    with open_reader(Path(case["rec"])) as r:
        held = list(r.messages())
    frames = sum(1 for m in held if m[0] == "/camera/color/image_raw" or m[0].endswith("compressed"))
else:
    run = Execution(overwrite=True, progress=False)
    store = run_ingest(Path(case["rec"]), Path(case["out"]), IngestConfig(encoder=case["encoder"]), run=run)
    frames = json.loads((store / "meta.json").read_text())["num_views"]
dt = time.perf_counter() - t0
print(json.dumps({"frames": frames, "seconds": dt, "base_mb": base, "peak_mb": peak_rss_mb()}))
"""


LABEL_NAMES = ("void", "floor", "sofa", "wall")
"""Stand-in classes for the labels encoder: the living room has no semantic labels, so the
labelled recording gives each pixel a class by depth band (near, middle, far); what is timed
is the encoder's work per pixel, which does not depend on what the labels mean."""


def _frames(count: int, repeat: int = 1, labelled: bool = False):
    """Living-room frames, streamed from disk (repeats continue the clock)."""
    import numpy as np
    from PIL import Image

    from care.frames import Frame

    lines = (DATA / "trajectory.log").read_text().split("\n")
    K = (
        np.array(json.loads((DATA / "camera_intrinsic.json").read_text())["intrinsic_matrix"])
        .reshape(3, 3)
        .T
    )
    for r in range(repeat):
        for k in range(count):
            pose = np.array(
                [[float(x) for x in row.split()] for row in lines[5 * k + 1 : 5 * k + 5]]
            )
            rgb = np.asarray(Image.open(DATA / "image" / f"{k:05d}.jpg").convert("RGB"))
            depth = (
                np.asarray(Image.open(DATA / "depth" / f"{k:05d}.png")).astype(np.float32) / 1000
            )
            extras = {}
            if labelled:
                band = np.digitize(depth, [1e-6, 1.5, 3.0]).astype(np.uint16)  # 0 = no depth
                extras = {"class": band, "instance": band}
            yield Frame(10**9 + (r * count + k) * 33_333_333, rgb, depth, K, pose, extras)


def _run(case: dict) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, json.dumps(case)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def _labels_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("world.perception.encoder") is not None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=211)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--workdir", type=Path, default=None)
    add_docs_flag(parser)
    args = parser.parse_args()
    with recorded("ingest", write=not args.no_docs):
        sys.path.insert(0, str(ROOT))
        from ingest.write import write_recording

        work = Path(args.workdir or tempfile.mkdtemp(prefix="care-bench-"))
        work.mkdir(parents=True, exist_ok=True)
        t = time.perf_counter()
        raw = write_recording(work / "living_raw.mcap", _frames(args.frames), fmt="mcap")
        labelled = write_recording(
            work / "living_labelled.mcap",
            _frames(args.frames, labelled=True),
            fmt="mcap",
            label_names=LABEL_NAMES,
        )
        jpeg1 = write_recording(
            work / "living_x1.mcap", _frames(args.frames), fmt="mcap", compressed_rgb=True
        )
        jpegn = write_recording(
            work / f"living_x{args.repeat}.mcap",
            _frames(args.frames, args.repeat),
            fmt="mcap",
            compressed_rgb=True,
        )
        print(f"recordings written in {time.perf_counter() - t:.1f} s under {work}")

        cases = [
            ("streamed, no encoder (raw rgb8)", raw, None, False),
            ("streamed, labels encoder (raw rgb8, depth-band labels)", labelled, "labels", False),
            ("naive: all messages in RAM (raw rgb8)", raw, None, True),
            ("streamed, no encoder (jpeg) x1", jpeg1, None, False),
            (f"streamed, no encoder (jpeg) x{args.repeat}", jpegn, None, False),
        ]
        rows = []
        for name, rec, encoder, naive in cases:
            if encoder == "labels" and not _labels_available():
                rows.append((name, "world.perception.encoder not available yet"))
                continue
            res = _run(
                {"rec": str(rec), "out": str(work / "store"), "encoder": encoder, "naive": naive}
            )
            rows.append((name, res))

        size = {p: p.stat().st_size / 2**20 for p in (raw, jpeg1, jpegn)}
        print(
            f"recording sizes: raw {size[raw]:.0f} MiB, jpeg x1 {size[jpeg1]:.0f} MiB, jpeg x{args.repeat} {size[jpegn]:.0f} MiB"
        )
        print(
            f"{'case':<42} {'frames':>7} {'frames/s':>9} {'base MB':>8} {'peak MB':>8} {'peak-base':>9}"
        )
        peaks = {}
        for name, res in rows:
            if isinstance(res, str) or "error" in res:
                print(f"{name:<42} {res if isinstance(res, str) else res['error']}")
                continue
            grow = res["peak_mb"] - res["base_mb"]
            peaks[name] = grow
            print(
                f"{name:<42} {res['frames']:>7} {res['frames'] / res['seconds']:>9.1f} "
                f"{res['base_mb']:>8.0f} {res['peak_mb']:>8.0f} {grow:>9.0f}"
            )
        streamed, naive = peaks.get(cases[0][0]), peaks.get(cases[2][0])
        if streamed and naive:
            print(f"naive / streamed memory above baseline: {naive / streamed:.1f}x")
        x1, xn = peaks.get(cases[3][0]), peaks.get(cases[4][0])
        if x1 and xn:
            print(f"x{args.repeat} / x1 memory above baseline: {xn / x1:.2f} (bounded if about 1)")


if __name__ == "__main__":
    main()
