"""Does a CARe rule's measure tell right candidates from wrong ones at the same confidence?

CARe can beat max confidence only if, inside the candidate set its rule chooses from, the
rule's measure (max entropy, min stderr, min pwKL) prefers candidates that would solve the
query over those that would not, *beyond what confidence already says*. This module counts,
for one measure and one query set, the within-query pairs (right, wrong) of set members:

- **concordant**: the rule's direction prefers the right one;
- **discordant**: it prefers the wrong one;
- **tied**: equal measure values (they count one half in the AUROC).

AUROC = (concordant + tied / 2) / pairs: the probability that the measure, read in the rule's
direction, ranks a random right member above a random wrong member of the same query's set
(0.5: no information). Pairs never cross queries (two queries' sets are not alternatives of
one choice). Counts, not ratios, come back (:class:`PairCounts`), so they sum across query
sets, scenes and datasets before :func:`auroc` turns them into one number.

Two pair populations are counted (:class:`Discrimination`):

- ``stratified``: only pairs whose members fall in the same confidence stratum
  (:func:`confidence_strata`): confidence held fixed;
- ``unstratified``: every (right, wrong) pair of the query's set.

A measure that merely tracks confidence separates right from wrong in the unstratified count
(right candidates are more confident) and not in the stratified one; only the stratified AUROC
says the measure adds what CARe needs.

Strata (:func:`confidence_strata`) are fixed-width bins of log-confidence,
:data:`LOG_CONFIDENCE_WIDTH` = 1 nat wide, anchored at 0: stratum -b holds
log P in (-(b+1), -b], i.e. confidences within a factor e of each other. Why this and not
within-query deciles:

- deciles of a query's whole row would put its whole top-k set (at most k of up to ~100k
  candidates) in the top decile: no control at all;
- deciles within the set are ranks, not confidences: with k = 2 every member is its own
  decile (no pairs left), and one decile spans a factor 1.01 in one query and 100 in another;
- fixed bins mean the same thing in every query, scene and dataset, so summed counts compare
  like with like, and the width is one stated number (a factor e in P). At CLIP's logit scale
  (100) a cosine gap of 0.01 is already one nat, so the bins are fine where candidates differ
  and lump only the near-certain ones (log P ~ -1e-6, all in stratum 0), which confidence
  cannot tell apart anyway. Bins are half-open on the left so log P = 0 (P = 1 in float)
  shares stratum 0 with P = 1 - 1e-6.

Any other strata can be passed as a (Q, N) integer array.

The set each rule sees at the second attempt comes from :func:`second_attempt_set`, which
builds it exactly as :func:`care_maps.replan.attempts.run_attempts` does (first attempt by max
confidence removed, grid exclusion if asked, then :func:`care_maps.replan.strategies.candidate_set`).
The direction of each rule comes from the rule itself (:func:`rule_direction`), not a copy.

Pure numpy, no I/O. Cost: one pass over the (Q, N) membership to gather the set's M members,
then sorting and binary searches over M: O(M log M) whatever the set sizes (no (Q, N, N) or
(Q, K, K) array), so large ``category`` sets on a grid are fine too.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from care_maps.query.map import MEASURES
from care_maps.replan.attempts import available_after
from care_maps.replan.strategies import Situation, Strategy, best_of, candidate_set, get_strategy

__all__ = [
    "LOG_CONFIDENCE_WIDTH",
    "Discrimination",
    "PairCounts",
    "auroc",
    "confidence_strata",
    "discrimination",
    "pair_counts",
    "rule_direction",
    "rule_discrimination",
    "second_attempt_set",
]

LOG_CONFIDENCE_WIDTH = 1.0
"""Width, in nats of log-confidence, of one confidence stratum (:func:`confidence_strata`):
the members of a stratum have confidences within a factor e of each other."""


def auroc(concordant: int, discordant: int, tied: int) -> float:
    """(concordant + tied / 2) / pairs from (summed) pair counts; NaN when there are no pairs."""
    pairs = concordant + discordant + tied
    return float("nan") if pairs == 0 else (concordant + 0.5 * tied) / pairs


@dataclass(frozen=True)
class PairCounts:
    """Counts of (right, wrong) pairs by what the measure, in the rule's direction, says."""

    concordant: int = 0
    """Pairs where the rule prefers the right candidate."""
    discordant: int = 0
    """Pairs where it prefers the wrong one."""
    tied: int = 0
    """Pairs with equal measure values."""

    def __add__(self, other: PairCounts) -> PairCounts:
        if not isinstance(other, PairCounts):
            return NotImplemented
        return PairCounts(
            self.concordant + other.concordant,
            self.discordant + other.discordant,
            self.tied + other.tied,
        )

    def __radd__(self, other: object) -> PairCounts:
        if other == 0:  # sum() starts from 0
            return self
        return NotImplemented

    @property
    def pairs(self) -> int:
        """Number of (right, wrong) pairs counted."""
        return self.concordant + self.discordant + self.tied

    @property
    def auroc(self) -> float:
        """:func:`auroc` of these counts (NaN: no pairs)."""
        return auroc(self.concordant, self.discordant, self.tied)


