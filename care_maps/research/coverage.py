"""How often a 95% interval of a paired difference in success covers zero when the two
strategies do not differ, by number of scenes: the scene sign-flip interval
(:func:`care_maps.evaluate.scene_test.scene_signflip`), the scene-clustered percentile bootstrap and
the query (unclustered) percentile bootstrap (:func:`care_maps.evaluate.paired.paired_bootstrap_ci`).

The null simulation (:func:`simulate_null`) has clustered, heterogeneous scenes: each scene
draws its query count (uniform in ``QUERIES``), its base success probability (a Beta), and
its discordance (the chance that exactly one strategy succeeds, a Beta share of what the base
rate allows). Within a scene the pair ``(a, b)`` is exchangeable, ``P(1, 0) = P(0, 1)``, so
the true difference is zero in every scene. A share of queries (``FRACTIONAL``) is
seed-averaged: both sides are means over ``SEEDS`` draws of the scene's pair. With
``effect_sd > 0`` each scene also gets its own difference ``e_g`` (normal, clipped
symmetrically to what its discordance allows), zero only on average over scenes: the case
where queries of one scene share a true difference, which only a scene-level method sees.

The sign-flip column's rejection is ``p(0) <= alpha``; its coverage is that of the printed
interval where one is printed (:data:`care_maps.evaluate.scene_test.MIN_SCENES` scenes or more) and of
the inverted set (``p(0) > alpha``) where not. A bootstrap interval rejects where it leaves
out zero. The bootstraps are slow, so they run on the first ``bootstrap_simulations`` data
sets only (the same data as the sign-flip column's first runs).

    python -m care_maps.research.coverage [--simulations 2000] [--bootstrap-simulations 400]
        [--effect-sd 0] [--seed 0]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Sequence

import numpy as np

from care_maps.evaluate.paired import paired_bootstrap_ci
from care_maps.evaluate.scene_test import ALPHA, MIN_SCENES, N_SIGN_FLIPS, scene_signflip

__all__ = ["coverage_markdown", "coverage_table", "simulate_null"]

QUERIES = (10, 40)
"""Queries per scene: uniform integers in this closed range."""
BASE_BETA = (2.0, 2.0)
"""Beta parameters of a scene's base success probability."""
DISCORDANCE_BETA = (1.0, 3.0)
"""Beta parameters of a scene's discordance, as a share of the most its base rate allows."""
FRACTIONAL = 0.2
"""Share of queries whose outcomes are averaged over seeds (a random strategy)."""
SEEDS = 4
"""Seeds averaged for a fractional query."""
SCENES = (2, 4, 6, 8, 12, 20, 30)
"""Scene counts of the table."""
SIMULATIONS = 2000
"""Null data sets per scene count (sign-flip column)."""
BOOTSTRAP_SIMULATIONS = 400
"""Null data sets per scene count for the bootstrap columns (the first ones)."""
BOOTSTRAP_RESAMPLES = 2000
"""Resamples of each simulated bootstrap interval (the report uses 10,000; the percentile
interval's coverage hardly moves with more)."""
METHODS = {
    "signflip": "scene sign-flip (test inversion)",
    "cluster_bootstrap": "scene-clustered percentile bootstrap",
    "query_bootstrap": "query percentile bootstrap (unclustered)",
}
"""Method key: its name in the table."""


