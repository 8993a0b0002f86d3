"""When CARe helps: the paired gain of each measure over a grid of perception settings.

The paper shows CARe helping on one dataset with one VLM. Whether it helps depends on how
the VLM errs: a confident, consistent mistake (persistent bias with little view noise)
looks *certain* to every consistency measure, while a mistake that changes with the
viewpoint (view-dependent bias, view noise) is what the per-view spread can see. This
module re-encodes the same recordings under each setting of a grid over (bias rate, bias
noise scale, view-dependent bias, view noise), builds both maps, plays the pre-registered
rules (:data:`care_maps.evaluate.report.preregistered.PAPER_SETTINGS`) and max confidence, and
reports each measure's paired gain over max confidence with its scene-level 95%
interval and its scene-level sign-flip p, Holm-corrected over every comparison of the sweep
(``sweep.parquet``), and a figure of it (``sweep.png``): the figure the paper lacks. Holm
over ``m`` comparisons needs a p-value of ``0.05 / m`` at least once, and ``G`` scenes give
no less than ``2 / 2^G`` (:func:`care_maps.evaluate.scene_test.scenes_for_family`): with
too few scenes per setting the table says the sweep cannot reject (``family_can_reject``)
instead of printing corrected p-values that could never pass.

Every setting is a perception override of the dataset's recorded model
(``EncoderOptions.perception = "default:key=value,..."``), so the scenes and the
trajectory stay fixed and only the perception changes. A re-run resumes: the stores of
finished settings are kept.

    python -m care_maps.research.sweep DATASET OUT [--design oat|grid] [--values bias_rate=0.1,0,0.3 ...]
"""

from __future__ import annotations

import argparse
import itertools
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from care_maps.core.maps import MapKind
from care_maps.core.store import write_table_atomic
from care_maps.evaluate.config import DEFAULT_BOOTSTRAP, QueryProtocol
from care_maps.evaluate.job import EvalConfig, run_eval
from care_maps.evaluate.paired import holm
from care_maps.evaluate.report.preregistered import PAPER_SETTINGS, headline_table
from care_maps.evaluate.scene_test import ALPHA, scenes_for_family
from care_maps.replan.strategies import StrategyName
from care_maps.research.dataset_stats import MeasureConfig, map_dataset
from care_maps.runtime.execution import Execution

__all__ = [
    "SWEEP_KNOBS",
    "SweepConfig",
    "SweepDesign",
    "comparisons",
    "main",
    "plot_sweep",
    "run_sweep",
    "settings_of",
    "sweep_settings",
]

SWEEP_KNOBS = ("bias_rate", "bias_noise_scale", "view_bias_rate", "base_noise")
"""The axes: ``bias_rate`` sets both the instance and the class bias rate; ``base_noise``
is the view noise of a near, frontal, fully visible segment (the rest grows from it)."""


class SweepDesign(StrEnum):
    """Which settings a sweep runs."""

    OAT = "oat"
    """One knob at a time around the first value of each (cheap)."""
    GRID = "grid"
    """Every combination (the full product)."""


@dataclass(frozen=True)
class SweepConfig:
    """The grid: values per knob; ``design`` ``oat`` varies one knob at a time around the
    first value of each (cheap), ``grid`` takes every combination."""

    bias_rate: tuple[float, ...] = (0.3, 0.0)
    bias_noise_scale: tuple[float, ...] = (1.0, 0.3)
    view_bias_rate: tuple[float, ...] = (0.5, 0.0)
    base_noise: tuple[float, ...] = (0.6, 0.3)
    design: SweepDesign = SweepDesign.OAT
    """Which settings are run (:class:`SweepDesign`)."""
    bootstrap: int = DEFAULT_BOOTSTRAP
    """0: no intervals (otherwise the scene test's own patterns,
    :mod:`care_maps.evaluate.scene_test`)."""
    workers: int = 1
    """Evaluation processes."""
    measure: MeasureConfig = field(default_factory=MeasureConfig)
    """Map settings (the encoder options' perception is replaced per setting)."""


def sweep_settings(config: SweepConfig) -> list[dict[str, float]]:
    """The settings of the sweep, each ``{knob: value}``, the centre first."""
    values = {k: tuple(getattr(config, k)) for k in SWEEP_KNOBS}
    if SweepDesign(config.design) is SweepDesign.GRID:
        return [
            dict(zip(SWEEP_KNOBS, combo, strict=True))
            for combo in itertools.product(*values.values())
        ]
    centre = {k: v[0] for k, v in values.items()}
    out = [centre]
    for knob, vals in values.items():
        out += [{**centre, knob: v} for v in vals[1:]]
    return out


