"""Does looking again where the map is unsure pay? ``care explore``'s views on the sample world.

For each Matterport-like scene (:data:`care_maps.world.presets.WorldPreset.MATTERPORT_LIKE`): record
the exploration, ingest it with the ``labels`` perception and fuse the grid ("before").
Then three ways to spend the same budget of new views (as many as ``care explore``
proposes, at most ``--views``):

- ``explore``: the views :func:`care_maps.query.explore_store.explore_store` proposes (no ground
  truth: the map's own measures);
- ``random``: viewpoints drawn uniformly from the same reachable free space, facing a
  uniform heading, looking at the height of the map's objects ``near_range`` ahead;
- ``top_confidence``: views chosen by the same viewpoint chooser, but looking at each
  object class's max-confidence candidate (weighted by its confidence): checking the
  answers a robot would try first.

Each set of views is rendered by the world's renderer at the recording's resolution,
encoded by the same perception model (stamps after the recording's, so its per-view draws
are fresh) and appended to a copy of the "before" store as one more run
(:func:`care_maps.ingest.runs.append_frames`, what ``care ingest --append`` does with a
recording), and the grid grows by the new views alone (:mod:`care_maps.fuse.grid_state`),
in the map frame the views were chosen in: the loop a robot closes. Every store is evaluated
on the same grid queries (class protocol, per room, ``care eval``'s success rule, walks from
the recording's first pose): the first attempt (max confidence), two attempts of max
confidence, and their SPL (:mod:`care_maps.evaluate.spl`). Comparisons are paired over the same queries with scenes as the units (queries
of one scene share a map): the scene-level sign-flip test of
:mod:`care_maps.evaluate.scene_test`, its inverted 95% interval, Holm over the scene p-values of
the five comparisons of a table, and the equivalence test within
:data:`~care_maps.evaluate.scene_test.EQUIVALENCE_MARGIN` (Holm alike); a row reads as
:func:`care_maps.evaluate.report.preregistered.reading` says (a difference only from its Holm p,
"within +-3 points" only from the equivalence test, else "not shown to differ").

    python -m care_maps.research.explore OUT [--scenes 40] [--views 8] [--seed 20]
"""

from __future__ import annotations

import argparse
import math
import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.encoders import EncoderOptions, make_encoder
from care_maps.core.encoders.base import RecordingContext
from care_maps.core.errors import CareError
from care_maps.core.maps import MapKind
from care_maps.core.outputs import remove_path
from care_maps.core.store import Store
from care_maps.core.vocab import STRUCTURE_NAMES
from care_maps.evaluate.job import EvalConfig, Scene, evaluate_scene
from care_maps.evaluate.paired import compare, comparison_rng
from care_maps.evaluate.report.paired import INTERVAL_NOTE, difference_text
from care_maps.evaluate.report.preregistered import with_holm
from care_maps.evaluate.scene_test import (
    EQUIVALENCE_MARGIN,
    EXACT_MAX_SCENES,
    N_SIGN_FLIPS,
)
from care_maps.evaluate.spl import episode_paths, spl
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.runs import append_frames, link_or_copy
from care_maps.query.confidence import log_confidence
from care_maps.query.explore import (
    ExploreConfig,
    Viewpoint,
    cell_uncertainty,
    look_at,
    object_cells,
)
from care_maps.query.explore_store import ExploreInputs, read_inputs
from care_maps.query.map import CandidateMap
from care_maps.replan.strategies import StrategyName
from care_maps.runtime.execution import Execution
from care_maps.world.presets import PRESETS, WorldPreset
from care_maps.world.record import make_recording, scene_seed
from care_maps.world.render import RenderConfig, Renderer
from care_maps.world.scene import SceneConfig, generate_scene

__all__ = [
    "PAIRS",
    "Condition",
    "ExperimentConfig",
    "comparison_lines",
    "comparison_rows",
    "main",
    "random_views",
    "run_experiment",
    "top_confidence_values",
]


class Condition(StrEnum):
    """The maps compared: the recording alone, and with each set of new views."""

    BEFORE = "before"
    EXPLORE = "explore"
    RANDOM = "random"
    TOP_CONFIDENCE = "top_confidence"


PAIRS: tuple[tuple[Condition, Condition], ...] = (
    (Condition.EXPLORE, Condition.BEFORE),
    (Condition.RANDOM, Condition.BEFORE),
    (Condition.TOP_CONFIDENCE, Condition.BEFORE),
    (Condition.EXPLORE, Condition.RANDOM),
    (Condition.EXPLORE, Condition.TOP_CONFIDENCE),
)
"""The comparisons (A, B) of each table: one Holm family."""


