"""Rerun logging of the evaluation: every decision of a query, and the success rates per k.

On the ``query`` timeline (one step per query), under ``world/eval/<map>/``: the top ranked
candidates coloured by confidence, the first attempt (green on success, red on failure), and
each strategy's next choice labelled with the measure that chose it and its outcome; a
``TextLog`` line per query says the same in words. On the ``k`` timeline, the success rate of
every (strategy, criterion) as a scalar, so the viewer plots the paper's tables.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import rerun as rr

from care.viz import open_recording
from query.confidence import confidence
from query.map import CandidateMap

__all__ = ["EVAL_ENTITY", "QUERY_TIMELINE", "log_evaluation", "write_evaluation_rrd"]

EVAL_ENTITY = "world/eval"
SCALAR_ENTITY = "eval/success"
QUERY_TIMELINE = "query"
K_TIMELINE = "k"
GREEN, RED, GREY = (40, 200, 80), (230, 50, 50), (150, 150, 150)


def _viridis(values: np.ndarray) -> np.ndarray:
    import matplotlib as mpl

    v = np.asarray(values, float)
    span = np.ptp(v) if len(v) else 0.0
    v = (v - v.min()) / span if span > 0 else np.zeros_like(v)
    return (mpl.colormaps["viridis"](v)[:, :3] * 255).astype(np.uint8)


def _choice_label(r: dict) -> str:
    """``min_stderr/conf k=4: 0.012 ok`` for one replan choice."""
    rule = r["strategy"] if r["criterion"] == "-" else f"{r['strategy']}/{r['criterion'][:4]}"
    k = f" k={r['k']}" if r["k"] else ""
    outcome = "ok" if r["success"] else "fail"
    return f"{rule}{k}: {r['value']:.3g} {outcome}{' (fallback)' if r['fell_back'] else ''}"


def _log_query(rec: rr.RecordingStream, cmap: CandidateMap, rows: list[dict], top: int) -> str:
    """Log one query's ranking and decisions; returns its one-line description.

    The ranked points are the scene's best by confidence (labelled ``scene #r``); the
    evaluation ranks within each room, so a room's first attempt need not be scene #1.
    """
    kind, target = rows[0]["map"], rows[0]["target"]
    base = f"{EVAL_ENTITY}/{kind}"
    y = cmap.class_id(target)
    conf = confidence(cmap, np.array([y]))[0]
    ranked = np.argsort(-conf, kind="stable")[:top]
    rec.log(
        f"{base}/ranked",
        rr.Points3D(
            cmap.positions[ranked], colors=_viridis(conf[ranked]), radii=0.06,
            labels=[f"scene #{r + 1} {conf[c]:.2f}" for r, c in enumerate(ranked)],
        ),
    )  # fmt: skip
    first = next(r for r in rows if r["attempt"] == 1)  # the same for every strategy
    words = [f"{rows[0]['query']} ({rows[0]['unit']}): first #{first['candidate']} "]
    words.append("succeeded" if first["success"] else "failed")
    if first["candidate"] >= 0:
        rec.log(
            f"{base}/first",
            rr.Points3D(
                cmap.positions[[first["candidate"]]], colors=[GREEN if first["success"] else RED],
                radii=0.12, labels=[f"first: conf {first['confidence']:.2f}"],
            ),
        )  # fmt: skip
    seconds = [r for r in rows if r["attempt"] == 2 and r["candidate"] >= 0]
    if seconds:
        labels = [_choice_label(r) for r in seconds]
        rec.log(
            f"{base}/replan",
            rr.Points3D(
                cmap.positions[[r["candidate"] for r in seconds]],
                colors=[GREEN if r["success"] else RED for r in seconds], radii=0.09, labels=labels,
            ),
        )  # fmt: skip
        good = sorted({r["strategy"] for r in seconds if r["success"]})
        words.append(f"; replans that succeed: {', '.join(good) or 'none'}")
    else:
        rec.log(f"{base}/replan", rr.Clear(recursive=False))
    return "".join(words)


def log_evaluation(
    rec: rr.RecordingStream,
    attempts: pa.Table,
    summary: pa.Table,
    maps: dict[str, CandidateMap],
    *,
    scene: str,
    max_queries: int = 40,
    top: int = 10,
) -> int:
    """Log the decisions of up to ``max_queries`` queries of ``scene`` and every success rate.

    Only deterministic strategies and the first seed of the random ones are drawn (at every
    criterion and k). Returns the number of queries logged.
    """
    for kind, cmap in maps.items():
        rec.log(
            f"{EVAL_ENTITY}/{kind}/candidates",
            rr.Points3D(cmap.positions, colors=[GREY], radii=0.02),
            static=True,
        )
    mine = attempts.filter(
        pc.and_(
            pc.equal(attempts.column("scene"), scene), pc.less_equal(attempts.column("seed"), 0)
        )
    )
    mine = mine.filter(pc.is_in(mine.column("map"), pa.array(list(maps))))
    groups: dict[tuple, list[dict]] = {}
    for row in mine.to_pylist():
        groups.setdefault((row["map"], row["protocol"], row["unit"], row["query"]), []).append(row)
    for step, (key, rows) in enumerate(list(groups.items())[:max_queries]):
        rec.set_time(QUERY_TIMELINE, sequence=step)
        text = _log_query(rec, maps[key[0]], rows, top)
        rec.log("eval/log", rr.TextLog(f"[{key[0]}/{key[1]}] {text}"))
    rates = summary.to_pylist()
    ks_of = {m: sorted({x["k"] for x in rates if x["map"] == m and x["k"]}) for m in maps}
    for r in rates:
        name = r["strategy"].replace(" (expected)", "_expected")
        path = f"{SCALAR_ENTITY}/{r['map']}/{r['protocol']}/{name}/{r['criterion'].replace('-', 'none')}"
        for k in [r["k"]] if r["k"] else ks_of.get(r["map"], []):
            rec.set_time(K_TIMELINE, sequence=int(k))
            rec.log(path, rr.Scalars([r["rate"]]))
    rec.reset_time()
    return min(len(groups), max_queries)


def write_evaluation_rrd(
    rrd: Path,
    attempts: pa.Table,
    summary: pa.Table,
    maps: dict[str, CandidateMap],
    *,
    scene: str,
    rec: rr.RecordingStream | None = None,
) -> Path:
    """Log :func:`log_evaluation` into ``rec``, or a new ``rrd`` file (``rerun rrd``)."""
    own = rec is None
    rec = rec or open_recording("care_eval", rrd)
    log_evaluation(rec, attempts, summary, maps, scene=scene)
    if own:
        rec.flush()
        rec.disconnect()
    return Path(rrd)