def _spec(setting: dict[str, float]) -> str:
    parts = {
        "instance_bias_rate": setting["bias_rate"],
        "class_bias_rate": setting["bias_rate"],
        "bias_noise_scale": setting["bias_noise_scale"],
        "view_bias_rate": setting["view_bias_rate"],
        "base_noise": setting["base_noise"],
    }
    return "default:" + ",".join(f"{k}={v:g}" for k, v in parts.items())


def _tag(setting: dict[str, float]) -> str:
    return "_".join(f"{k}{setting[k]:g}" for k in SWEEP_KNOBS)


def _evaluation() -> EvalConfig:
    """What each setting is evaluated with: the pre-registered rules and max confidence."""
    return EvalConfig(
        strategies=(
            StrategyName.NO_REPLAN,
            StrategyName.MAX_CONFIDENCE,
            StrategyName.MAX_ENTROPY,
            StrategyName.MIN_STDERR,
            StrategyName.MIN_PWKL,
        ),
        k_instances=tuple(sorted({k for _, _, k in PAPER_SETTINGS[MapKind.INSTANCES]})),
        k_grid=tuple(sorted({k for _, _, k in PAPER_SETTINGS[MapKind.GRID]})),
        protocols=(QueryProtocol.INSTANCE,),
        seeds=1,
        bootstrap=0,
    )


def comparisons(config: SweepConfig | None = None) -> int:
    """The size of the sweep's Holm family: every setting's pre-registered rules against max
    confidence, on each instance protocol and each grid protocol."""
    evaluation = _evaluation()
    per_setting = len(evaluation.protocols) * len(PAPER_SETTINGS[MapKind.INSTANCES]) + len(
        evaluation.exclude_radii
    ) * len(PAPER_SETTINGS[MapKind.GRID])
    return len(sweep_settings(config or SweepConfig())) * per_setting


def run_sweep(
    dataset: Path, out: Path, config: SweepConfig | None = None, *, progress: bool = True
) -> pa.Table:
    """Run every setting on ``dataset`` under ``out`` (stores per setting are kept, so a
    re-run resumes) and write ``out/sweep.parquet`` and ``out/sweep.png``."""
    from tqdm import tqdm

    config = config or SweepConfig()
    out = Path(out)
    evaluation = _evaluation()
    rows = []
    settings = sweep_settings(config)
    for setting in tqdm(settings, desc="sweep", unit="setting", disable=not progress):
        here = out / _tag(setting)
        measure = replace(
            config.measure,
            encoder_options=replace(config.measure.encoder_options, perception=_spec(setting)),
        )
        scenes = map_dataset(dataset, here, measure)
        run = Execution(workers=config.workers, progress=False)
        report = run_eval(scenes, evaluation, here / "eval", run=run)
        import pyarrow.parquet as pq

        attempts = pq.read_table(here / "eval" / "attempts.parquet")
        first = report.summary.filter(
            pc.equal(report.summary.column("strategy"), StrategyName.NO_REPLAN)
        )
        first_rate = {r["map"]: r["rate"] for r in first.to_pylist()}
        table = headline_table(attempts, bootstrap=config.bootstrap)
        for r in table.to_pylist():
            if r["family"] != "pre-registered" or not r["baseline"].startswith("Max confidence"):
                continue
            rows.append(
                {
                    **setting,
                    "map": r["map"],
                    "protocol": r["protocol"],
                    "measure": r["strategy"],
                    "criterion": r["criterion"],
                    "k": r["k"],
                    "first_attempt": first_rate.get(r["map"], float("nan")),
                    StrategyName.MAX_CONFIDENCE: r["baseline_rate"],
                    "rate": r["rate"],
                    "gain": r["diff"],
                    "lo": r["lo"],
                    "hi": r["hi"],
                    "mcnemar_p": r["mcnemar_p"],
                    "scene_p": r["scene_p"],
                    "scene_min_p": r["scene_min_p"],
                    "scenes": r["scenes"],
                    "n_queries": r["n_queries"],
                }
            )
    # one family: every (setting, map, protocol, measure) compared, on the scene p-values
    adjusted = holm(np.array([r["scene_p"] for r in rows], np.float64))
    floor = min((r["scene_min_p"] for r in rows), default=1.0)
    for r, h in zip(rows, adjusted, strict=True):
        r["holm_p"] = float(h)
        r["family_size"] = len(rows)
        r["family_can_reject"] = bool(floor <= ALPHA / len(rows))
        r["scenes_needed"] = scenes_for_family(len(rows))
    result = pa.Table.from_pylist(rows)
    write_table_atomic(result, out / "sweep.parquet")
    plot_sweep(result, out / "sweep.png", config)
    return result


