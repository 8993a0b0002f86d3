"""Ingest throughput and peak memory on the 211-frame living-room recording.

Each case runs in its own subprocess so its peak resident memory (``bench.rss``) is its own.
Cases, from raw ``rgb8`` and from JPEG messages: the recording's messages read alone (the
floor), streamed ingest without encoder into today's store (``png-lists``, the 0.1 encoding)
and into the default (``raw-zstd``, :mod:`care_maps.core.codecs`) side by side with the store's size
a view; the JPEG recording repeated 5 times (peak memory must not grow with length); the
naive way (every message of the bag read into memory first) for the ratio; and the ``labels``
encoder.

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
from care_maps.runtime.malloc import keep_freed_memory
keep_freed_memory()  # as the care program does
import numpy as np
from care_maps.core.codecs import StoreEncoding
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.readers import open_reader
from care_maps.ingest.select import FrameSelection
from care_maps.runtime.execution import Execution
# program start, untimed (as in bench/fuse.py): the modules ingest loads at its first frame
# (readers, codecs, Pillow's plugins), by ingesting the recording's first 0.2 s elsewhere
warm = IngestConfig(select=FrameSelection(end=0.2))
run_ingest(Path(case["rec"]), Path(case["out"] + "-warm"), warm,
           run=Execution(overwrite=True, progress=False))
base = current_rss_mb()
t0 = time.perf_counter()
size = 0.0
if case["way"] == "small":  # ingest's first pass: poses and camera info before any frame
    with open_reader(Path(case["rec"])) as r:
        small = ("/tf", "/tf_static", "/camera/color/camera_info")
        frames = sum(1 for m in r.messages(small) if m[0] == "/tf")  # one a frame
elif case["way"] in ("naive", "read"):
    with open_reader(Path(case["rec"])) as r:
        messages = r.messages()
        held = list(messages) if case["way"] == "naive" else None
        colour = ("/camera/color/image_raw", "/camera/color/image_raw/compressed")
        frames = sum(1 for m in (held if held is not None else messages) if m[0] in colour)
else:
    run = Execution(overwrite=True, progress=False)
    config = IngestConfig(encoder=case["encoder"], store_encoding=StoreEncoding(case["way"]))
    store = run_ingest(Path(case["rec"]), Path(case["out"]), config, run=run)
    frames = json.loads((store / "meta.json").read_text())["num_views"]
    size = sum(p.stat().st_size for p in store.glob("*.parquet")) / frames / 1e3
dt = time.perf_counter() - t0
print(json.dumps({"frames": frames, "seconds": dt, "base_mb": base, "peak_mb": peak_rss_mb(),
                  "kb_per_view": size}))
"""


LABEL_NAMES = ("void", "floor", "sofa", "wall")
"""Stand-in classes for the labels encoder: the living room has no semantic labels, so the
labelled recording gives each pixel a class by depth band (near, middle, far); what is timed
is the encoder's work per pixel, which does not depend on what the labels mean."""


def _frames(count: int, repeat: int = 1, labelled: bool = False):
    """Living-room frames, streamed from disk (repeats continue the clock)."""
    import numpy as np
    from PIL import Image

    from care_maps.core.frames import Frame

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

    return importlib.util.find_spec("care_maps.world.perception.encoder") is not None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=211)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--workdir", type=Path, default=None)
    add_docs_flag(parser)
    args = parser.parse_args()
    with recorded("ingest", write=not args.no_docs):
        sys.path.insert(0, str(ROOT))
        from care_maps.core.codecs import StoreEncoding
        from care_maps.ingest.write import write_recording

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

        today, default = StoreEncoding.PNG_LISTS.value, StoreEncoding.RAW_ZSTD.value
        cases = {
            "raw: messages read alone (the floor)": (raw, None, "read"),
            "raw: poses and camera info alone (ingest's first pass)": (raw, None, "small"),
            "raw: today's store (png-lists)": (raw, None, today),
            "raw: default store (raw-zstd)": (raw, None, default),
            "jpeg: messages read alone (the floor)": (jpeg1, None, "read"),
            "jpeg: poses and camera info alone (ingest's first pass)": (jpeg1, None, "small"),
            "jpeg: today's store (png-lists)": (jpeg1, None, today),
            "jpeg: default store (raw-zstd, the recording's JPEG kept)": (jpeg1, None, default),
            f"jpeg x{args.repeat}: default store": (jpegn, None, default),
            "raw: naive, every message in memory first": (raw, None, "naive"),
            "raw, labels encoder: default store": (labelled, "labels", default),
        }
        results = {}
        for name, (rec, encoder, way) in cases.items():
            if encoder == "labels" and not _labels_available():
                continue
            case = {"rec": str(rec), "out": str(work / "store"), "encoder": encoder, "way": way}
            results[name] = _run(case)
        _report(results, args.repeat, {p.name: p.stat().st_size / 2**20 for p in (raw, jpeg1)})


