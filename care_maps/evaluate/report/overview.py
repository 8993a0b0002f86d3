"""What ``care run`` prints first: per map, one small table of the success (and SPL, where
the queries walked) of no replan, max confidence, the pre-registered CARe rules
(:data:`~care_maps.evaluate.report.preregistered.PAPER_SETTINGS`) and the oracle, a column
group per protocol. Every other rule, k, interval and test is in ``results.md``; this adds
nothing to it, and a note that holds for every cell (no interval below
:data:`~care_maps.evaluate.scene_test.MIN_SCENES` scenes) is said once, under its table."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from care_maps.evaluate.config import NO_CRITERION
from care_maps.evaluate.report.preregistered import MAX_CONF, PAPER_SETTINGS, Rule, _label
from care_maps.evaluate.report.rates import MAP_TITLES
from care_maps.evaluate.scene_test import MIN_SCENES
from care_maps.replan.strategies import StrategyName

__all__ = ["overview_markdown", "overview_rows", "overview_rules"]

NO_REPLAN: Rule = (StrategyName.NO_REPLAN, NO_CRITERION, 0)
ORACLE: Rule = (StrategyName.ORACLE, NO_CRITERION, 0)


def overview_rules(
    kind: str, settings: dict[str, tuple[Rule, ...]] | None = None
) -> tuple[Rule, ...]:
    """The rows of a map's overview, in order: no replan, max confidence, the pre-registered
    rules of ``kind`` (``settings``, default :data:`PAPER_SETTINGS`), the oracle."""
    settings = PAPER_SETTINGS if settings is None else settings
    return (NO_REPLAN, MAX_CONF, *settings.get(kind, ()), ORACLE)


def _finite(value: float | None) -> bool:
    return value is not None and not np.isnan(value)


def overview_rows(
    summary: pa.Table, scenes: pa.Table, settings: dict[str, tuple[Rule, ...]] | None = None
) -> list[dict]:
    """One row per (map, protocol, rule of :func:`overview_rules`) that ``summary`` measured
    (its ``rate``, ``lo``, ``hi``, ``spl`` and ``n_queries``; closed forms left out), with
    ``rule`` (its label) and ``scenes`` (the scenes of its map and protocol in ``scenes``,
    the per-scene summary)."""
    measured = {
        (r["map"], r["protocol"], r["strategy"], r["criterion"], r["k"]): r
        for r in summary.to_pylist()
        if not r["closed_form"]
    }
    seen: dict[tuple[str, str], set[str]] = {}
    for r in scenes.select(["map", "protocol", "scene"]).to_pylist():
        seen.setdefault((r["map"], r["protocol"]), set()).add(r["scene"])
    rows = []
    for kind, protocol in sorted({key[:2] for key in measured}):
        for rule in overview_rules(kind, settings):
            r = measured.get((kind, protocol, *rule))
            if r is None:
                continue
            rows.append(
                {
                    "map": kind, "protocol": protocol, "strategy": rule[0],
                    "criterion": rule[1], "k": rule[2], "rule": _label(rule),
                    "rate": r["rate"], "lo": r["lo"], "hi": r["hi"], "spl": r.get("spl"),
                    "n_queries": r["n_queries"], "scenes": len(seen.get((kind, protocol), ())),
                }
            )  # fmt: skip
    return rows


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def _table(head: list[str], body: list[list[str]]) -> list[str]:
    """A markdown table padded to its columns' widths (the first left, the others right)."""
    widths = [max(len(row[i]) for row in (head, *body)) for i in range(len(head))]

    def line(cells: list[str]) -> str:
        padded = [
            c.ljust(w) if i == 0 else c.rjust(w)
            for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        ]
        return "| " + " | ".join(padded) + " |"

    rule = ["-" * widths[0]] + ["-" * (w - 1) + ":" for w in widths[1:]]
    return [line(head), "|" + "|".join(f" {r} " for r in rule) + "|", *(line(r) for r in body)]


def overview_markdown(rows: list[dict]) -> str:
    """Per map: a title (protocols, their queries, the scenes), the table (a row per rule,
    a column group per protocol: success, its 95% interval where any row has one, SPL where
    any query walked) and, once under it, what holds for every cell."""
    out: list[str] = []
    for kind in dict.fromkeys(r["map"] for r in rows):
        mine = [r for r in rows if r["map"] == kind]
        protocols = {r["protocol"]: r for r in mine}  # one row of each: its queries, scenes
        with_ci = any(_finite(r["lo"]) and _finite(r["hi"]) for r in mine)
        with_spl = any(_finite(r["spl"]) for r in mine)
        scenes = max(r["scenes"] for r in mine)
        what = "success and SPL (%)" if with_spl else "success (%)"
        queries = ", ".join(f"{p} {r['n_queries']}" for p, r in protocols.items())
        title = MAP_TITLES.get(kind, kind).split(":")[0]
        out.append(f"{title}: {what}, {_plural(scenes, 'scene')}; queries: {queries}")
        head = ["rule"]
        for p in protocols:
            head += [
                f"{p} success",
                *(["95% CI"] if with_ci else []),
                *(["SPL"] if with_spl else []),
            ]
        cells = {(r["protocol"], r["rule"]): r for r in mine}
        body = []
        for label in dict.fromkeys(r["rule"] for r in mine):
            line = [label]
            for p in protocols:
                r = cells.get((p, label))
                if r is None:
                    line += [""] * (1 + with_ci + with_spl)
                    continue
                line.append(f"{r['rate']:.1f}")
                if with_ci:
                    ok = _finite(r["lo"]) and _finite(r["hi"])
                    line.append(f"[{r['lo']:.1f}, {r['hi']:.1f}]" if ok else "–")
                if with_spl:
                    line.append(f"{r['spl']:.1f}" if _finite(r["spl"]) else "–")
            body.append(line)
        out += _table(head, body)
        if not with_ci and scenes < MIN_SCENES:
            out.append(
                f"No 95% intervals: {_plural(scenes, 'scene')}; an interval holds from "
                f"{MIN_SCENES} scenes."
            )
        elif not with_ci:
            out.append("No 95% intervals (results.md says why).")
        elif any(not (_finite(r["lo"]) and _finite(r["hi"])) for r in mine):
            out.append(f"–: no interval (fewer than {MIN_SCENES} effective scenes).")
        out.append("")
    return "\n".join(out)
