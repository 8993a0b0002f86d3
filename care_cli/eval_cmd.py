"""``care query``, ``care replan``, ``care eval`` and ``care run``: ask a map, replan, evaluate
a dataset, and the main job that chains every stage.

Stage modules are imported inside the commands so ``care --help`` stays fast. ``care eval``'s
options mirror :class:`evaluate.job.EvalConfig`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

__all__ = ["register"]

StoreArg = Annotated[Path, typer.Argument(help="Store directory with fused maps (`care fuse`).")]
TextArg = Annotated[str, typer.Argument(help="What to look for: a class name or free text.")]
MapOpt = Annotated[str, typer.Option("--map", help="Map to ask: instances or grid.")]
RayOpt = Annotated[
    bool,
    typer.Option("--ray", help="Evaluate scenes as Ray tasks (a local Ray unless --ray-address)."),
]
RayAddressOpt = Annotated[
    str | None,
    typer.Option(help="Address of a running Ray cluster, e.g. ray://head:10001 (implies --ray)."),
]


def _csv(value: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in value.split(",") if v.strip())


def _ints(value: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in _csv(value))
    except ValueError as err:
        from care.errors import EvalError

        msg = f"expected comma-separated integers, got {value!r}"
        raise EvalError(msg) from err


def _ray_target(ray: bool, address: str | None) -> str | bool | None:
    """What ``run_eval`` takes: a cluster address, True for a local Ray, None for no Ray."""
    return address or (True if ray else None)


def _resolve(store: Path, kind: str, text: str) -> tuple:
    """The map and the class the text maps to (the mapping is printed unless exact)."""
    from query import load_map, resolve_text

    cmap = load_map(store, kind)  # type: ignore[arg-type]
    match = resolve_text(cmap, text)
    if match.method != "vocabulary":
        typer.echo(f"query {match.describe()}")
    return cmap, match


def query(
    store: StoreArg,
    text: TextArg,
    kind: MapOpt = "instances",
    top: Annotated[int, typer.Option(help="How many candidates to list.")] = 10,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Rank a map's candidates by confidence for TEXT, with their uncertainty measures."""
    import numpy as np

    from query import confidence, rank_by_confidence

    cmap, match = _resolve(store, kind, text)
    conf = confidence(cmap, np.array([match.class_id]))[0]
    order = rank_by_confidence(conf[None])[0][:top]
    rows = [
        {
            "rank": r + 1,
            "candidate": int(c),
            "confidence": float(conf[c]),
            "entropy": float(cmap.entropy[c]),
            "stderr": float(cmap.stderr[c]),
            "pwkl": float(cmap.pwkl[c]),
            "num_views": int(cmap.num_views[c]),
            "position": [round(float(v), 3) for v in cmap.positions[c]],
        }
        for r, c in enumerate(order)
    ]
    if as_json:
        typer.echo(json.dumps({"query": text, "class": match.names[0], "candidates": rows}))
        return
    typer.echo(f"{kind} map, class {match.names[0]!r}: {cmap.num_candidates} candidates")
    typer.echo("rank  cand  confidence  entropy   stderr     pwkl  views  position")
    for r in rows:
        typer.echo(
            f"{r['rank']:>4} {r['candidate']:>5} {r['confidence']:>11.4g} {r['entropy']:>8.3f} "
            f"{r['stderr']:>8.4g} {r['pwkl']:>8.4g} {r['num_views']:>6}  {r['position']}"
        )


def replan(
    store: StoreArg,
    text: TextArg,
    visited: Annotated[
        str, typer.Option(help="Comma-separated candidate ids already tried (failed).")
    ] = "",
    strategy: Annotated[
        str, typer.Option(help="Replan strategy (see `care eval --help`).")
    ] = "min_stderr",
    criterion: Annotated[
        str, typer.Option(help="Candidate set: confidence or category.")
    ] = "confidence",
    k: Annotated[int, typer.Option("-k", help="Size parameter of the candidate set.")] = 4,
    kind: MapOpt = "instances",
    exclude_radius: Annotated[
        float, typer.Option(help="Grid: skip cells within this distance (m) of failed ones.")
    ] = 1.0,
    seed: Annotated[int, typer.Option(help="Seed of the random strategies.")] = 0,
) -> None:
    """The next candidate to try for TEXT after the --visited ones (JSON on stdout)."""
    import dataclasses

    from replan import next_goal

    cmap, match = _resolve(store, kind, text)
    choice = next_goal(
        cmap, match.class_id, list(_ints(visited)), strategy=strategy, criterion=criterion,
        k=k, exclude_radius=exclude_radius, seed=seed,
    )  # fmt: skip
    out = dataclasses.asdict(choice)
    out["position"] = (
        [float(v) for v in cmap.positions[choice.candidate]] if choice.candidate >= 0 else None
    )
    out["class"] = match.names[0]
    typer.echo(json.dumps(out))


