"""A cold ``care query``: a new process, a store on disk, one answer, as a robot's task
planner calls it.

A store is ingested from the bundled sample recording (every 15th frame) with a CLIP of
ViT-B/32's architecture and random weights (:mod:`care_maps.core.encoders.random_clip`; a real
``--weights`` directory can be given instead), and its instance map built. Then each way
runs ``--repeat`` times in fresh processes, and the best wall time is printed:

- a class of the vocabulary, ``care query STORE chair`` end to end: answered from the
  store's cached text embeddings, no model loaded (target < 2 s);
- free text, ``care query STORE "somewhere to sit down"`` end to end: the CLIP text tower
  alone is loaded (``ClipEncoder.for_text``);
- side by side, free text the whole-model way: the same map load and text match with the
  whole CLIP (both towers, image processor) built to embed the text, as a query did before
  the text side could be loaded alone.

Run: ``python bench/cold_query.py`` (``--repeat 1`` for a quick look).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.docs_section import add_docs_flag, recorded  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "care_maps" / "data" / "sample" / "scene_000.mcap"
CLASS, FREE_TEXT = "chair", "somewhere to sit down"
REPEAT = 3
OFFLINE = {"HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}

_WHOLE_MODEL = """
import sys
from pathlib import Path
from care_maps.core.encoders.record import encoder_for_store
from care_maps.query.map import load_map
from care_maps.query.text import resolve_text
store = Path(sys.argv[1])
cmap = load_map(store)
match = resolve_text(cmap, sys.argv[2], embed=encoder_for_store(store).encode_text,
                     same_space=True)
print(match.describe())
"""


def _store(workdir: Path, weights: Path | None) -> Path:
    """The bench's CLIP store (made once, reused while its inputs stay the same)."""
    from care_maps.core.encoders.random_clip import ClipSize, save_random_clip

    if weights is None:
        weights = workdir / "clip-vit-b32-random"
        if not weights.is_dir():
            save_random_clip(weights, size=ClipSize.VIT_B32)
    store = workdir / "store"
    care = [sys.executable, "-m", "care_maps.cli.main"]
    env = _env()
    subprocess.run(
        [*care, "ingest", SAMPLE, "--out", store, "--encoder", "clip",
         "--weights", weights, "--every", "15"],
        check=True, env=env, capture_output=True,
    )  # fmt: skip
    subprocess.run([*care, "fuse", "instances", store], check=True, env=env, capture_output=True)
    return store


def _env() -> dict[str, str]:
    """Offline, and with Python's bytecode cache on, as in a user's installation (pip
    compiles a wheel's modules; a checkout's are cached on first import): a shell with
    ``PYTHONDONTWRITEBYTECODE`` set would time compiling every module, not starting."""
    env = {**os.environ, **OFFLINE}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def _best(argv: list[str], repeat: int) -> tuple[float, float]:
    """Best wall time (s) and the largest resident memory (MiB) of ``argv`` in a fresh
    process, ``repeat`` times."""
    times, peaks = [], []
    for _ in range(repeat):
        start = time.perf_counter()
        proc = subprocess.Popen(
            argv, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        _, status, usage = os.wait4(proc.pid, 0)
        times.append(time.perf_counter() - start)
        if os.waitstatus_to_exitcode(status) != 0:
            msg = f"{' '.join(map(str, argv))} failed"
            raise SystemExit(msg)
        peaks.append(usage.ru_maxrss / 1024)  # KiB on Linux
    return min(times), max(peaks)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/care-bench-cold-query"))
    parser.add_argument("--weights", type=Path, help="a real CLIP directory (save_pretrained)")
    parser.add_argument("--repeat", type=int, default=REPEAT)
    add_docs_flag(parser)
    args = parser.parse_args()
    args.workdir.mkdir(parents=True, exist_ok=True)
    store = _store(args.workdir, args.weights)
    care = [sys.executable, "-m", "care_maps.cli.main", "query", str(store)]
    with recorded("cold_query", write=not args.no_docs and args.repeat >= REPEAT):
        model = "given weights" if args.weights else "ViT-B/32 architecture, random weights"
        print(f"cold `care query` on the sample store (instances map; CLIP: {model}),")
        print(f"best of {args.repeat} fresh processes each")
        print("| query | way | seconds | peak MiB | against the whole-model way |")
        print("| --- | --- | --- | --- | --- |")
        whole = _best([sys.executable, "-c", _WHOLE_MODEL, str(store), FREE_TEXT], args.repeat)
        rows = [
            (f"class `{CLASS}`", "cached text embeddings, no model", _best([*care, CLASS], args.repeat)),
            (f"free text `{FREE_TEXT}`", "text tower alone", _best([*care, FREE_TEXT], args.repeat)),
            (f"free text `{FREE_TEXT}`", "whole CLIP (both towers)", whole),
        ]  # fmt: skip
        for query, way, (seconds, mib) in rows:
            ratio = whole[0] / seconds
            print(f"| {query} | {way} | {seconds:.2f} | {mib:.0f} | x{ratio:.2f} faster |")


if __name__ == "__main__":
    main()