@dataclass(frozen=True)
class ExperimentConfig:
    """The scenes and the budget of the experiment."""

    scenes: int = 40
    """Matterport-like scenes: about 2,700 grid queries, for 95% intervals of about +-2
    points (``docs/explore.md``)."""
    seed: int = 20
    """Dataset seed (scene i: :func:`care_maps.world.record.scene_seed`); 20 is the preset's own."""
    views: int = ExploreConfig.views
    """Budget of new views per scene (each condition gets as many as explore proposes)."""
    width: int = 160
    """Image width of the recording and the new views."""
    height: int = 120
    """Image height."""
    rooms: int | None = None
    """Rooms per scene (default drawn from 2 to 5)."""
    explore: ExploreConfig = field(default_factory=ExploreConfig)
    """The proposal settings (``views`` replaced by the budget)."""


def top_confidence_values(cmap: CandidateMap) -> np.ndarray:
    """(N,) each object class's max-confidence cell, valued at its confidence (0 elsewhere)."""
    values = np.zeros(cmap.num_candidates)
    keep = np.flatnonzero(object_cells(cmap))
    classes = [i for i, n in enumerate(cmap.vocabulary) if n.strip().lower() not in STRUCTURE_NAMES]
    if not len(keep):
        return values
    for lo in range(0, len(classes), 32):
        rows = log_confidence(cmap, np.array(classes[lo : lo + 32]))[:, keep]
        best = np.argmax(rows, axis=1)
        conf = np.exp(rows[np.arange(len(rows)), best].astype(np.float64))
        np.maximum.at(values, keep[best], conf)
    return values


def random_views(
    inputs: ExploreInputs, count: int, config: ExploreConfig, rng: np.random.Generator
) -> list[Viewpoint]:
    """``count`` viewpoints uniform over the cells a view may stand on, uniform headings,
    each camera looking ``near_range`` ahead at the median height of the map's objects."""
    ix, iy = np.nonzero(inputs.stand)
    if not len(ix) or count < 1:
        return []
    pick = rng.choice(len(ix), size=count, replace=len(ix) < count)
    size, (ox, oy) = inputs.layout.cell_size, inputs.layout.origin
    objects = object_cells(inputs.cmap)
    z = float(np.median(inputs.cmap.positions[objects, 2])) if objects.any() else 0.5
    out = []
    for i, yaw in zip(pick, rng.uniform(-math.pi, math.pi, count), strict=True):
        x, y = ox + (ix[i] + 0.5) * size, oy + (iy[i] + 0.5) * size
        target = (x + config.near_range * math.cos(yaw), y + config.near_range * math.sin(yaw), z)
        camera = look_at([x, y, inputs.camera_height], target)
        out.append(Viewpoint((x, y), float(yaw), camera, target, -1, 0.0, 0))
    return out


def _record(out: Path, index: int, config: ExperimentConfig) -> tuple[Path, SceneConfig]:
    """The scene's recording (made once; kept for a re-run)."""
    world = PRESETS[WorldPreset.MATTERPORT_LIKE]
    scene = SceneConfig(
        seed=scene_seed(config.seed, index), num_rooms=config.rooms, **world.scene_values()
    )
    path = out / "dataset" / f"scene_{index:03d}.mcap"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        render = RenderConfig(width=config.width, height=config.height, threads=1)
        make_recording(path, scene, render, perception=world.as_json()["perception"])
    return path, scene


def _with_views(
    before: Path, out: Path, recording: Path, renderer: Renderer, views: list[Viewpoint]
) -> None:
    """A copy of store ``before`` (with its grid) at ``out``, ``views`` rendered, encoded and
    appended to it as one more run."""
    remove_path(out)
    # linked, not copied: every later write to a store is a new file renamed into place
    shutil.copytree(before, out, copy_function=link_or_copy)
    old = Store(out)
    world_from_map = np.linalg.inv(old.map_frame.map_from_world)
    stamps = old.views(["stamp_ns"]).column("stamp_ns").to_numpy()
    step = round(1e9 / RenderConfig.fps)
    frames = [
        renderer.render(world_from_map @ v.camera, int(stamps.max()) + (i + 1) * step)
        for i, v in enumerate(views)
    ]
    encoder = make_encoder("labels", EncoderOptions())
    encoder.prepare(RecordingContext(recording, tuple(old.meta.label_names)))
    features: np.ndarray | list[np.ndarray] = encoder.encode_views(frames) if frames else []
    append_frames(out, frames, features, name=out.name, fingerprint=f"{out.name}-{len(frames)}")


def _appended(store: Path) -> bool:
    """Whether ``store`` holds its new views already (a run appended to the recording's)."""
    try:
        return len(Store(store).meta.runs) == 2
    except CareError:
        return False


