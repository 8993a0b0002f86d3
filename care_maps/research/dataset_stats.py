"""How hard a sample-world dataset is: first-attempt success of each map, measured by running
the pipeline (``care sample make --measure``).

A preset is only as Matterport-like as its first attempts: the paper's max-confidence
first attempt succeeds 12.09% of the time on instances (``instance`` protocol) and 54.4% on
the grid. This module maps every recording of a dataset (the same ingest, grid and instance
map as ``care run``, without the Rerun files), evaluates the first attempt only, and writes
the rates into the dataset's ``index.json`` (``statistics.first_attempt``).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow.compute as pc

from care_maps.core.encoders import EncoderOptions
from care_maps.core.maps import MapKind
from care_maps.core.outputs import atomic_write_text
from care_maps.evaluate.job import EvalConfig, Scene, run_eval
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.fuse.instances import InstanceConfig, build_instances
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.replan.strategies import StrategyName
from care_maps.runtime.execution import Execution
from care_maps.truth.dataset_index import INDEX_NAME, read_index

__all__ = ["MeasureConfig", "first_attempt_rates", "map_dataset", "measure_first_attempts"]

MEASURE_DIR = "measure"
"""Sub-directory of the dataset that holds the stores and evaluation of the measurement."""


@dataclass(frozen=True)
class MeasureConfig:
    """How a dataset is mapped and evaluated for its first attempts (``care run``'s maps)."""

    encoder_options: EncoderOptions = field(default_factory=EncoderOptions)
    """Options of the ``labels`` encoder (``perception="default"``: the dataset's own model)."""
    grid: GridConfig = field(default_factory=lambda: GridConfig(stride=2))
    """Grid settings (as ``care run``)."""
    instances: InstanceConfig = field(default_factory=InstanceConfig)
    """Instance-map settings (as ``care run``)."""


def map_dataset(
    dataset: Path, out: Path, config: MeasureConfig | None = None, *, progress: bool = False
) -> list[Scene]:
    """Ingest every recording of ``dataset`` into ``out/stores/<name>`` and build both maps
    (each step skipped where up to date); returns the scenes to evaluate."""
    config = config or MeasureConfig()
    scenes = []
    for entry in read_index(dataset):
        store = Path(out) / "stores" / entry.name
        run = Execution(progress=progress)
        run_ingest(
            entry.recording,
            store,
            IngestConfig(encoder="labels", encoder_options=config.encoder_options),
            run=run,
        )
        build_grid(store, config.grid, run=run)
        build_instances(store, config.instances, run=run)
        scenes.append(Scene(entry.name, store, entry.recording.resolve()))
    return scenes


def first_attempt_rates(summary_rows: Sequence[dict]) -> dict[str, float]:
    """``{"instances/instance": %, "instances/class": %, "grid": %}`` from a summary's
    ``no replan`` rows."""
    out = {}
    for r in summary_rows:
        if r["strategy"] != StrategyName.NO_REPLAN:
            continue
        key = "grid" if r["map"] == MapKind.GRID else f"{r['map']}/{r['protocol']}"
        out[key] = round(float(r["rate"]), 2)
    return dict(sorted(out.items(), key=lambda kv: (kv[0] == MapKind.GRID, kv[0])))


def measure_first_attempts(
    dataset: Path,
    *,
    workers: int | None = 1,
    config: MeasureConfig | None = None,
    progress: bool = True,
    out: Path | None = None,
) -> dict[str, float]:
    """Map and evaluate ``dataset`` (first attempts only) in ``out`` (default
    ``dataset/measure``) and return the rates; with the default ``out`` they are also
    recorded in the dataset's ``index.json`` under ``statistics.first_attempt``."""
    dataset = Path(dataset)
    record = out is None
    out = dataset / MEASURE_DIR if out is None else Path(out)
    scenes = map_dataset(dataset, out, config, progress=progress)
    evaluation = EvalConfig(strategies=(StrategyName.NO_REPLAN,), attempts=1, seeds=1, bootstrap=0)
    run = Execution(workers=workers, progress=progress)
    report = run_eval(scenes, evaluation, out / "eval", run=run)
    rows = report.summary.filter(
        pc.equal(report.summary.column("strategy"), StrategyName.NO_REPLAN)
    )
    rates = first_attempt_rates(rows.to_pylist())
    if not record:
        return rates
    index_path = dataset / INDEX_NAME
    doc = json.loads(index_path.read_text())
    doc.setdefault("statistics", {})["first_attempt"] = rates
    atomic_write_text(index_path, json.dumps(doc, indent=1))
    return rates