@dataclass(frozen=True)
class Discrimination:
    """One measure's pair counts with confidence held fixed and without."""

    stratified: PairCounts = PairCounts()
    """Pairs of one query's set within one confidence stratum."""
    unstratified: PairCounts = PairCounts()
    """Every (right, wrong) pair of one query's set."""

    def __add__(self, other: Discrimination) -> Discrimination:
        if not isinstance(other, Discrimination):
            return NotImplemented
        return Discrimination(
            self.stratified + other.stratified, self.unstratified + other.unstratified
        )

    def __radd__(self, other: object) -> Discrimination:
        if other == 0:
            return self
        return NotImplemented


def confidence_strata(conf: np.ndarray, width: float = LOG_CONFIDENCE_WIDTH) -> np.ndarray:
    """int64 stratum of each log-confidence (any shape): ``ceil(log P / width)``, i.e.
    stratum -b holds log P in (-(b+1) w, -b w]. ``conf`` must be log-confidence (nats; pass
    ``np.log`` of a probability); log P = -inf (P = 0) gets a stratum of its own, below all
    others."""
    conf = np.asarray(conf, np.float64)
    if not width > 0:
        msg = f"stratum width must be > 0 nats, got {width}"
        raise ValueError(msg)
    if np.isnan(conf).any():
        msg = "log-confidence holds NaN: no stratum for it"
        raise ValueError(msg)
    lowest = -1e15  # far below any finite log-confidence bin, and exact in int64
    return np.ceil(np.maximum(conf, lowest * width) / width).astype(np.int64)