def _report(results: dict[str, dict], repeat: int, mib: dict[str, float]) -> None:
    """The cases as a table, then the targets against the figures they are read from."""
    print(f"recordings: raw {mib['living_raw.mcap']:.0f} MiB, jpeg {mib['living_x1.mcap']:.0f} MiB")
    print("| case | frames | frames/s | store KB a view | memory above baseline (MB) |")
    print("| --- | ---: | ---: | ---: | ---: |")
    rate, size, grow = {}, {}, {}
    for name, res in results.items():
        if "error" in res:
            print(f"| {name} | {res['error']} | | | |")
            continue
        rate[name] = res["frames"] / res["seconds"]
        size[name] = res["kb_per_view"]
        grow[name] = res["peak_mb"] - res["base_mb"]
        kb = f"{size[name]:.0f}" if size[name] else ""
        print(f"| {name} | {res['frames']} | {rate[name]:.1f} | {kb} | {grow[name]:.0f} |")
    print()
    print("| target | measured | met |")
    print("| --- | --- | --- |")

    def line(target: str, measured: str, met: bool) -> None:
        print(f"| {target} | {measured} | {'yes' if met else '**no**'} |")

    for src in ("raw", "jpeg"):
        new = next((n for n in rate if n.startswith(f"{src}: default")), None)
        old = next((n for n in rate if n.startswith(f"{src}: today")), None)
        if new is None or old is None:
            continue
        line(
            f"{src}: >= 100 frames/s without an encoder",
            f"{rate[new]:.1f} (today's store {rate[old]:.1f}: x{rate[new] / rate[old]:.2f})",
            rate[new] >= 100,
        )
        ratio = size[new] / size[old]
        line(
            f"{src}: store size a view within 1.5x of today's",
            f"{size[new]:.0f} KB against {size[old]:.0f} KB (x{ratio:.2f})",
            ratio <= 1.5,
        )
    one = "jpeg: default store (raw-zstd, the recording's JPEG kept)"
    many = f"jpeg x{repeat}: default store"
    if one in grow and many in grow:
        # what one more frame adds to the peak, against what a decoded 640x480 frame holds
        # (uint8 colour and float32 depth): bounded if a small, fixed share of it
        extra = (grow[many] - grow[one]) * 1e3 / (results[many]["frames"] - results[one]["frames"])
        frame_kb = 640 * 480 * (3 + 4) / 1e3
        line(
            "memory bounded, not growing with the recording's length (< 5% of a frame a frame)",
            f"x{repeat} frames: {grow[many]:.0f} MB against {grow[one]:.0f} MB, {extra:.0f} KB "
            f"a further frame ({extra / frame_kb:.1%} of a decoded frame's {frame_kb:.0f} KB)",
            extra < 0.05 * frame_kb,
        )
    naive = "raw: naive, every message in memory first"
    streamed = "raw: default store (raw-zstd)"
    if naive in grow and streamed in grow:
        print(f"\nnaive / streamed memory above baseline: x{grow[naive] / grow[streamed]:.1f}")


if __name__ == "__main__":
    main()