def _outcomes(store: Path, name: str, recording: Path) -> dict[tuple, tuple[float, float, float]]:
    """(scene, room, class) -> (first attempt succeeded, two attempts of max confidence
    succeeded, their SPL)."""
    config = EvalConfig(
        maps=(MapKind.GRID,),
        strategies=(StrategyName.NO_REPLAN, StrategyName.MAX_CONFIDENCE),
        attempts=2,
        seeds=1,
        bootstrap=0,
    )
    rows = evaluate_scene(Scene(name, store, recording), config).to_pylist()
    out: dict[tuple, list[bool]] = {}
    walks: dict[tuple, list[tuple[bool, float, float, float]]] = {}
    for r in rows:
        key = (r["scene"], r["unit"], r["query"])
        got = out.setdefault(key, [False, False])
        if r["strategy"] == StrategyName.NO_REPLAN:
            got[0] |= bool(r["success"])
        else:
            got[1] |= bool(r["success"])
            walks.setdefault(key, []).append(
                (bool(r["success"]), r["distance"], r["walked"], r["shortest"])
            )
    return {k: (float(a), float(b), _spl(walks.get(k, []))) for k, (a, b) in out.items()}


def _spl(attempts: Sequence[tuple[bool, float, float, float]]) -> float:
    """SPL of one episode's attempts ``(success, leg, walked so far, shortest)``: solved at a
    goal the robot reached, over the path it walked (:func:`care_maps.evaluate.spl.spl`)."""
    if not attempts:
        return float("nan")
    success, leg, walked, shortest = (
        np.array(column, np.float64) for column in zip(*attempts, strict=True)
    )
    _, solved = episode_paths(leg[None], success[None], np.ones((1, len(leg)), bool))
    return float(spl(solved, shortest[:1], walked[-1:])[0])


def _scene(out: Path, index: int, config: ExperimentConfig) -> tuple[dict, dict]:
    """Every condition's outcomes for one scene, and the views each got."""
    recording, scene_config = _record(out, index, config)
    name = recording.stem
    stores = out / "stores" / name
    before = stores / Condition.BEFORE
    run = Execution(progress=False, workers=1)
    run_ingest(recording, before, IngestConfig(encoder="labels"), run=run)
    grid = GridConfig(stride=2)
    build_grid(before, grid, run=run)
    settings = replace(config.explore, views=config.views)
    inputs = read_inputs(before, settings)
    explore = inputs.choose(cell_uncertainty(inputs.cmap, settings), settings)
    budget = len(explore)
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, index, 7]))
    chosen = {
        Condition.EXPLORE: explore,
        Condition.RANDOM: random_views(inputs, budget, settings, rng),
        Condition.TOP_CONFIDENCE: inputs.choose(
            top_confidence_values(inputs.cmap), replace(settings, views=budget)
        ),
    }
    renderer = Renderer(
        generate_scene(scene_config),
        RenderConfig(width=config.width, height=config.height, threads=1),
    )
    outcomes = {Condition.BEFORE: _outcomes(before, name, recording)}
    for condition, views in chosen.items():
        store = stores / f"{condition}-{config.views}"
        if not _appended(store):  # a re-run resumes where the views were added
            _with_views(before, store, recording, renderer, views)
        build_grid(store, grid, run=run)  # grown by the new views (current: nothing to do)
        outcomes[condition] = _outcomes(store, name, recording)
    return outcomes, {c: len(v) for c, v in chosen.items()}


def comparison_rows(
    outcomes: Mapping[Condition, np.ndarray],
    scene: np.ndarray,
    *,
    seed: int,
    pairs: Sequence[tuple[Condition, Condition]] = PAIRS,
) -> list[dict[str, Any]]:
    """One row per pair ``(A, B)`` of ``outcomes`` (per-query success, aligned; ``scene``:
    each query's scene), as :func:`care_maps.evaluate.report.preregistered.reading` reads rows:
    rates, difference and its 95% interval in points, the discordant queries, the scene-level
    sign-flip p and equivalence p (:func:`care_maps.evaluate.scene_test.scene_signflip`), both
    Holm-corrected over ``pairs`` (one family), whether the family's scenes can reject at all,
    and the reading."""
    rows: list[dict[str, Any]] = []
    for a, b in pairs:
        name = f"{a} vs {b}"
        res = compare(outcomes[a], outcomes[b], rng=comparison_rng(seed, name), groups=scene)
        test = res.scene
        assert test is not None  # groups given: the scene test always runs
        rows.append(
            {
                "comparison": name,
                "rate_a": 100 * res.rate_a,
                "rate_b": 100 * res.rate_b,
                "diff": 100 * res.diff,
                "lo": 100 * res.lo,
                "hi": 100 * res.hi,
                "only_a": res.only_a,
                "only_b": res.only_b,
                "binary": bool(
                    np.isin(outcomes[a], (0.0, 1.0)).all()
                    and np.isin(outcomes[b], (0.0, 1.0)).all()
                ),
                "scenes": test.scenes,
                "effective_scenes": test.effective,
                "scene_p": test.p_value,
                "scene_mc_error": test.mc_error,
                "scene_min_p": test.min_p,
                "equivalence_p": test.equivalence_p,
            }
        )
    return with_holm(rows, ())


