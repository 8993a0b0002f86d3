"""What a user's own CLIP costs at ingest: `care ingest --encoder clip` against the bare
forward pass of the same model on the same inputs, side by side in one run.

The living-room recording (``../shared/data``, 640x480, JPEG colour as a robot records it,
written to MCAP; frames repeat, the clock going on, past its 211) is ingested with a CLIP of
ViT-B/32's architecture and random weights (:mod:`care_maps.core.encoders.random_clip`; no
download), each way in a fresh process with its own peak memory (``bench/rss.py``):

- ``care ingest REC --encoder clip --weights DIR --vocabulary scannet200``, the whole command
  (interpreter start, imports, model load, the vocabulary's text, reading, decoding, the
  geometry check, the store);
- the bare forward: the same model (``ClipEncoder.encode_prepared``: the vision tower up to
  the MaskCLIP value path and the projection) on the same views read back from the
  recording, resized and normalised beforehand and untimed, in batches of the same size with
  the same threads (``Work.ENCODE``: every core). Its views/s is the floor ingest is held to.

The cheaper way to run the same checkpoint, ``--precision bfloat16``
(:class:`care_maps.core.encoders.base.Precision`), is timed both ways too: its ``care ingest``
(against float32's floor) in the table above, and, on the sweep's views, its bare forward
and its crops (``encode_crops``: a quadrant or the centre of each view, what instance maps
with ``features=crops`` encode) against float32's in one process, with its fidelity: the
cosine of each cell's (crop's) feature with float32's, and the share of cells (crops) whose
best class of the vocabulary is float32's.

The crops of instance maps: ``care fuse instances --features crops`` on the 200-view store
as a whole command, against ``--features masked`` on it (the same map without a model: what
the crops add is the difference) and against the bare ``encode_crops`` of the very crops the
command encodes (recorded by a build of its own with a stand-in model, then timed in the same
calls on the same threads).

Also the bare forward's views/s by batch size (what the default batch is chosen from),
ViT-L/14 rows with ``--large`` (too slow for 2 cores at 200 views: ``--large-views``, default
8; its precision table too), a GPU row with ``--device cuda`` where torch sees one (else a
note), and ``--baseline DIR``: the same ``care ingest`` from another checkout of the project
(``git archive HEAD | tar -x -C DIR``), to measure a change against what it replaces in the
same run.

The random checkpoints' tokenizer makes each word of the bundled vocabularies' prompts one
token, as CLIP's does (:mod:`care_maps.core.encoders.random_clip`), so the vocabulary's text
costs what it costs a user's checkpoint.

    python bench/encode.py [--views 200] [--large] [--device cuda] [--baseline DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.docs_section import add_docs_flag, recorded  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "rgbd" / "livingroom1_clean_micro"
OFFLINE = {"HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
VOCABULARY = "scannet200"
SWEEP = (2, 4, 8, 16)
"""Batch sizes of the bare forward's sweep."""

_COMMAND = r"""
import json, resource, sys, time
t0 = time.perf_counter()
case = json.loads(sys.argv[1])
sys.argv = ["bench-care", *case["args"]]  # not "care": exits come back here
import care_maps
from care_maps.cli.main import main
try:
    main()
except SystemExit as done:
    if done.code:
        raise
seconds = time.perf_counter() - t0
from bench.rss import peak_rss_mb
use = resource.getrusage(resource.RUSAGE_SELF)
out = {"seconds": seconds, "cpu": use.ru_utime + use.ru_stime, "peak_mb": peak_rss_mb(),
       "package": care_maps.__file__}
if "out" in case:  # a store written: its views
    out["views"] = json.loads(open(case["out"] + "/meta.json").read())["num_views"]
print(json.dumps(out))
"""
"""A ``care`` command (``args``) in this fresh process: its seconds from program start, CPU
seconds and peak memory (and, given the store it writes, ``out``, its views)."""

