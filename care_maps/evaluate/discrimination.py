"""Does a CARe rule's measure tell right candidates from wrong ones at the same confidence?

Inside the candidate set a CARe rule chooses from, does the rule's measure (max entropy, min
stderr, min pwKL) prefer candidates that would solve the query over those that would not,
*beyond what confidence already says*? That is what the measure adds to confidence, not a
condition for a gain: a rule can also gain by where its pick lies (away from a failed grid
cell's neighbours), which no count within the set sees. This module counts,
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
(right candidates are more confident); a count with confidence held equal says what the
measure adds to it, and the 1-nat strata hold it only roughly (the matched pairs below).

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

**The 1-nat strata do not hold confidence equal**, so a third population is counted. Inside
one stratum confidence itself can still tell right from wrong: log P squeezes every P above
1 - 1e-3 into a thousandth of a nat, and on the grid, after a failed first attempt without
exclusion, the failed cell's near-certain neighbours are mostly wrong. The **matched** pairs
are the (right, wrong) pairs of one query's set whose confidences lie within
:data:`MATCH_CALIPER` of each other on the log-odds scale, ``log P - log(1 - P)``
(:func:`log_odds`): the right member's log-odds ``x_r`` and the wrong one's ``x_w`` with
``x_r - c <= x_w <= x_r + c`` (caliper matching on confidence, every pair within the caliper
kept). Log-odds, not log P: below P ~ 0.05 the two agree (log(1 - P) ~ 0), and near P = 1
the log-odds is ~ ``-log(1 - P)``, so a caliper of c nats holds the odds within a factor
e^c at both ends, where log P lets 1 - P differ by any factor. Log-odds of +inf (P = 1 in
floating point) or -inf (P = 0) match only each other. Every matched pair is counted twice,
by the measure (``matched``) and by confidence itself (``matched_confidence``, the order of
``conf`` in the same pairs): the second AUROC is the check that the caliper held confidence
equal (0.5 when it did). ``stratified_confidence`` is the same check for the 1-nat strata.
The matched pairs are enumerated (sorted wrong members, one window of them per right member,
in chunks of :data:`_PAIR_CHUNK` pairs): their number, not the square of the set's, bounds
the cost.

**Scenes as units** (:func:`scene_auroc`): pairs of one scene share a map and a perception
run, so an AUROC's interval resamples scenes, not pairs: the scene-level sign-flip test of
:mod:`care_maps.evaluate.scene_test` on each scene's ``S_g = concordant - discordant`` over
``n_g`` pairs, whose pooled ``sum S_g / sum n_g = 2 AUROC - 1`` (Somers' D). Under "the
measure is exchangeable between the right and wrong member of a pair within every scene"
(AUROC 0.5) each ``S_g`` is symmetric about 0, so the p-value of AUROC = 0.5 is exact, and
the inverted interval, mapped by ``AUROC = (1 + D) / 2``, covers an AUROC away from 0.5
approximately (as :mod:`care_maps.evaluate.scene_test` says of a non-zero difference). No
interval below :data:`care_maps.evaluate.scene_test.MIN_SCENES` effective scenes (Kish's, by
pair counts).

The set each rule sees at the second attempt comes from :func:`second_attempt_set`, which
builds it exactly as :func:`care_maps.replan.attempts.run_attempts` does (first attempt by max
confidence removed, grid exclusion if asked, then :func:`care_maps.replan.strategies.candidate_set`).
The direction of each rule comes from the rule itself (:func:`rule_direction`), not a copy.

Pure numpy, no I/O. Cost: one pass over the (Q, N) membership to gather the set's M members,
then sorting and binary searches over M: O(M log M) whatever the set sizes (no (Q, N, N) or
(Q, K, K) array), so large ``category`` sets on a grid are fine too.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from care_maps.evaluate.scene_test import (
    ALPHA,
    N_SIGN_FLIPS,
    TIE_TOLERANCE,
    effective_scenes,
    min_scenes,
    sign_vectors,
    signflip_interval,
    signflip_p,
)
from care_maps.query.map import MEASURES
from care_maps.replan.attempts import available_after
from care_maps.replan.strategies import Situation, Strategy, best_of, candidate_set, get_strategy

__all__ = [
    "LOG_CONFIDENCE_WIDTH",
    "MATCH_CALIPER",
    "Discrimination",
    "PairCounts",
    "SceneAuroc",
    "auroc",
    "confidence_strata",
    "discrimination",
    "log_odds",
    "matched_pair_counts",
    "pair_counts",
    "rule_direction",
    "rule_discrimination",
    "scene_auroc",
    "second_attempt_set",
]

LOG_CONFIDENCE_WIDTH = 1.0
"""Width, in nats of log-confidence, of one confidence stratum (:func:`confidence_strata`):
the members of a stratum have confidences within a factor e of each other."""
MATCH_CALIPER = 0.25
"""Largest difference, in nats of log-odds of confidence (:func:`log_odds`), between the two
members of a matched pair: odds within a factor e^0.25 ~ 1.28 of each other. Chosen by the
balance check alone (confidence's own AUROC in the pairs near 0.5 on the grid, where
candidates are many), never by a measure's AUROC; the tables print that check beside every
figure."""
_PAIR_CHUNK = 1 << 22
"""Matched pairs compared at once (bounds the memory of a large set's pairs)."""


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
    stratified_confidence: PairCounts = PairCounts()
    """The ``stratified`` pairs counted by confidence itself (0.5: the strata held it equal)."""
    matched: PairCounts = PairCounts()
    """Pairs of one query's set within :data:`MATCH_CALIPER` of log-odds of each other."""
    matched_confidence: PairCounts = PairCounts()
    """The ``matched`` pairs counted by confidence itself (0.5: the caliper held it equal)."""

    def __add__(self, other: Discrimination) -> Discrimination:
        if not isinstance(other, Discrimination):
            return NotImplemented
        return Discrimination(
            self.stratified + other.stratified,
            self.unstratified + other.unstratified,
            self.stratified_confidence + other.stratified_confidence,
            self.matched + other.matched,
            self.matched_confidence + other.matched_confidence,
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


def log_odds(conf: np.ndarray) -> np.ndarray:
    """float64 ``log P - log(1 - P)`` of log-confidences ``conf`` (any shape; nats), computed
    from log P so near-certain candidates stay apart (``-log(-expm1(log P))`` keeps
    ``1 - P`` where ``P`` itself rounds to 1): +inf where log P = 0, -inf where log P = -inf.
    Raises on NaN or a positive log P (not a probability)."""
    conf = np.asarray(conf, np.float64)
    if np.isnan(conf).any() or (conf > 0).any():
        msg = "log-confidence holds NaN or a value above 0: not the log of a probability"
        raise ValueError(msg)
    with np.errstate(divide="ignore"):
        return conf - np.log(-np.expm1(conf))


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


def _rule_score(vals: np.ndarray, prefer_high: bool) -> np.ndarray:
    """float64 score, higher where the rule prefers; NaN is the worst value (-inf)."""
    vals = np.asarray(vals, np.float64)
    score = vals if prefer_high else -vals
    return np.where(np.isnan(score), -np.inf, score)


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
    score = _rule_score(vals, prefer_high)
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


def _keys_before(
    key_rows: np.ndarray, key_x: np.ndarray, rows: np.ndarray, x: np.ndarray, *, inclusive: bool
) -> np.ndarray:
    """For each probe ``(rows, x)``, how many keys (sorted by (row, x)) precede it: keys
    ``< (row, x)``, or ``<=`` when ``inclusive``. One merge by ``np.lexsort``."""
    n = len(key_rows)
    tag = np.full(n + len(rows), 2 if inclusive else 0, np.int8)
    tag[:n] = 1  # a probe sorts before (tag 0) or after (tag 2) keys equal to it
    order = np.lexsort((tag, np.concatenate([key_x, x]), np.concatenate([key_rows, rows])))
    is_key = order < n
    before: np.ndarray = np.cumsum(is_key) - is_key
    out = np.empty(len(rows), np.int64)
    out[order[~is_key] - n] = before[~is_key]
    return out


def _order_counts(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(a > b, a < b) counted over aligned arrays without NaN (every other pair ties)."""
    return np.array([np.count_nonzero(a > b), np.count_nonzero(a < b)])


def _from_order(counts: np.ndarray, pairs: int) -> PairCounts:
    """:class:`PairCounts` from (higher, lower) counts over ``pairs`` pairs."""
    higher, lower = int(counts[0]), int(counts[1])
    return PairCounts(higher, lower, pairs - higher - lower)


def _matched(
    rows: np.ndarray,
    right: np.ndarray,
    conf: np.ndarray,
    vals: np.ndarray,
    prefer_high: bool,
    caliper: float,
) -> tuple[PairCounts, PairCounts]:
    """The measure's and confidence's own counts over the matched pairs of gathered members
    (query ``rows``, ``right``, log-confidence ``conf``, measure ``vals``; each (M,)): a right
    and a wrong member of one query whose :func:`log_odds` differ by at most ``caliper``."""
    if not (np.isfinite(caliper) and caliper >= 0):
        msg = f"caliper must be a finite number of nats >= 0, got {caliper}"
        raise ValueError(msg)
    if right.all() or not right.any():
        return PairCounts(), PairCounts()
    score = _rule_score(vals, prefer_high)
    conf = np.asarray(conf, np.float64)
    odds = log_odds(conf)
    wrong = np.flatnonzero(~right)
    wrong = wrong[np.lexsort((odds[wrong], rows[wrong]))]
    mine = np.flatnonzero(right)
    # each right member's partners: one run [lo, hi) of the sorted wrong members
    lo = _keys_before(rows[wrong], odds[wrong], rows[mine], odds[mine] - caliper, inclusive=False)
    hi = _keys_before(rows[wrong], odds[wrong], rows[mine], odds[mine] + caliper, inclusive=True)
    width = hi - lo
    ends = np.cumsum(width)
    w_score, w_conf, r_score, r_conf = score[wrong], conf[wrong], score[mine], conf[mine]
    measure = np.zeros(2, np.int64)  # (right member higher, lower); the rest tie
    confidence = np.zeros(2, np.int64)
    start = 0
    while start < len(mine):  # chunks of at most _PAIR_CHUNK pairs (or one member's run)
        begin = ends[start] - width[start]
        stop = max(int(np.searchsorted(ends, begin + _PAIR_CHUNK, "right")), start + 1)
        run = width[start:stop]
        w = np.repeat(lo[start:stop] - (ends[start:stop] - run - begin), run)
        w += np.arange(len(w))  # the sorted wrong member of each pair
        measure += _order_counts(np.repeat(r_score[start:stop], run), w_score[w])
        confidence += _order_counts(np.repeat(r_conf[start:stop], run), w_conf[w])
        start = stop
    pairs = int(ends[-1])
    return _from_order(measure, pairs), _from_order(confidence, pairs)


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


def matched_pair_counts(
    conf: np.ndarray,
    success: np.ndarray,
    member: np.ndarray,
    values: np.ndarray,
    *,
    prefer_high: bool,
    caliper: float = MATCH_CALIPER,
) -> tuple[PairCounts, PairCounts]:
    """The matched pairs' counts ``(by the measure, by confidence itself)``: every (right,
    wrong) pair of one query's set whose :func:`log_odds` of the log-confidences ``conf``
    (Q, N) differ by at most ``caliper`` nats. Arguments as :func:`pair_counts`."""
    rows, cols = _members(success, member)
    shape = np.shape(member)
    right = _at(success, shape, rows, cols).astype(bool)
    return _matched(
        rows, right, _at(conf, shape, rows, cols), _at(values, shape, rows, cols),
        prefer_high, caliper,
    )  # fmt: skip


def discrimination(
    conf: np.ndarray,
    success: np.ndarray,
    member: np.ndarray,
    values: np.ndarray,
    *,
    prefer_high: bool,
    strata: np.ndarray | None = None,
    caliper: float = MATCH_CALIPER,
) -> Discrimination:
    """:func:`pair_counts` with confidence held fixed (``strata``, default
    :func:`confidence_strata` of the log-confidence ``conf`` (Q, N)) and without, confidence's
    own counts in the strata, and :func:`matched_pair_counts` at ``caliper``."""
    rows, cols = _members(success, member)
    shape = np.shape(member)
    right = _at(success, shape, rows, cols).astype(bool)
    vals = _at(values, shape, rows, cols)
    member_conf = _at(conf, shape, rows, cols)  # only the members: no (Q, N) pass
    stratum = confidence_strata(member_conf) if strata is None else _at(strata, shape, rows, cols)
    matched, matched_confidence = _matched(rows, right, member_conf, vals, prefer_high, caliper)
    return Discrimination(
        stratified=_count(rows, right, vals, prefer_high, stratum),
        unstratified=_count(rows, right, vals, prefer_high),
        stratified_confidence=_count(rows, right, member_conf, True, stratum),
        matched=matched,
        matched_confidence=matched_confidence,
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
    caliper: float = MATCH_CALIPER,
) -> Discrimination:
    """:func:`discrimination` of ``strategy``'s measure (from ``columns``) in its direction."""
    measure, high = rule_direction(strategy)
    return discrimination(
        conf, success, member, columns[measure], prefer_high=high, strata=strata, caliper=caliper
    )


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


@dataclass(frozen=True)
class SceneAuroc:
    """An AUROC pooled over scenes, with its scene-level sign-flip interval."""

    auroc: float
    """The pooled AUROC, (concordant + tied / 2) / pairs over every scene (NaN: no pair)."""
    low: float | None
    high: float | None
    """The ``1 - alpha`` interval of the AUROC by inverting the scene-level sign-flip test;
    None below :func:`care_maps.evaluate.scene_test.min_scenes` effective scenes."""
    p_value: float
    """Two-sided sign-flip p-value of AUROC = 0.5 (NaN: no pair)."""
    scenes: int
    """Scenes with at least one pair."""
    effective: float
    """Kish's effective number of scenes, by pair counts."""


def scene_auroc(
    per_scene: Sequence[PairCounts],
    *,
    rng: np.random.Generator,
    alpha: float = ALPHA,
    resamples: int = N_SIGN_FLIPS,
) -> SceneAuroc:
    """The AUROC of summed counts with scenes as the units: the sign-flip test over scenes of
    ``S_g = concordant - discordant`` on ``n_g`` pairs (module docstring), its p-value of
    AUROC = 0.5 and its inverted interval mapped from Somers' D to the AUROC. ``per_scene``:
    one :class:`PairCounts` per scene (scenes without a pair carry nothing and are dropped);
    ``rng`` is drawn from only above
    :data:`care_maps.evaluate.scene_test.EXACT_MAX_SCENES` scenes."""
    counts = [c for c in per_scene if c.pairs]
    if not counts:
        return SceneAuroc(float("nan"), None, None, float("nan"), 0, 0.0)
    sums = np.array([c.concordant - c.discordant for c in counts], np.float64)
    pairs = np.array([c.pairs for c in counts], np.float64)
    signs, exact = sign_vectors(len(counts), rng=rng, resamples=resamples)
    effective = effective_scenes(pairs)
    low = high = None
    if effective >= min_scenes(alpha) - TIE_TOLERANCE:
        d_low, d_high = signflip_interval(sums, pairs, signs=signs, exact=exact, alpha=alpha)
        low, high = (1 + d_low) / 2, (1 + d_high) / 2
    return SceneAuroc(
        auroc=sum(counts, PairCounts()).auroc,
        low=low,
        high=high,
        p_value=signflip_p(sums, pairs, 0.0, signs=signs, exact=exact),
        scenes=len(counts),
        effective=effective,
    )