def comparison_lines(rows: Sequence[dict[str, Any]]) -> list[str]:
    """:func:`comparison_rows` as a Markdown table (a Holm p of a family its scenes cannot
    reject prints as "–"; a Monte Carlo scene p with its standard error)."""
    lines = [
        "| comparison | A % | B % | A - B, points [95% CI] | only A / only B | scene p "
        f"| Holm p | equivalence Holm p (±{100 * EQUIVALENCE_MARGIN:.0f}) | reading |",
        "| --- | ---: | ---: | --- | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in rows:
        scene_p = f"{r['scene_p']:.3g}"
        if r["scene_mc_error"] > 0:
            scene_p += f" ±{r['scene_mc_error']:.1g}"
        holm_p, equivalence = (
            (f"{r['holm_p']:.3g}", f"{r['holm_equivalence_p']:.3g}")
            if r["family_can_reject"]
            else ("–", "–")
        )
        only = f"{r['only_a']:.0f} / {r['only_b']:.0f}" if r.get("binary", True) else "–"
        lines.append(
            f"| {r['comparison']} | {r['rate_a']:.1f} | {r['rate_b']:.1f} "
            f"| {difference_text(r)} | {only} | {scene_p} "
            f"| {holm_p} | {equivalence} | {r['reading']} |"
        )
    return lines


def run_experiment(out: Path, config: ExperimentConfig | None = None) -> str:
    """Run every scene under ``out`` (recordings and stores kept: a re-run resumes) and
    return the report (Markdown)."""
    config = config or ExperimentConfig()
    start = time.perf_counter()
    outcomes: dict[Condition, dict] = {c: {} for c in Condition}
    budgets = []
    for index in range(config.scenes):
        scene_outcomes, budget = _scene(Path(out), index, config)
        budgets.append(budget[Condition.EXPLORE])
        for condition, found in scene_outcomes.items():
            outcomes[condition].update(found)
    keys = sorted(set.intersection(*(set(v) for v in outcomes.values())))
    scene = np.array([k[0] for k in keys])
    lines = [
        f"{config.scenes} Matterport-like scenes (seed {config.seed}, {config.width}x"
        f"{config.height}), {len(keys)} grid queries (class protocol, per room); new views "
        f"per scene: {', '.join(map(str, budgets))} (budget {config.views})",
        "",
    ]
    patterns = (
        "every sign pattern"
        if len(np.unique(scene)) <= EXACT_MAX_SCENES
        else f"{N_SIGN_FLIPS:,} random sign patterns"
    )
    lines += [
        f"Paired over the same queries; {INTERVAL_NOTE} ({patterns}); Holm over the "
        f"{len(PAIRS)} scene p-values of each table; equivalence: two one-sided sign-flip tests "
        f"at ±{100 * EQUIVALENCE_MARGIN:.0f} points, Holm alike. A: the first condition named.",
        "",
    ]
    tables = (
        (0, "first attempt"),
        (1, "two attempts, max confidence"),
        (2, "SPL of two attempts, max confidence (points of SPL)"),
    )
    for column, title in tables:
        result = {c: np.array([outcomes[c][k][column] for k in keys], float) for c in Condition}
        known = np.all([np.isfinite(v) for v in result.values()], axis=0)  # SPL: walks known
        if not known.all():
            title += f" ({int(known.sum())} queries with a known walk)"
        result = {c: v[known] for c, v in result.items()}
        rows = comparison_rows(result, scene[known], seed=config.seed)
        lines += [f"## {title}", *comparison_lines(rows), ""]
    lines.append(f"run time: {time.perf_counter() - start:.0f} s")
    return "\n".join(lines)


def main() -> None:
    """The command line: ``python -m care_maps.research.explore`` or ``scripts/explore.py``."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", type=Path, help="Directory of the recordings and stores.")
    defaults = ExperimentConfig()
    parser.add_argument("--scenes", type=int, default=defaults.scenes)
    parser.add_argument("--views", type=int, default=defaults.views)
    parser.add_argument("--seed", type=int, default=defaults.seed)
    parser.add_argument("--width", type=int, default=defaults.width)
    parser.add_argument("--height", type=int, default=defaults.height)
    args = parser.parse_args()
    from threadpoolctl import threadpool_limits

    config = ExperimentConfig(
        scenes=args.scenes, views=args.views, seed=args.seed, width=args.width, height=args.height
    )
    with threadpool_limits(1):
        print(run_experiment(args.out, config))


if __name__ == "__main__":
    main()
