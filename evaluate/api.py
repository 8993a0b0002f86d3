"""The evaluate stage as one function: fused stores (or scenes) in, the report out."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from care.store import Store
from evaluate.job import EvalConfig, Scene, run_eval
from evaluate.report import Report
from runtime.parallel import Runner

__all__ = ["evaluate"]


def evaluate(
    stores: Sequence[Store | Path | Scene] | Path,
    config: EvalConfig,
    out: Path,
    *,
    workers: int | None = None,
    ray_address: str | bool | None = None,
    progress: bool = True,
    runner: Runner | None = None,
) -> Report:
    """Evaluate every scene (a dataset directory, stores, or :class:`Scene` s with their
    ground truth) with ``config`` into ``out``; returns the report.

    Scenes run in this process (``workers=1``), a local process pool of ``workers``, or on
    Ray (``ray_address``: True for a local Ray, or a cluster's address); the outputs are
    the same, bit for bit, either way (``runner``, when given, says where instead). Scenes already evaluated with the same config and
    the same map and ground-truth content are read from ``out/scenes``.
    """
    if isinstance(stores, Path | str):
        dataset: Path | list[Path | Scene] = Path(stores)
    else:
        dataset = [s.path if isinstance(s, Store) else s for s in stores]
    return run_eval(
        dataset, config, out, workers=workers, ray_address=ray_address, progress=progress,
        runner=runner,
    )  # fmt: skip