_BARE = r"""
import json, resource, sys, time
from pathlib import Path
case = json.loads(sys.argv[1])
from care_maps.runtime.threads import Work, use_threads
threads = use_threads(Work.ENCODE)  # what ingest's forward pass runs under
import torch
from care_maps.core.encoders import EncoderOptions, make_encoder
from care_maps.ingest.folders.frames import open_frames
from care_maps.ingest.source import ReadOptions
from bench.rss import peak_rss_mb
options = EncoderOptions(weights=case["weights"], device=case["device"], batch_size=max(case["sizes"]))
encoder = make_encoder("clip", options)
cuda = encoder.device.type == "cuda"

def cpu():
    use = resource.getrusage(resource.RUSAGE_SELF)
    return use.ru_utime + use.ru_stime

def batches(size):  # the recording's first views, decoded as ingest decodes them
    batch, seen = [], 0
    with open_frames(Path(case["rec"]), ReadOptions()) as stream:
        for frame in stream:
            batch.append(frame)
            seen += 1
            if len(batch) == size or seen == case["views"]:
                yield batch
                batch = []
            if seen == case["views"]:
                return

encoder.encode_prepared(encoder.prepare_views(next(batches(1))))  # first call, untimed
rows = []
for size in case["sizes"]:
    seconds = cpu_s = 0.0
    views = 0
    for batch in batches(size):
        prepared = encoder.prepare_views(batch)  # untimed, as the decoding
        if cuda:
            torch.cuda.synchronize()
        t, c = time.perf_counter(), cpu()
        encoder.encode_prepared(prepared)  # to host memory, as ingest takes it
        seconds += time.perf_counter() - t
        cpu_s += cpu() - c
        views += len(batch)
    rows.append({"batch": size, "seconds": seconds, "cpu": cpu_s, "views": views})
print(json.dumps({"rows": rows, "threads": threads, "peak_mb": peak_rss_mb()}))
"""


_PRECISION = r"""
import json, sys, time
from pathlib import Path
case = json.loads(sys.argv[1])
from care_maps.runtime.threads import Work, use_threads
use_threads(Work.ENCODE)
import numpy as np
from care_maps.core.encoders import EncoderOptions, Precision, make_encoder
from care_maps.core.vocab import vocabulary_option
from care_maps.ingest.folders.frames import open_frames
from care_maps.ingest.source import ReadOptions

with open_frames(Path(case["rec"]), ReadOptions()) as stream:
    frames = [f for _, f in zip(range(case["views"]), stream)]
h, w = frames[0].height, frames[0].width
boxes = [(0, h // 2, 0, w // 2), (0, h // 2, w // 2, w), (h // 2, h, 0, w // 2),
         (h // 2, h, w // 2, w), (h // 4, 3 * h // 4, w // 4, 3 * w // 4)]
crops = [f.rgb[a:b, c:d] for f in frames for a, b, c, d in boxes]
out = {"views": len(frames), "crops": len(crops)}
names = list(vocabulary_option(case["vocabulary"]))
INT8 = "int8 (not offered)"
encoders = {}
for precision in Precision:
    options = EncoderOptions(weights=case["weights"], device=case["device"], precision=precision)
    encoders[str(precision)] = make_encoder("clip", options)
if case["device"] in (None, "cpu"):  # torch's dynamic int8 of the linear layers: CPU only
    import torch
    int8 = make_encoder("clip", EncoderOptions(weights=case["weights"], device="cpu"))
    int8.model = torch.ao.quantization.quantize_dynamic(int8.model, {torch.nn.Linear}, dtype=torch.qint8)
    encoders[INT8] = int8
for encoder in encoders.values():  # warm
    encoder.encode_prepared(encoder.prepare_views(frames[:8]))
    encoder.encode_crops(crops[:8])
text = encoders["float32"].encode_text(names)  # the text side is float32 at any precision
for turn in range(case["turns"]):  # in turn, each precision's least time kept
    for precision, encoder in encoders.items():
        prepared = encoder.prepare_views(frames)
        t = time.perf_counter()
        dense = encoder.encode_prepared(prepared)
        dense_s = time.perf_counter() - t
        t = time.perf_counter()
        crop = encoder.encode_crops(crops)
        crop_s = time.perf_counter() - t
        best = out.get(str(precision), {"dense_s": dense_s, "crop_s": crop_s})
        out[str(precision)] = {"dense": dense, "crop": crop,
                               "dense_s": min(dense_s, best["dense_s"]),
                               "crop_s": min(crop_s, best["crop_s"])}

def fidelity(a, b):
    a = a.reshape(-1, a.shape[-1]).astype(np.float64)
    b = b.reshape(-1, b.shape[-1]).astype(np.float64)
    cos = (a * b).sum(1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    top = (np.argmax(a @ text.T, 1) == np.argmax(b @ text.T, 1)).mean()
    return {"cos_mean": float(cos.mean()), "cos_min": float(cos.min()), "top1": float(top)}

full = out.pop("float32")
rows = []
for precision in encoders:
    res = full if precision == "float32" else out.pop(precision)
    rows.append({
        "precision": precision,
        "dense_s": res["dense_s"], "crop_s": res["crop_s"],
        "dense": fidelity(full["dense"], res["dense"]),
        "crop": fidelity(full["crop"], res["crop"]),
    })
print(json.dumps({**out, "rows": rows}))
"""