def eval_(
    dataset: Annotated[
        list[Path],
        typer.Argument(
            help="Dataset directory (index.json of recordings with fused stores) or stores."
        ),
    ],
    out: Annotated[
        Path, typer.Option(help="Output directory (results.md, Parquet, plots).")
    ] = Path("out/eval"),
    maps: Annotated[str, typer.Option(help="Maps to evaluate: instances,grid.")] = "instances,grid",
    strategies: Annotated[str, typer.Option(help="Comma-separated strategies; default all.")] = "",
    criteria: Annotated[str, typer.Option(help="Selection criteria.")] = "confidence,category",
    k_instances: Annotated[str, typer.Option(help="k values of the instance map.")] = "2,4,8,16,40",
    k_grid: Annotated[str, typer.Option(help="k values of the grid map.")] = "4,8,16,40,100",
    attempts: Annotated[int, typer.Option(help="Attempts per query (first + replans).")] = 2,
    protocols: Annotated[
        str, typer.Option(help="Instance query protocols: instance,class.")
    ] = "instance,class",
    rooms: Annotated[
        bool, typer.Option(help="Evaluate room by room where the GT has rooms.")
    ] = True,
    seeds: Annotated[int, typer.Option(help="Seeds of the random strategies.")] = 10,
    exclude_radius: Annotated[
        float, typer.Option(help="Grid: radius (m) skipped around a failure.")
    ] = 1.0,
    bootstrap: Annotated[int, typer.Option(help="Bootstrap resamples for the 95% CIs.")] = 1000,
    workers: Annotated[int, typer.Option(help="Local processes (0: one per CPU).")] = 0,
    ray: RayOpt = False,
    ray_address: RayAddressOpt = None,
) -> None:
    """Success of every strategy on every (scene, class) query; writes the paper's tables."""
    from evaluate.job import EvalConfig, run_eval
    from replan import STRATEGIES

    config = EvalConfig(
        maps=_csv(maps),
        strategies=_csv(strategies) or tuple(STRATEGIES),
        criteria=_csv(criteria),
        k_instances=_ints(k_instances),
        k_grid=_ints(k_grid),
        attempts=attempts,
        protocols=_csv(protocols),
        rooms=rooms,
        seeds=seeds,
        exclude_radius=exclude_radius,
        bootstrap=bootstrap,
    )
    report = run_eval(
        dataset, config, out, workers=workers or None, ray_address=_ray_target(ray, ray_address)
    )
    typer.echo(report.markdown)
    typer.echo(f"wrote {out}/results.md, attempts.parquet, summary.parquet and plots/")


def register(app: typer.Typer) -> None:
    """Add ``care query``, ``care replan``, ``care eval`` and ``care run`` to ``app``."""
    app.command("query")(query)
    app.command("replan")(replan)
    app.command("eval")(eval_)
    app.command("run")(run)


def run(
    recording: Annotated[
        Path | None,
        typer.Argument(
            help="Recording or dataset directory with ground truth; default the bundled sample."
        ),
    ] = None,
    out: Annotated[Path, typer.Option(help="Output directory: stores, .rrd files, tables.")] = Path(
        "out"
    ),
    attempts: Annotated[int, typer.Option(help="Attempts per query (first + replans).")] = 2,
    seeds: Annotated[int, typer.Option(help="Seeds of the random strategies.")] = 10,
    workers: Annotated[
        int, typer.Option(help="Local processes of the evaluation (0: one per CPU).")
    ] = 0,
    ray: RayOpt = False,
    ray_address: RayAddressOpt = None,
    rrd_ingest: Annotated[
        bool, typer.Option(help="Also write <name>.ingest.rrd (camera, depth, map building up).")
    ] = True,
    rrd_class: Annotated[
        str | None,
        typer.Option(
            "--rrd-class",
            help="Class of the grid recording's confidence layer (default: each query class).",
        ),
    ] = None,
) -> None:
    """The main job: ingest, fuse both maps, evaluate every strategy; print the table."""
    from evaluate.job import EvalConfig
    from evaluate.pipeline import RunConfig, run_all

    config = RunConfig(
        evaluation=EvalConfig(attempts=attempts, seeds=seeds),
        workers=workers or None,
        ray_address=_ray_target(ray, ray_address),
        rrd_ingest=rrd_ingest,
        rrd_class=rrd_class,
    )
    result = run_all(recording, out, config)
    md = result.report.markdown
    typer.echo(md.split("## 95% bootstrap")[0].rstrip())
    typer.echo(f"\nfull report: {out / 'eval' / 'results.md'}")
    typer.echo(f"open the maps and every decision in Rerun:\n  {result.rerun_command()}")