def simulate_null(
    rng: np.random.Generator,
    scenes: int,
    *,
    fractional: float = FRACTIONAL,
    seeds: int = SEEDS,
    effect_sd: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One null data set of ``scenes`` scenes: per-query ``(a, b, groups)``.

    Scene ``g``: ``n_g`` queries (uniform in :data:`QUERIES`), base success ``p_g`` (Beta
    :data:`BASE_BETA`), discordance ``q_g = u_g * 2 min(p_g, 1 - p_g)`` with ``u_g`` from Beta
    :data:`DISCORDANCE_BETA`, and the joint of one query's ``(a, b)``:
    ``P(1, 0) = (q_g + e_g) / 2``, ``P(0, 1) = (q_g - e_g) / 2``, ``P(1, 1) = p_g - q_g / 2``,
    ``P(0, 0) = 1 - p_g - q_g / 2``, with ``e_g = 0`` unless ``effect_sd > 0`` (then normal,
    clipped to ``[-q_g, q_g]``: symmetric about 0). Each query is, with probability
    ``fractional``, the mean over ``seeds`` independent draws of that joint (both sides), else
    one draw.
    """
    lo, hi = QUERIES
    counts = rng.integers(lo, hi + 1, scenes)
    base = rng.beta(*BASE_BETA, scenes)
    discord = rng.beta(*DISCORDANCE_BETA, scenes) * 2 * np.minimum(base, 1 - base)
    effect = np.zeros(scenes)
    if effect_sd > 0:
        effect = np.clip(rng.normal(0.0, effect_sd, scenes), -discord, discord)
    # cumulative P of (1, 0), (0, 1), (1, 1); (0, 0) is the rest
    cum = np.cumsum(
        np.stack([(discord + effect) / 2, (discord - effect) / 2, base - discord / 2], axis=1),
        axis=1,
    )
    groups = np.repeat(np.arange(scenes), counts)
    u = rng.random((len(groups), seeds))
    c = cum[groups][:, None, :]
    one_zero = u < c[..., 0]
    zero_one = (u >= c[..., 0]) & (u < c[..., 1])
    both = (u >= c[..., 1]) & (u < c[..., 2])
    a_draws = (one_zero | both).astype(np.float64)
    b_draws = (zero_one | both).astype(np.float64)
    averaged = rng.random(len(groups)) < fractional
    a = np.where(averaged, a_draws.mean(axis=1), a_draws[:, 0])
    b = np.where(averaged, b_draws.mean(axis=1), b_draws[:, 0])
    return a, b, groups


def _rate_row(scenes: int, method: str, rejected: np.ndarray, covered: np.ndarray) -> dict:
    n = len(rejected)
    coverage = float(np.mean(covered))
    return {
        "scenes": scenes,
        "method": method,
        "simulations": n,
        "coverage": coverage,
        "rejection": float(np.mean(rejected)),
        "se": math.sqrt(ALPHA * (1 - ALPHA) / n),
        "printed": method != "signflip" or scenes >= MIN_SCENES,
    }


def coverage_table(
    scenes: Sequence[int] = SCENES,
    *,
    simulations: int = SIMULATIONS,
    bootstrap_simulations: int = BOOTSTRAP_SIMULATIONS,
    seed: int = 0,
    resamples: int = N_SIGN_FLIPS,
    bootstrap_resamples: int = BOOTSTRAP_RESAMPLES,
    effect_sd: float = 0.0,
) -> list[dict]:
    """Coverage of zero by each method's 95% interval, and its rejection rate of zero, per
    scene count: one row per (scene count, method) with keys ``scenes``, ``method`` (a key
    of :data:`METHODS`), ``simulations``, ``coverage``, ``rejection``, ``se`` (the Monte Carlo
    standard error of a coverage of ``1 - ALPHA``: the yardstick of a deviation) and
    ``printed`` (whether a report prints the interval: the sign-flip one from
    :data:`MIN_SCENES` scenes).

    Data set ``i`` of ``G`` scenes comes from the generator of ``(seed, G, i)`` and the
    draws of method ``k`` (its place in :data:`METHODS`) from ``(seed, G, i, k)``:
    deterministic, and the methods see the same data sets."""
    rows = []
    for g in scenes:
        rejected = np.zeros(simulations, bool)
        covered = np.zeros(simulations, bool)
        bootstraps = {"cluster_bootstrap": True, "query_bootstrap": False}  # clustered?
        boot = {m: np.zeros((min(bootstrap_simulations, simulations), 2), bool) for m in bootstraps}
        for i in range(simulations):
            a, b, groups = simulate_null(
                np.random.default_rng([seed, g, i]), g, effect_sd=effect_sd
            )
            test = scene_signflip(
                a, b, groups, rng=np.random.default_rng([seed, g, i, 0]), resamples=resamples
            )
            rejected[i] = test.p_value <= ALPHA
            if test.low is None:
                covered[i] = not rejected[i]
            else:
                covered[i] = test.low <= 0 <= test.high
            if i >= bootstrap_simulations:
                continue
            for k, (method, clustered) in enumerate(bootstraps.items(), start=1):
                lo, hi = paired_bootstrap_ci(
                    a, b, rng=np.random.default_rng([seed, g, i, k]),
                    n_resamples=bootstrap_resamples, confidence=1 - ALPHA,
                    groups=groups if clustered else None,
                )  # fmt: skip
                boot[method][i] = (not lo <= 0 <= hi, lo <= 0 <= hi)
        rows.append(_rate_row(g, "signflip", rejected, covered))
        rows.extend(_rate_row(g, m, boot[m][:, 0], boot[m][:, 1]) for m in bootstraps)
    return rows


def coverage_markdown(rows: list[dict]) -> str:
    """The rows of :func:`coverage_table` as a markdown table (one line per scene count and
    method)."""
    lines = [
        "| scenes | method | simulations | coverage of 0 | rejects 0 | interval printed |",
        "|---:|---|---:|---:|---:|---|",
    ]
    lines.extend(
        f"| {row['scenes']} | {METHODS[row['method']]} | {row['simulations']} "
        f"| {row['coverage']:.3f} ± {row['se']:.3f} | {row['rejection']:.3f} "
        f"| {'yes' if row['printed'] else 'no (too few scenes)'} |"
        for row in rows
    )
    return "\n".join(lines)


def main() -> None:
    """The command line: ``python -m care_maps.research.coverage``."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--simulations", type=int, default=SIMULATIONS)
    parser.add_argument("--bootstrap-simulations", type=int, default=BOOTSTRAP_SIMULATIONS)
    parser.add_argument("--effect-sd", type=float, default=0.0, help="scene effect (0: none)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    start = time.perf_counter()
    rows = coverage_table(
        simulations=args.simulations,
        bootstrap_simulations=args.bootstrap_simulations,
        seed=args.seed,
        effect_sd=args.effect_sd,
    )
    print(coverage_markdown(rows))
    print(
        f"\nnominal 95% (alpha {ALPHA}); sign-flip from {MIN_SCENES} scenes; "
        f"effect_sd {args.effect_sd}; ± one Monte Carlo s.e. of a 95% coverage; "
        f"{time.perf_counter() - start:.0f} s"
    )


if __name__ == "__main__":
    main()