_BARE_CROPS = r"""
import json, resource, sys, time
from pathlib import Path
case = json.loads(sys.argv[1])
from care_maps.runtime.threads import Work, threads_for, use_threads
use_threads(Work.FUSE)  # what `care fuse instances` runs under; the model: Work.ENCODE's
import numpy as np
from care_maps.core.encoders.record import encoder_for_store
from care_maps.fuse.config import InstanceConfig, InstanceFeatures
from care_maps.fuse.instances import build_instances
from care_maps.runtime.execution import Execution
from bench.rss import peak_rss_mb

class Recorder:  # the store's model, its crops kept (each call: one batch of store views)
    def __init__(self, real):
        self.real, self.calls = real, []
    def __getattr__(self, name):
        return getattr(self.real, name)
    def encode_crops(self, crops):
        self.calls.append([np.array(c) for c in crops])
        return np.ones((len(crops), self.real.dim), np.float32)

store = Path(case["store"])
real = encoder_for_store(store)
recorder = Recorder(real)
config = InstanceConfig(features=InstanceFeatures.CROPS)
build_instances(store, config, run=Execution(progress=False, overwrite=True), encoder=recorder)
with threads_for(Work.ENCODE):
    real.encode_crops(recorder.calls[0][:2])  # first call, untimed
    use = resource.getrusage(resource.RUSAGE_SELF)
    c0, t = use.ru_utime + use.ru_stime, time.perf_counter()
    for crops in recorder.calls:  # as crop_features calls it
        real.encode_crops(crops)
    seconds = time.perf_counter() - t
    use = resource.getrusage(resource.RUSAGE_SELF)
crops = sum(len(c) for c in recorder.calls)
print(json.dumps({"seconds": seconds, "cpu": use.ru_utime + use.ru_stime - c0, "crops": crops,
                  "peak_mb": peak_rss_mb()}))
"""


def _living_room(views: int) -> Iterator:
    """``views`` living-room frames with their poses (past the 211 recorded, they start
    again, the clock going on)."""
    import numpy as np
    from PIL import Image

    from care_maps.core.frames import Frame

    lines = (DATA / "trajectory.log").read_text().split("\n")
    intrinsic = json.loads((DATA / "camera_intrinsic.json").read_text())["intrinsic_matrix"]
    K = np.array(intrinsic).reshape(3, 3).T
    count = len(list((DATA / "image").glob("*.jpg")))
    for i in range(views):
        k = i % count
        pose = np.array([[float(x) for x in row.split()] for row in lines[5 * k + 1 : 5 * k + 5]])
        rgb = np.asarray(Image.open(DATA / "image" / f"{k:05d}.jpg").convert("RGB"))
        depth = np.asarray(Image.open(DATA / "depth" / f"{k:05d}.png")).astype(np.float32) / 1e3
        yield Frame(10**9 + i * 33_333_333, rgb, depth, K, pose)


def _recording(work: Path, views: int) -> Path:
    from care_maps.ingest.write import write_recording

    path = work / f"living_room_{views}.mcap"
    if not path.is_file():
        write_recording(path, _living_room(views), fmt="mcap", compressed_rgb=True)
    return path


def _weights(work: Path, size: str) -> Path:
    from care_maps.core.encoders.random_clip import ClipSize, save_random_clip

    path = work / f"clip-{size}-random"
    if not path.is_dir():
        save_random_clip(path, size=ClipSize(size))
    return path


