"""Where the `labels` perception model's mistakes come from, on a sample-world recording.

Ingests the recording with the ``labels`` encoder (``--perception`` preset, default
``default``), builds the instance map with oracle masks (``labels`` proposals, so mask
errors do not blur the picture) and prints two tables:

1. per ground-truth instance, whether the fused top-1 class is right, and for the wrong
   ones whether the instance is persistently biased (seen as its confuser in every view)
   or unbiased and misread through view-dependent noise;
2. per class query (protocol ``class``), the first attempt (max confidence) and, for each
   failure, its cause: the retrieved instance is biased *into* the target, every instance
   of the target is biased *away* from it, or neither (noise).

    python -m care_maps.research.perception_breakdown [RECORDING] [--perception default|ideal]
"""

from __future__ import annotations

import argparse
import tempfile
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from care_maps.core.encoders import EncoderOptions, make_encoder
from care_maps.core.encoders.base import RecordingContext
from care_maps.core.maps import MapKind
from care_maps.core.store import read_table
from care_maps.evaluate.pipeline import SAMPLE
from care_maps.fuse.config import ProposalMethod
from care_maps.fuse.instances import InstanceConfig, build_instances
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.source import RecordingFrames
from care_maps.query import confidence, load_map
from care_maps.runtime.execution import Execution
from care_maps.truth.formats.native import read_native
from care_maps.world.perception.model import PerceptionPreset

if TYPE_CHECKING:
    from care_maps.world.perception.encoder import LabelsEncoder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("recording", nargs="?", type=Path, default=SAMPLE / "scene_000.mcap")
    parser.add_argument(
        "--perception",
        type=PerceptionPreset,
        choices=list(PerceptionPreset),
        default=PerceptionPreset(EncoderOptions.perception),
    )
    args = parser.parse_args()

    gt = read_native(args.recording)
    with RecordingFrames(args.recording) as rec:
        names = list(rec.label_names)
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "store"
        options = EncoderOptions(perception=args.perception)
        run_ingest(
            args.recording,
            store,
            IngestConfig(encoder="labels", encoder_options=options),
            run=Execution(progress=False),
        )
        build_instances(store, InstanceConfig(proposals=ProposalMethod.LABELS))
        cmap = load_map(store, MapKind.INSTANCES)
        inst = read_table(store / "instances.parquet", ["source_id"]).column("source_id")
        inst = inst.to_numpy().astype(np.int64)
    enc = cast("LabelsEncoder", make_encoder("labels", options))  # the registry's "labels"
    enc.prepare(RecordingContext(args.recording, tuple(names)))

    truth = gt.instance_class_names()
    true_cls = np.array([names.index(truth[int(i)]) for i in inst])
    biased = enc.biased(inst, true_cls)
    perceived = enc.perceived_class(inst, true_cls)
    vocab = list(cmap.vocabulary)
    top1 = np.array([names.index(vocab[c]) for c in cmap.top_classes[:, 0]])
    wrong = top1 != true_cls
    print(f"{args.recording.name}, perception {args.perception!r}, {len(inst)} instances:")
    print(f"  fused top-1 class right: {int((~wrong).sum())}")
    print(
        f"  wrong, persistent bias:  {int((wrong & biased).sum())} (of {int(biased.sum())} biased)"
    )
    print(f"  wrong, view noise:       {int((wrong & ~biased).sum())}")

    causes: Counter[str] = Counter()
    targets = sorted({int(c) for c in true_cls})  # the object classes present
    for y in targets:
        conf = confidence(cmap, np.array([vocab.index(names[y])]))[0]
        first = int(np.argmax(conf))
        if true_cls[first] == y:
            causes["success"] += 1
        elif biased[first] and perceived[first] == y:
            causes["failure: retrieved instance biased into the target"] += 1
        elif np.all(biased[true_cls == y]):
            causes["failure: every target instance biased away"] += 1
        else:
            causes["failure: view-dependent noise"] += 1
    print(f"first attempt over {len(targets)} class queries:")
    for cause, n in sorted(causes.items()):
        print(f"  {cause}: {n}")


if __name__ == "__main__":
    main()
