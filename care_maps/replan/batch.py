"""Queries plus replans as one batch job, for maps without ground truth.

Given many queries (class names or free text, each optionally with places the robot has
already searched), :func:`plan_batch` answers all of them over one loaded map: the ranked
candidates with their measures, and for every strategy and selection criterion the sequence of
attempts it would make if every earlier one failed. Text resolves exactly as in ``care query``
(:func:`care_maps.query.openvocab.open_queries`, the free texts embedded in one call); the episodes are :func:`care_maps.replan.attempts.run_attempts`
with no success anywhere, vectorised over the queries, so every row equals what repeated
:func:`care_maps.replan.attempts.next_goal` calls answer (random strategies draw from one generator
seeded by ``BatchConfig.seed``: reproducible, but not the draws of separate calls).

The result is one long Arrow table (:data:`BATCH_SCHEMA`): a row per (query, ``ranking``
position) and per (query, strategy, criterion, attempt). With goals, its schema metadata
names their frame (:data:`care_maps.core.keys.GOAL_FRAME_KEY`): ``goal_x``, ``goal_y`` and ``goal_yaw``
are in ``frame_id`` (the goal's height: 0 for an approach point, else the object's ``z``),
and ``world_from_frame`` gives each goal in the recording's world frame.

With a :class:`care_maps.query.paths.Travel` (the shortest paths from the batch's one start, as
``care query`` chooses it: ``--from`` or the recording's first pose), each row also says how
far the robot drives from that start to the goal (``distance``) and whether it can get
there at all (``reachable``): one search for the whole batch, every row a look-up, so a
batch of thousands of queries pays for paths once. The start is in the metadata
(``path_start``, map x, y; null without paths).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from care_maps.core.errors import ReplanError
from care_maps.core.keys import GOAL_FRAME_KEY
from care_maps.core.maps import MapKind
from care_maps.query.confidence import rank_by_confidence
from care_maps.query.goals import Goal, GoalMaker
from care_maps.query.map import MEASURES, REPLAN_COLUMNS, CandidateMap
from care_maps.query.openvocab import open_queries
from care_maps.query.paths import Travel
from care_maps.replan.attempts import (
    DEFAULT_EXCLUDE_RADIUS,
    ReplanConfig,
    candidates_near,
    run_attempts,
)
from care_maps.replan.strategies import CRITERIA, STRATEGIES

__all__ = [
    "BATCH_SCHEMA",
    "RANKING",
    "BatchConfig",
    "BatchQuery",
    "plan_batch",
    "read_queries",
]

RANKING = "ranking"
"""``strategy`` of the rows that list the max-confidence ranking (``attempt`` = rank)."""

BATCH_SCHEMA = pa.schema(
    [
        ("query_index", pa.int32()),
        ("query", pa.string()),
        ("target", pa.string()),
        ("method", pa.string()),
        ("strategy", pa.string()),
        ("criterion", pa.string()),
        ("k", pa.int32()),
        ("attempt", pa.int32()),
        ("candidate", pa.int64()),
        ("confidence", pa.float32()),
        ("entropy", pa.float32()),
        ("stderr", pa.float32()),
        ("pwkl", pa.float32()),
        ("num_views", pa.int32()),
        ("fell_back", pa.bool_()),
        ("set_size", pa.int64()),
        ("x", pa.float32()),
        ("y", pa.float32()),
        ("z", pa.float32()),
        ("goal_x", pa.float64()),
        ("goal_y", pa.float64()),
        ("goal_yaw", pa.float64()),
        ("goal_approach", pa.bool_()),
        ("distance", pa.float64()),
        ("reachable", pa.bool_()),
    ]
)
"""One row per listed candidate or attempt; ``candidate`` -1 where no attempt was left.
``distance``: metres along free space from the batch's start to the goal, null where the
goal is unreachable (or there are no paths: no grid, no start, no attempt); ``reachable``:
null where there are no paths or no attempt."""


@dataclass(frozen=True)
class BatchQuery:
    """One query of a batch: what to look for, and where the robot has already looked."""

    text: str
    visited_at: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class BatchConfig:
    """What every query of a batch is answered with."""

    strategies: tuple[str, ...] = tuple(
        s for s in STRATEGIES if not (STRATEGIES[s].needs_truth or STRATEGIES[s].travel)
    )
    """Replan strategies whose attempt sequences are listed (the oracle needs ground truth;
    the travel rules a walk from each attempt's goal to the next, which ``care eval`` plays)."""
    criteria: tuple[str, ...] = tuple(CRITERIA)
    k: int = ReplanConfig.k
    """Size parameter of the candidate sets."""
    attempts: int = 3
    """Attempts per sequence (the first and its replans)."""
    top: int = 10
    """Ranked candidates listed per query."""
    exclude_radius: float = DEFAULT_EXCLUDE_RADIUS
    """Grid: metres around a failed cell skipped later; also the radius of a visited place."""
    seed: int = ReplanConfig.seed
    """Seed of the random strategies' one generator."""
    chunk: int = 256
    """Queries played at once (bounds the (Q, N) confidence and availability arrays)."""

    def __post_init__(self) -> None:
        unknown = [s for s in self.strategies if s not in STRATEGIES]
        unknown += [c for c in self.criteria if c not in CRITERIA]
        if unknown:
            msg = (
                f"unknown strategy or criterion {', '.join(map(repr, unknown))}; strategies: "
                f"{', '.join(STRATEGIES)}; criteria: {', '.join(CRITERIA)}"
            )
            raise ReplanError(msg)
        if any(STRATEGIES[s].needs_truth for s in self.strategies):
            msg = "the oracle needs ground truth; a batch without it cannot list its attempts"
            raise ReplanError(msg)
        travel = [s for s in self.strategies if STRATEGIES[s].travel]
        if travel:
            msg = (
                f"{', '.join(travel)} trade their measure against travel from each attempt's "
                "goal to the next, which a batch does not walk; `care eval` plays them, "
                "`care replan --strategy` answers one query"
            )
            raise ReplanError(msg)
        if min(self.k, self.attempts, self.top, self.chunk) < 1:
            msg = "k, attempts, top and chunk must each be at least 1"
            raise ReplanError(msg)
        if not (np.isfinite(self.exclude_radius) and self.exclude_radius >= 0):
            msg = f"exclude radius must be a finite distance >= 0 m, got {self.exclude_radius}"
            raise ReplanError(msg)


def read_queries(path: Path) -> list[BatchQuery]:
    """Queries from a text file (one a line; blank lines and ``#`` comments skipped) or a
    ``.csv`` with a ``query`` column and an optional ``visited`` column of places
    ``x,y;x,y`` (metres, map frame)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        msg = f"{path}: cannot read the batch file ({err})"
        raise ReplanError(msg) from err
    if path.suffix.lower() != ".csv":
        lines = (ln.strip() for ln in text.splitlines())
        return [BatchQuery(ln) for ln in lines if ln and not ln.startswith("#")]
    rows = list(csv.DictReader(text.splitlines()))
    if not rows or "query" not in rows[0]:
        msg = f"{path}: a batch CSV needs a header with a 'query' column (and optionally 'visited')"
        raise ReplanError(msg)
    out = []
    for line, row in enumerate(rows, start=2):
        places = []
        for item in (row.get("visited") or "").split(";"):
            if not item.strip():
                continue
            try:
                x, y = (float(v) for v in item.split(","))
            except ValueError as err:
                msg = f"{path}, line {line}: visited {item!r} is not x,y in metres"
                raise ReplanError(msg) from err
            places.append((x, y))
        if not (row.get("query") or "").strip():
            msg = f"{path}, line {line}: empty query"
            raise ReplanError(msg)
        out.append(BatchQuery(row["query"].strip(), tuple(places)))
    return out


@dataclass(frozen=True)
class _Resolved:
    """The queries of one chunk as arrays: log-confidence, category ranks, searched places."""

    target: list[str]
    method: list[str]
    conf: np.ndarray
    """(Q, N) float32 log P_c of each query's target."""
    rank: np.ndarray | None
    searched: np.ndarray


def _resolve(cmap: CandidateMap, queries: Sequence[BatchQuery], config: BatchConfig) -> _Resolved:
    conf = np.empty((len(queries), cmap.num_candidates), np.float32)
    rank = np.empty(conf.shape, np.int16) if "category" in config.criteria else None
    searched = np.zeros(conf.shape, bool)
    unique = list(dict.fromkeys(q.text for q in queries))
    targets = dict(zip(unique, open_queries(cmap, unique), strict=True))
    for i, q in enumerate(queries):
        searched[i, candidates_near(cmap, np.array(q.visited_at), config.exclude_radius)] = True
    for text, target in targets.items():
        rows = [i for i, q in enumerate(queries) if q.text == text]
        conf[rows] = target.log_confidence()  # ranked as next_goal ranks: no ties at 1.0
        if rank is not None:
            rank[rows] = target.class_rank(limit=config.k)
    return _Resolved(
        [targets[q.text].match.names[0] for q in queries],
        [targets[q.text].match.method for q in queries],
        conf,
        rank,
        searched,
    )


def _rows(
    cmap: CandidateMap,
    goals: GoalMaker | None,
    cache: dict[int, Goal],
    candidate: np.ndarray,
    conf: np.ndarray,
    travel: Travel | None = None,
) -> dict[str, np.ndarray | pa.Array]:
    """The per-candidate columns of rows listing ``candidate`` (-1: none)."""
    c = np.maximum(candidate, 0)
    has = candidate >= 0
    cols: dict[str, np.ndarray | pa.Array] = {
        "candidate": candidate,
        "confidence": np.where(has, np.exp(conf), np.nan).astype(np.float32),
        **{m: np.where(has, cmap.column(m)[c], np.nan).astype(np.float32) for m in MEASURES},
        "num_views": np.where(has, cmap.num_views[c], 0).astype(np.int32),
        **{
            axis: np.where(has, cmap.positions[c, j], np.nan).astype(np.float32)
            for j, axis in enumerate("xyz")
        },
    }
    gx, gy, yaw = (np.full(len(c), np.nan) for _ in range(3))
    approach = np.zeros(len(c), bool)
    chosen: list[Goal] = []
    if goals is not None:
        for i, cand in enumerate(candidate):
            if cand < 0:
                continue
            goal = cache.get(int(cand))
            if goal is None:
                goal = cache[int(cand)] = goals.goal(cmap, int(cand))
            gx[i], gy[i], yaw[i] = goal.position[0], goal.position[1], goal.yaw
            approach[i] = goal.approach
            chosen.append(goal)
    cols.update(goal_x=gx, goal_y=gy, goal_yaw=yaw, goal_approach=approach)
    metres = np.full(len(c), np.inf)
    known = has & (travel is not None)
    if chosen and travel is not None:
        metres[has] = travel.distances(chosen)
    reach = np.isfinite(metres)
    cols["distance"] = pa.array(np.where(reach, metres, 0.0), pa.float64(), mask=~reach)
    cols["reachable"] = pa.array(reach, pa.bool_(), mask=~known)
    return cols


@dataclass(frozen=True)
class _Chunk:
    """One chunk of queries being answered, and how rows of it become table rows."""

    cmap: CandidateMap
    queries: Sequence[BatchQuery]
    first: int
    """Index of the chunk's first query in the whole batch."""
    res: _Resolved
    goals: GoalMaker | None
    cache: dict[int, Goal]
    travel: Travel | None = None

    def table(
        self,
        rows: np.ndarray,
        strategy: str,
        criterion: str | None,
        k: int,
        attempt: np.ndarray,
        cand: np.ndarray,
        fell: np.ndarray,
        size: np.ndarray,
    ) -> pa.Table:
        """Table rows for chunk-relative query ``rows`` listing candidates ``cand``."""
        n = len(cand)
        return pa.table(
            {
                "query_index": (rows + self.first).astype(np.int32),
                "query": [self.queries[i].text for i in rows],
                "target": [self.res.target[i] for i in rows],
                "method": [self.res.method[i] for i in rows],
                "strategy": [strategy] * n,
                "criterion": [criterion] * n,
                "k": np.full(n, k, np.int32),
                "attempt": attempt.astype(np.int32),
                **_rows(
                    self.cmap,
                    self.goals,
                    self.cache,
                    cand,
                    self.res.conf[rows, np.maximum(cand, 0)],
                    self.travel,
                ),
                "fell_back": fell,
                "set_size": size,
            },
            schema=BATCH_SCHEMA,
        )


def plan_batch(
    cmap: CandidateMap,
    queries: Sequence[BatchQuery],
    config: BatchConfig | None = None,
    *,
    goals: GoalMaker | None = None,
    travel: Travel | None = None,
    progress: bool = False,
) -> pa.Table:
    """Every query's ranking and every strategy's attempt sequence, as :data:`BATCH_SCHEMA`.

    ``travel``: the shortest paths from the batch's start over ``goals``' free space (one
    search, made by the caller), for each row's ``distance`` and ``reachable``."""
    from tqdm import tqdm

    config = config or BatchConfig()
    if goals is None or travel is None or travel.source is None:
        travel = None  # no paths: no grid, no start, or no free cell near it
    columns = {name: cmap.column(name) for name in REPLAN_COLUMNS}
    positions = cmap.positions if cmap.kind == MapKind.GRID else None
    radius = config.exclude_radius if cmap.kind == MapKind.GRID else 0.0
    rng = np.random.default_rng(config.seed)
    cache: dict[int, Goal] = {}
    parts: list[pa.Table] = []
    bar = tqdm(total=len(queries), desc="batch queries", unit="query", disable=not progress)
    for lo in range(0, len(queries), config.chunk):
        chunk = queries[lo : lo + config.chunk]
        res = _resolve(cmap, chunk, config)
        part = _Chunk(cmap, chunk, lo, res, goals, cache, travel)
        top = min(config.top, cmap.num_candidates)
        order = rank_by_confidence(res.conf)[:, :top]
        rows = np.repeat(np.arange(len(chunk)), top)
        parts.append(
            part.table(
                rows, RANKING, None, top, np.tile(np.arange(1, top + 1), len(chunk)),
                order.reshape(-1), np.zeros(len(rows), bool), np.zeros(len(rows), np.int64),
            )
        )  # fmt: skip
        rows = np.repeat(np.arange(len(chunk)), config.attempts)
        attempt = np.tile(np.arange(1, config.attempts + 1), len(chunk))
        for name in config.strategies:
            for criterion in config.criteria if STRATEGIES[name].uses_set else (None,):
                played = run_attempts(
                    name, res.conf, np.zeros(res.conf.shape, bool), columns,
                    criterion=criterion or "confidence", k=config.k, attempts=config.attempts,
                    rank=res.rank if criterion == "category" else None, positions=positions,
                    exclude_radius=radius, rng=rng, searched=res.searched,
                )  # fmt: skip
                parts.append(
                    part.table(
                        rows, name, criterion, config.k, attempt, played.candidate.reshape(-1),
                        played.fell_back.reshape(-1), played.set_size.reshape(-1),
                    )
                )  # fmt: skip
        bar.update(len(chunk))
    bar.close()
    table = pa.concat_tables(parts) if parts else BATCH_SCHEMA.empty_table()
    if goals is None:
        return table
    frame = {
        "frame_id": goals.frame_id,
        "world_frame": goals.world_frame,
        "world_from_frame": goals.world_from_frame().reshape(-1).tolist(),
        "path_start": None if travel is None else list(travel.start),
    }
    return table.replace_schema_metadata({GOAL_FRAME_KEY: json.dumps(frame).encode()})