def _child(script: str, case: dict, cwd: Path) -> dict:
    env = {**os.environ, **OFFLINE, "PYTHONPATH": f"{cwd}{os.pathsep}{ROOT}"}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    done = subprocess.run(
        [sys.executable, "-c", script, json.dumps(case)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        lines = done.stderr.strip().splitlines() or ["no output"]
        return {"error": lines[-1]}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _ingest(
    rec: Path,
    weights: Path,
    out: Path,
    device: str | None,
    cwd: Path = ROOT,
    extra: tuple[str, ...] = (),
) -> dict:
    args = [str(rec), "--out", str(out), "--encoder", "clip", "--weights", str(weights),
            "--vocabulary", VOCABULARY, "--force", *extra]  # fmt: skip
    if device:
        args += ["--device", device]
    return _child(_COMMAND, {"args": ["ingest", *args], "out": str(out)}, cwd)


def _bare(rec: Path, weights: Path, views: int, device: str | None, sizes: list[int]) -> dict:
    case = {"rec": str(rec), "weights": str(weights), "views": views, "device": device,
            "sizes": sizes}  # fmt: skip
    return _child(_BARE, case, ROOT)


def _precisions(rec: Path, weights: Path, views: int, device: str | None) -> dict:
    case = {"rec": str(rec), "weights": str(weights), "views": views, "device": device,
            "vocabulary": VOCABULARY, "turns": 2}  # fmt: skip
    return _child(_PRECISION, case, ROOT)


def _fuse(store: Path, features: str) -> dict:
    args = ["fuse", "instances", str(store), "--features", features, "--overwrite"]
    return _child(_COMMAND, {"args": args}, ROOT)


def _crops(model: str, store: Path, repeat: int) -> None:
    """``care fuse instances --features crops`` on ``store`` (a whole command, fresh process)
    against ``--features masked`` (the same map, no model: what the crops add is the
    difference) and against the bare ``encode_crops`` of the very crops it encodes (recorded
    from a build of its own, then timed in the same calls, on the same threads)."""
    runs: dict[str, list[dict]] = {"crops": [], "masked": [], "bare": []}
    for _ in range(repeat):
        runs["bare"].append(_child(_BARE_CROPS, {"store": str(store)}, ROOT))
        runs["crops"].append(_fuse(store, "crops"))
        runs["masked"].append(_fuse(store, "masked"))
    bare, crops, masked = (_best(runs[k]) for k in ("bare", "crops", "masked"))
    print()
    failed = [r["error"] for r in (bare, crops, masked) if "error" in r]
    if failed:
        print(f"crops of care fuse instances failed: {failed[0]}")
        return
    n = bare["crops"]
    views = json.loads((store / "meta.json").read_text())["num_views"]
    added = {"seconds": crops["seconds"] - masked["seconds"], "cpu": crops["cpu"] - masked["cpu"]}
    print(
        f"crops of `care fuse instances` ({model}, cpu, the {views}-view store of `care "
        f"ingest` above; geometric proposals, up to 5 views an instance: {n} crops; "
        f"best of {repeat}; the whole commands include program start and, with crops, "
        f"the model's load)"
    )
    print()
    print(
        "| way | crops | seconds | crops/s | of the floor | CPU s | of the floor (CPU) | peak MiB |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    rows = (
        ("bare `encode_crops` of the same crops (the floor)", bare, False),
        ("`care fuse instances --features crops`, whole command", crops, False),
        ("the same `--features masked` (no model)", masked, None),
        ("what the crops add (the difference)", {**added, "peak_mb": crops["peak_mb"]}, True),
    )
    for way, res, of in rows:
        count = "" if of is None else f"{n}"
        rate = "" if of is None else f"{n / res['seconds']:.1f}"
        wall = f"{bare['seconds'] / res['seconds']:.2f}" if of else ""
        cpu = f"{bare['cpu'] / res['cpu']:.2f}" if of else ""
        print(
            f"| {way} | {count} | {res['seconds']:.1f} | {rate} | {wall} "
            f"| {res['cpu']:.0f} | {cpu} | {res['peak_mb']:,.0f} |"
        )


def _precision_table(res: dict, model: str, device: str | None) -> None:
    """Each precision's bare forward against float32's, dense maps and crops: speed-up, and
    fidelity (cosine of each cell's or crop's feature with float32's, mean and least; the
    share of cells or crops whose best class of the vocabulary is float32's)."""
    print()
    if "error" in res:
        print(f"precisions failed: {res['error']}")
        return
    print(
        f"precision against float32 ({model}, {device or 'cpu'}, {res['views']} living-room "
        f"views and {res['crops']} crops of them, a quadrant or the centre; top-1: the best "
        f"of the {VOCABULARY} classes, as float32 has it; each time the least of 2 turns)"
    )
    print()
    print(
        "| precision | dense views/s | speed-up | cosine mean | cosine least | top-1 agreement "
        "| crops/s | speed-up | cosine mean | cosine least | top-1 agreement |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    full = res["rows"][0]
    for row in res["rows"]:
        dense, crop = row["dense"], row["crop"]
        print(
            f"| {row['precision']} | {res['views'] / row['dense_s']:.2f} "
            f"| x{full['dense_s'] / row['dense_s']:.2f} | {dense['cos_mean']:.5f} "
            f"| {dense['cos_min']:.5f} | {100 * dense['top1']:.1f}% "
            f"| {res['crops'] / row['crop_s']:.1f} | x{full['crop_s'] / row['crop_s']:.2f} "
            f"| {crop['cos_mean']:.5f} | {crop['cos_min']:.5f} | {100 * crop['top1']:.1f}% |"
        )


def _cuda() -> bool:
    probe = "import torch; print(torch.cuda.is_available())"
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=False
    )
    return done.stdout.strip() == "True"


def _row(model: str, device: str, way: str, res: dict, floor: dict | None) -> None:
    """Print one table row, with its rates over the floor's (wall and CPU time)."""
    if "error" in res:
        print(f"| {model} | {device} | {way} | failed: {res['error']} | | | | | | |")
        return
    rate, per_cpu = res["views"] / res["seconds"], res["views"] / res["cpu"]
    of_wall = of_cpu = ""
    if floor is not None:
        of_wall = f"{rate / (floor['views'] / floor['seconds']):.2f}"
        of_cpu = f"{per_cpu / (floor['views'] / floor['cpu']):.2f}"
    print(
        f"| {model} | {device} | {way} | {res['views']} | {res['seconds']:.1f} | {rate:.2f} "
        f"| {of_wall} | {res['cpu']:.0f} | {per_cpu:.2f} | {of_cpu} | {res['peak_mb']:,.0f} |"
    )


def _best(runs: list[dict]) -> dict:
    """The run of least wall time (CPU time: the least of any run), or the first error."""
    failed = [r for r in runs if "error" in r]
    if failed:
        return failed[0]
    return {**min(runs, key=lambda r: r["seconds"]), "cpu": min(r["cpu"] for r in runs)}


def _past_start(long: dict, short: dict) -> dict:
    """What the views past a short run's cost: the difference of two runs (program start,
    model load and the vocabulary's text cancel out)."""
    if "error" in long or "error" in short:
        return long if "error" in long else short
    return {
        "views": long["views"] - short["views"],
        "seconds": long["seconds"] - short["seconds"],
        "cpu": long["cpu"] - short["cpu"],
        "peak_mb": long["peak_mb"],
    }


def _compare(
    model: str,
    device: str | None,
    recs: tuple[Path, Path],
    weights: Path,
    work: Path,
    baseline: Path | None,
    repeat: int,
    *,
    cheaper: bool = False,
) -> Path:
    """The bare forward and ``care ingest`` (and the baseline checkout's) on the long of
    ``recs``, and ingest on the short one, one after another ``repeat`` times, each way's
    best run; ``cheaper``: ingest at ``--precision bfloat16`` too. Returns the store of
    ``care ingest`` on the long recording (float32)."""
    from care_maps.core.store import BATCH_SIZE

    label = device or "cpu"
    slug = f"{model.lower().replace('/', '')}-{label}"
    rec, short = recs
    views = int(rec.stem.rsplit("_", 1)[-1])
    ways = {"ingest": ROOT, **({"before": baseline} if baseline is not None else {})}
    if cheaper:
        ways["bfloat16"] = ROOT
    runs: dict[str, list[dict]] = {"bare": []}
    for _ in range(repeat):
        res = _bare(rec, weights, views, device, [BATCH_SIZE])
        runs["bare"].append(res if "error" in res else {**res, **res["rows"][0]})
        for way, checkout in ways.items():
            store = work / f"store-{slug}-{way}"
            extra = ("--precision", way) if way == "bfloat16" else ()
            runs.setdefault(way, []).append(_ingest(rec, weights, store, device, checkout, extra))
            runs.setdefault(f"{way}-short", []).append(
                _ingest(short, weights, work / f"store-{slug}-{way}-short", device, checkout, extra)
            )
    floor = _best(runs["bare"])
    _row(model, label, "bare forward (the floor)", floor, None)
    floor = None if "error" in floor else floor
    for way, checkout in ways.items():
        name = {
            "ingest": "`care ingest --encoder clip`",
            "bfloat16": "the same `--precision bfloat16` (floor: float32's)",
        }.get(way, f"the same from {checkout}")
        long, cut = _best(runs[way]), _best(runs[f"{way}-short"])
        _row(model, label, name, long, floor)
        _row(model, label, f"{name}: views past the first {cut.get('views', '?')}",
             _past_start(long, cut), floor)  # fmt: skip
    return work / f"store-{slug}-ingest"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=200, help="Views a way (default 200).")
    parser.add_argument("--large", action="store_true", help="Add ViT-L/14 rows.")
    parser.add_argument("--large-views", type=int, default=8, help="Views of the ViT-L/14 rows.")
    parser.add_argument(
        "--sweep-views", type=int, default=16, help="Views of the batch sweep and precisions."
    )
    parser.add_argument("--device", default=None, help="cuda: add GPU rows where torch has one.")
    parser.add_argument("--baseline", type=Path, default=None, help="Another checkout to time.")
    parser.add_argument("--repeat", type=int, default=2, help="Runs of each way, best kept.")
    parser.add_argument("--workdir", type=Path, default=None)
    add_docs_flag(parser)
    args = parser.parse_args()
    work = Path(args.workdir or tempfile.mkdtemp(prefix="care-bench-encode-"))
    work.mkdir(parents=True, exist_ok=True)
    with recorded("encode", write=not args.no_docs):
        load = os.getloadavg()[0]
        t = time.perf_counter()
        b32 = _weights(work, "vit-b32")
        rec = _recording(work, args.views)
        sweep = _recording(work, args.sweep_views)
        print(
            f"living room, 640x480 JPEG, {args.views} views; CLIP with random weights (ViT-B/32: "
            f"14x19 cells of 448x608 input); inputs written in {time.perf_counter() - t:.0f} s"
        )
        devices: list[str | None] = [None]
        stores: dict[tuple[str, str | None], Path] = {}  # each model's float32 store, by device
        if args.device == "cuda" and _cuda():
            devices.append("cuda")
        elif args.device == "cuda":
            print("no GPU here: no cuda rows")
        print()
        print(
            "| model | device | way | views | seconds | views/s | of the floor | CPU s "
            "| views per CPU s | of the floor (CPU) | peak MiB |"
        )
        print("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
        for device in devices:
            stores["ViT-B/32", device] = _compare(
                "ViT-B/32", device, (rec, sweep), b32, work, args.baseline, args.repeat,
                cheaper=True,
            )  # fmt: skip
            if args.large:
                l14 = _weights(work, "vit-l14")
                large = _recording(work, args.large_views)
                short = _recording(work, max(1, args.large_views // 4))
                stores["ViT-L/14", device] = _compare(
                    "ViT-L/14", device, (large, short), l14, work, None, 1
                )
        for model in ("ViT-B/32", "ViT-L/14") if args.large else ("ViT-B/32",):
            _crops(model, stores[model, None], args.repeat)
        for device in devices:
            res = _precisions(sweep, b32, args.sweep_views, device)
            _precision_table(res, "ViT-B/32", device)
            if args.large:
                res = _precisions(_recording(work, args.large_views), _weights(work, "vit-l14"),
                                  args.large_views, device)  # fmt: skip
                _precision_table(res, "ViT-L/14", device)
        res = _bare(sweep, b32, args.sweep_views, None, list(SWEEP))
        print()
        threads = res.get("threads", "?")
        if "error" in res:
            print(f"batch sweep failed: {res['error']}")
        else:
            print(f"bare forward by batch size (ViT-B/32, cpu, {args.sweep_views} views)")
            print()
            print("| batch | views/s | CPU s a view |")
            print("| ---: | ---: | ---: |")
            for row in res["rows"]:
                rate = row["views"] / row["seconds"]
                print(f"| {row['batch']} | {rate:.2f} | {row['cpu'] / row['views']:.2f} |")
        print()
        print(
            f"best of {args.repeat} runs a way, in turn; seconds: ingest's whole command "
            f"(program start, model load and the vocabulary's {VOCABULARY} prompts included), "
            f"the bare forward's model calls alone; torch threads {threads} for the forward in "
            f"both; shared machine: load average {load:.1f} at the start, "
            f"{os.getloadavg()[0]:.1f} at the end"
        )


if __name__ == "__main__":
    main()