def plot_sweep(table: pa.Table, path: Path, config: SweepConfig | None = None) -> Path:
    """One panel per (map, knob): each measure's gain over max confidence (percentage points)
    against the knob's value, the other knobs at the centre; 95% intervals as error bars."""
    import matplotlib as mpl

    mpl.use("Agg")
    import matplotlib.pyplot as plt

    config = config or SweepConfig()
    rows = table.to_pylist()
    panels = sorted(
        {(r["map"], r["protocol"]) for r in rows}, key=lambda mp: (mp[0] == MapKind.GRID, mp)
    )
    centre = {k: getattr(config, k)[0] for k in SWEEP_KNOBS}
    colours = {
        StrategyName.MAX_ENTROPY: "tab:orange",
        StrategyName.MIN_STDERR: "tab:green",
        StrategyName.MIN_PWKL: "tab:purple",
    }
    fig, axes = plt.subplots(
        len(panels), len(SWEEP_KNOBS), figsize=(14, 3.3 * len(panels)), squeeze=False, sharey="row"
    )
    for i, (kind, protocol) in enumerate(panels):
        for j, knob in enumerate(SWEEP_KNOBS):
            ax = axes[i][j]
            others = [k for k in SWEEP_KNOBS if k != knob]
            for measure, colour in colours.items():
                pts = sorted(
                    (r[knob], r["gain"], r["lo"], r["hi"])
                    for r in rows
                    if (r["map"], r["protocol"]) == (kind, protocol)
                    and r["measure"] == measure
                    and all(np.isclose(r[o], centre[o]) for o in others)
                )
                if not pts:
                    continue
                x, y, lo, hi = (np.array(v, np.float64) for v in zip(*pts, strict=True))
                err = np.stack([np.nan_to_num(y - lo), np.nan_to_num(hi - y)])
                ax.errorbar(x, y, yerr=err, marker="o", capsize=3, color=colour, label=measure)
            ax.axhline(0, color="black", linewidth=0.8)
            ax.axvline(centre[knob], color="gray", linewidth=0.6, linestyle=":")
            ax.set_xlabel(knob)
            ax.grid(alpha=0.3)
            if j == 0:
                ax.set_ylabel(f"{kind} ({protocol}):\ngain over max conf. (pp)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(
        handles, labels, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=3, frameon=False
    )
    fig.suptitle(
        "When CARe helps: paired gain of each measure (paper's settings), 95% scene-level CI",
        y=1.06,
    )
    fig.tight_layout()
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=110, bbox_inches="tight")
    plt.close(fig)
    tmp.replace(path)
    return path


def settings_of(values: Sequence[str]) -> dict[str, tuple[float, ...]]:
    """``["bias_rate=0.1,0,0.3", ...]`` as ``{knob: values}`` (for the script's options)."""
    out = {}
    for item in values:
        key, _, text = item.partition("=")
        if key not in SWEEP_KNOBS:
            msg = f"sweep knob {key!r}: choose from {', '.join(SWEEP_KNOBS)}"
            raise ValueError(msg)
        out[key] = tuple(float(v) for v in text.split(","))
    return out


def main() -> None:
    """The command line: ``python -m care_maps.research.sweep`` or ``scripts/sweep.py``."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("dataset", type=Path, help="A `care sample make` dataset directory.")
    parser.add_argument("out", type=Path, help="Directory of the sweep's stores and results.")
    defaults = SweepConfig()
    parser.add_argument(
        "--design", type=SweepDesign, choices=list(SweepDesign), default=defaults.design
    )
    parser.add_argument("--values", nargs="*", default=[], help="KNOB=v1,v2,... (centre first)")
    parser.add_argument("--workers", type=int, default=defaults.workers)
    parser.add_argument("--bootstrap", type=int, default=defaults.bootstrap)
    args = parser.parse_args()
    try:
        values: dict[str, Any] = settings_of(args.values)  # knob -> values, as SweepConfig's
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    config = replace(
        SweepConfig(), design=args.design, workers=args.workers, bootstrap=args.bootstrap, **values
    )
    table = run_sweep(args.dataset, args.out, config)
    print(f"{table.num_rows} rows: {args.out / 'sweep.parquet'}, {args.out / 'sweep.png'}")


if __name__ == "__main__":
    main()