def _members(success: np.ndarray, member: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row, id) of every set member, row-major: one pass over (Q, N)."""
    if np.shape(success) != np.shape(member):
        msg = f"success {np.shape(success)} and set membership {np.shape(member)} differ in shape"
        raise ValueError(msg)
    return np.divmod(np.flatnonzero(np.asarray(member, bool)), np.shape(member)[1])


def _at(
    array: np.ndarray, shape: tuple[int, ...], rows: np.ndarray, cols: np.ndarray
) -> np.ndarray:
    """``array`` (N,) or (Q, N) at the members."""
    array = np.asarray(array)
    return array[cols] if array.ndim == 1 else np.broadcast_to(array, shape)[rows, cols]


def _count(
    rows: np.ndarray,
    right: np.ndarray,
    vals: np.ndarray,
    prefer_high: bool,
    stratum: np.ndarray | None = None,
) -> PairCounts:
    """The pair counts over gathered members: query ``rows``, ``right``, measure ``vals`` and
    ``stratum`` (None: one per query), each (M,)."""
    if right.all() or not right.any():
        return PairCounts()
    vals = np.asarray(vals, np.float64)
    score = vals if prefer_high else -vals
    score = np.where(np.isnan(score), -np.inf, score)  # higher score: preferred by the rule
    # dense group id of (query, stratum) and dense rank of the score, so one int64 key
    # group * n_scores + rank orders members by group, then score
    if stratum is None:
        group_key = rows
    else:
        _, s_rank = np.unique(np.asarray(stratum, np.int64), return_inverse=True)
        group_key = rows * (int(s_rank.max()) + 1) + s_rank.reshape(-1)
    _, group = np.unique(group_key, return_inverse=True)
    levels, rank = np.unique(score, return_inverse=True)
    n_s = np.int64(len(levels))
    key = group.reshape(-1).astype(np.int64) * n_s + rank.reshape(-1)
    wrong = np.sort(key[~right])
    mine = key[right]
    start = (mine // n_s) * n_s
    lo = np.searchsorted(wrong, start, "left")  # the group's first wrong member
    below = np.searchsorted(wrong, mine, "left")  # first wrong member scoring as high
    above = np.searchsorted(wrong, mine, "right")  # first scoring higher
    hi = np.searchsorted(wrong, start + n_s, "left")  # past the group's wrong members
    return PairCounts(int((below - lo).sum()), int((hi - above).sum()), int((above - below).sum()))


def pair_counts(
    success: np.ndarray,
    member: np.ndarray,
    values: np.ndarray,
    *,
    prefer_high: bool,
    strata: np.ndarray | None = None,
) -> PairCounts:
    """Within-query (right, wrong) pairs of set members in one stratum, by what ``values``
    prefers.

    ``success`` and ``member`` are (Q, N) bool (right for the query; in the query's set);
    ``values`` is the measure, (N,) or (Q, N); ``prefer_high``: the rule picks the highest
    value (else the lowest). NaN counts as the worst value (as :func:`best_of` does), so two
    NaNs tie, and a NaN ties with the worst infinity. ``strata`` (Q, N) int: only pairs with
    equal strata count; None: one stratum per query.
    """
    rows, cols = _members(success, member)
    shape = np.shape(member)
    right = _at(success, shape, rows, cols).astype(bool)
    stratum = None if strata is None else _at(strata, shape, rows, cols)
    return _count(rows, right, _at(values, shape, rows, cols), prefer_high, stratum)


def discrimination(
    conf: np.ndarray,
    success: np.ndarray,
    member: np.ndarray,
    values: np.ndarray,
    *,
    prefer_high: bool,
    strata: np.ndarray | None = None,
) -> Discrimination:
    """:func:`pair_counts` with confidence held fixed (``strata``, default
    :func:`confidence_strata` of the log-confidence ``conf`` (Q, N)) and without."""
    rows, cols = _members(success, member)
    shape = np.shape(member)
    right = _at(success, shape, rows, cols).astype(bool)
    vals = _at(values, shape, rows, cols)
    if strata is None:  # only the members' strata: no (Q, N) pass over the confidences
        stratum = confidence_strata(_at(conf, shape, rows, cols))
    else:
        stratum = _at(strata, shape, rows, cols)
    return Discrimination(
        _count(rows, right, vals, prefer_high, stratum), _count(rows, right, vals, prefer_high)
    )


def rule_direction(strategy: Strategy | str) -> tuple[str, bool]:
    """``(measure column, prefer_high)`` of a CARe rule or ablation (``max_entropy``,
    ``min_stderr``, ``min_pwkl``, ``min_entropy``, ``max_pwkl``), read from the rule itself:
    it is asked to choose between two equally confident candidates of measure 0 and 1."""
    strategy = get_strategy(strategy) if isinstance(strategy, str) else strategy
    if strategy.rule is None or strategy.measure not in MEASURES or strategy.travel:
        msg = f"strategy {strategy.name!r} does not choose by one measure column alone"
        raise ValueError(msg)
    picks = []
    for column in (np.array([0.0, 1.0]), np.array([1.0, 0.0])):
        mask = np.ones((1, 2), bool)
        s = Situation(np.zeros((1, 2)), mask, mask, {strategy.measure: column})
        picks.append(float(column[int(strategy.rule(s).candidate[0])]))
    if picks[0] != picks[1]:
        msg = f"strategy {strategy.name!r} does not choose by the order of its measure"
        raise ValueError(msg)
    return strategy.measure, picks[0] == 1.0


def rule_discrimination(
    strategy: Strategy | str,
    conf: np.ndarray,
    success: np.ndarray,
    member: np.ndarray,
    columns: Mapping[str, np.ndarray],
    *,
    strata: np.ndarray | None = None,
) -> Discrimination:
    """:func:`discrimination` of ``strategy``'s measure (from ``columns``) in its direction."""
    measure, high = rule_direction(strategy)
    return discrimination(conf, success, member, columns[measure], prefer_high=high, strata=strata)


def second_attempt_set(
    conf: np.ndarray,
    criterion: str,
    k: int,
    *,
    rank: np.ndarray | None = None,
    success: np.ndarray | None = None,
    positions: np.ndarray | None = None,
    exclude_radius: float = 0.0,
) -> np.ndarray:
    """(Q, N) bool: the candidate set a rule chooses from at the second attempt, built as
    :func:`care_maps.replan.attempts.run_attempts` builds it.

    The first attempt (max confidence, ties to the lower id) is removed, with the grid cells
    within ``exclude_radius`` of it where ``positions`` (N, 3) are given; then
    :func:`care_maps.replan.strategies.candidate_set` of ``criterion`` and ``k`` (``rank``: the class
    ranks the ``category`` criterion needs). With ``success`` (Q, N), a query whose first
    attempt succeeded makes no second attempt, so its set is empty, as in the evaluation;
    without it every query gets its set.
    """
    conf = np.asarray(conf)
    available = np.ones(conf.shape, bool)
    first, found = best_of(conf, available, conf, maximise=True)
    first = np.where(found, first, -1)
    available = available_after(available, first, positions, exclude_radius)
    live = found.copy()
    if success is not None:
        live &= ~np.asarray(success, bool)[np.arange(len(first)), np.maximum(first, 0)]
    available[~live] = False
    return candidate_set(criterion, conf, available, k, rank)
