"""The evaluate stage as one function: fused stores (or scenes) in, the report out."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from care_maps.core.store import Store
from care_maps.evaluate.groundtruth import GtSource
from care_maps.evaluate.job import EvalConfig, Scene, run_eval
from care_maps.evaluate.report import Report
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution

__all__ = ["evaluate"]


def evaluate(
    stores: Sequence[Store | Path | Scene] | Path,
    config: EvalConfig,
    out: Path,
    *,
    run: Execution = DEFAULT_EXECUTION,
    gt: Sequence[Path] = (),
    gt_defaults: GtSource | None = None,
) -> Report:
    """Evaluate every scene (a dataset directory, stores, or :class:`Scene` s with their
    ground truth) with ``config`` into ``out``; returns the report.

    Scenes run where ``run`` says (:meth:`care_maps.runtime.parallel.Runner.of`): in this process
    (``workers=1``), a local process pool of ``run.workers``, or on Ray (a cluster at
    ``run.ray_address``, else a local one); the outputs are the same, bit for bit, either
    way. Inside an open pool of the same settings (:func:`care_maps.runtime.parallel.open_runner`)
    the scenes run on it. Scenes already evaluated with the same config and the same map
    and ground-truth content are read from ``out/scenes``. ``gt``: one ground-truth file
    per scene, in order (else each scene's own); ``gt_defaults``: the format, transform and
    class map of scenes that name none (``care eval --gt-format`` ...).
    """
    if isinstance(stores, Path | str):
        dataset: Path | list[Path | Scene] = Path(stores)
    else:
        dataset = [s.path if isinstance(s, Store) else s for s in stores]
    return run_eval(dataset, config, out, run=run, gt=gt, gt_defaults=gt_defaults)
