"""Whether a recording's geometry agrees with itself: overlapping views reprojected into each
other with the poses and intrinsics they were given.

Every RGB-D recording can check its own geometry. Where two views see the same surface, one
view's depth, back-projected with its camera matrix, moved by the two poses and projected
into the other view, must land where the other view's depth says the surface is. A wrong
convention (poses written world-to-camera, a quaternion read in the other order, depth in
other units, a body frame read as optical, another camera's focal length) breaks that
agreement everywhere, while a right one keeps it up to sensor noise and occlusion.

This module is the arithmetic only: views in, figures out. Which views are sampled, what the
mistakes are called and which option selects each is :mod:`care_maps.ingest.consistency`'s.

- :class:`DepthSample`: one view's depth, subsampled to a few thousand pixels, with its
  camera matrix and pose.
- :func:`pick_pairs`: pairs of views a bounded distance apart in time that moved enough for
  a wrong convention to show (a camera that stands still agrees with any pose convention).
- :func:`pair_agreement`: one direction of one pair: the share of the first view's pixels
  whose reprojected depth matches the second view's within tolerance, and their residuals.
- :func:`agreement`: a hypothesis (the views as given, or with one mistake undone) scored
  over all pairs.
- :class:`Hypothesis`: how the views change under one reading (poses inverted, depth scaled,
  focal length scaled, axes turned, quaternion reordered).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TypedDict

import numpy as np

from care_maps.geometry.transforms import (
    BODY_FROM_OPTICAL,
    backproject,
    matrix_to_quaternion,
    project,
    quaternion_to_matrix,
)

__all__ = [
    "AGREE_ABSOLUTE_M",
    "AGREE_RELATIVE",
    "MAX_CROSS_MOTION",
    "Agreement",
    "DepthSample",
    "Hypothesis",
    "Mistake",
    "PairAgreement",
    "Status",
    "Verdict",
    "agreement",
    "depth_scales",
    "hypotheses",
    "judge",
    "median_range",
    "pair_agreement",
    "pick_cross_pairs",
    "pick_pairs",
    "reorder_quaternion",
    "subsample",
]

SAMPLE_WIDTH = 80
"""Pixels across a subsampled depth image: some 4,800 points a view, enough for a median and
a share to two decimals, and a pair's reprojection costs well under a millisecond."""
AGREE_RELATIVE = 0.05
"""Relative depth difference within which a reprojected pixel agrees (structured-light and
time-of-flight sensors are good to 1-3 % of range; rendered depth to far better)."""
AGREE_ABSOLUTE_M = 0.03
"""Metres added to the tolerance: quantisation and noise of near surfaces, pose noise of a
few centimetres in estimated trajectories."""
MIN_OVERLAP = 0.15
"""Share of a view's points that must land inside the other view for the pair to count in a
hypothesis's score: a pair that does not overlap says nothing either way."""
TARGET_MOTION_M = 0.3
"""Metres of travel between a pair's views the check aims for (or :data:`TARGET_TURN_DEG`)."""
TARGET_TURN_DEG = 15.0
MIN_MOTION = 1 / 6
"""Least motion of a pair, as a share of the target (5 cm, 2.5 degrees): a camera that
stands still agrees with any pose convention, so such a pair cannot tell them apart."""
MAX_PAIR_GAP = 8
"""Most sampled views between the two of a pair: views far apart in time seldom overlap."""


@dataclass(frozen=True)
class DepthSample:
    """One view for the check: depth subsampled on a regular grid, its camera matrix for that
    grid, its optical camera-to-world pose."""

    depth: np.ndarray = field(repr=False)
    """(h, w) float32 metres, 0 = invalid."""
    K: np.ndarray = field(repr=False)
    """(3, 3) camera matrix of the subsampled grid."""
    pose: np.ndarray = field(repr=False)
    """(4, 4) optical camera-to-world pose."""
    stamp_ns: int = 0


def subsample(depth: np.ndarray, K: np.ndarray, pose: np.ndarray, stamp_ns: int = 0) -> DepthSample:
    """A view's depth taken every ``step`` pixels (about :data:`SAMPLE_WIDTH` across): the
    pixel (u, v) of the grid is (step u, step v) of the image, so its K is the image's with
    focal lengths and principal point divided by ``step``."""
    step = max(1, int(np.ceil(depth.shape[1] / SAMPLE_WIDTH)))
    small = np.ascontiguousarray(depth[::step, ::step], np.float32)
    small = np.where(np.isfinite(small) & (small > 0), small, np.float32(0.0))
    scale = np.diag([1.0 / step, 1.0 / step, 1.0])
    return DepthSample(
        small, scale @ np.asarray(K, np.float64), np.asarray(pose, np.float64), stamp_ns
    )


def _turn_deg(a: np.ndarray, b: np.ndarray) -> float:
    R = a[:3, :3].T @ b[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _motion(a: np.ndarray, b: np.ndarray) -> float:
    """How far apart two poses are, in units of the pair motion the check aims for: 1 at
    :data:`TARGET_MOTION_M` of travel or :data:`TARGET_TURN_DEG` of turn (whichever is more)."""
    moved = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
    return max(moved / TARGET_MOTION_M, _turn_deg(a, b) / TARGET_TURN_DEG)


def pick_pairs(
    samples: Sequence[DepthSample], max_pairs: int, runs: Sequence[int] | None = None
) -> list[tuple[int, int]]:
    """Pairs ``(i, j)``, i < j, for the check: each view with the later view (at most
    :data:`MAX_PAIR_GAP` on) whose motion from it is nearest the target (:func:`_motion`),
    among those that moved at least :data:`MIN_MOTION` of it, evenly thinned to
    ``max_pairs``. A wrong convention shows in proportion to the motion between the views,
    and overlap falls with it: the target is a tenth of a room's width or a sixth of a
    field of view. Motion is judged on the poses as given: a pose inverted or reordered
    moves about as much as the right one, so the pairs are the same for every hypothesis.

    ``runs``: lengths of runs of consecutive views the samples come in (one run if None); a
    pair never spans two runs."""
    ends = np.cumsum(runs if runs is not None else [len(samples)])
    pairs = []
    for i in range(len(samples)):
        end = int(ends[np.searchsorted(ends, i, side="right")])
        later = range(i + 1, min(end, i + 1 + MAX_PAIR_GAP))
        moved = [
            (abs(np.log(m)), j)
            for j in later
            if (m := _motion(samples[i].pose, samples[j].pose)) >= MIN_MOTION
        ]
        if moved:
            pairs.append((i, min(moved)[1]))
    if len(pairs) > max_pairs:
        keep = np.linspace(0, len(pairs) - 1, max_pairs).round().astype(int)
        pairs = [pairs[k] for k in np.unique(keep)]
    return pairs


MAX_CROSS_MOTION = 2.0
"""How far apart (in :func:`_motion`'s units: 0.6 m or 30 degrees) a view of one run and the
nearest view of another may be for the pair to be judged: near enough that they overlap,
whatever time passed between the runs."""


def pick_cross_pairs(
    first: Sequence[DepthSample], second: Sequence[DepthSample], max_pairs: int
) -> list[tuple[int, int]]:
    """Pairs ``(i, len(first) + j)`` joining each view of ``first`` to the view of ``second``
    nearest it in pose (:func:`_motion`), where that is within :data:`MAX_CROSS_MOTION`: two
    runs of one place overlap where the robot came back, not at any time offset, so pairs
    are picked by place. Indices are into ``[*first, *second]``, evenly thinned to
    ``max_pairs``."""
    pairs = []
    for i, sample in enumerate(first):
        moved = [(_motion(sample.pose, other.pose), j) for j, other in enumerate(second)]
        if moved and (near := min(moved))[0] <= MAX_CROSS_MOTION:
            pairs.append((i, len(first) + near[1]))
    if len(pairs) > max_pairs:
        keep = np.linspace(0, len(pairs) - 1, max_pairs).round().astype(int)
        pairs = [pairs[k] for k in np.unique(keep)]
    return pairs


@dataclass(frozen=True)
class PairAgreement:
    """One direction of one pair."""

    points: int
    """Valid depth points of the first view."""
    overlap: float
    """Share of them that land in front of the second camera, inside its image, on a valid
    depth pixel."""
    agree: float
    """Share of the landed points whose depth agrees with the second view's (within
    :data:`AGREE_RELATIVE` of it plus :data:`AGREE_ABSOLUTE_M`)."""
    residuals: np.ndarray = field(repr=False)
    """Relative depth residuals ``(z - d) / d`` of the landed points."""


def _focal(K: np.ndarray, focal_scale: float) -> np.ndarray:
    """``K`` with both focal lengths scaled (the principal point stays: a focal length read
    from another camera or resolution moves the rays' spread, not the image centre)."""
    scaled = np.array(K, np.float64)
    scaled[0, 0] *= focal_scale
    scaled[1, 1] *= focal_scale
    return scaled


def _points(sample: DepthSample, depth_scale: float, focal_scale: float) -> np.ndarray:
    """Camera-frame points of the sample's valid pixels as a hypothesis reads them."""
    # a point's coordinates are linear in its depth: scaled in float64 after back-projection
    return backproject(sample.depth, _focal(sample.K, focal_scale))[0] * depth_scale


def pair_agreement(
    first: DepthSample,
    second: DepthSample,
    first_pose: np.ndarray,
    second_pose: np.ndarray,
    *,
    depth_scale: float = 1.0,
    focal_scale: float = 1.0,
) -> PairAgreement:
    """``first``'s depth reprojected into ``second`` with the poses given here (a hypothesis
    may change them) and depth and focal lengths scaled as a hypothesis says."""
    points = _points(first, depth_scale, focal_scale)
    n = len(points)
    if n == 0:
        return PairAgreement(0, 0.0, 0.0, np.zeros(0))
    T = np.linalg.solve(second_pose, first_pose)  # second_from_first
    p = points @ T[:3, :3].T + T[:3, 3]
    p = p[p[:, 2] > 1e-6]  # in front of the second camera
    uv, z = project(p, _focal(second.K, focal_scale))
    u, v = np.rint(uv).astype(np.int64).T
    h, w = second.depth.shape
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    d = np.zeros(len(z))
    d[inside] = second.depth[v[inside], u[inside]].astype(np.float64) * depth_scale
    landed = d > 0
    if not landed.any():
        return PairAgreement(n, 0.0, 0.0, np.zeros(0))
    z, d = z[landed], d[landed]
    tolerance = AGREE_RELATIVE * d + AGREE_ABSOLUTE_M
    agree = np.abs(z - d) <= tolerance
    return PairAgreement(n, float(landed.sum() / n), float(agree.mean()), (z - d) / d)


@dataclass(frozen=True)
class Hypothesis:
    """One reading of the views: how their poses, depth and focal lengths change."""

    name: str
    pose: Callable[[np.ndarray], np.ndarray] | None = None
    """Each pose as this reading would have it (None: as given)."""
    depth_scale: float = 1.0
    focal_scale: float = 1.0


@dataclass(frozen=True)
class Agreement:
    """A hypothesis scored over the pairs."""

    pairs: int
    """Pair directions that overlapped enough to judge (:data:`MIN_OVERLAP`)."""
    agree: float
    """Median over those of the share of landed points that agree."""
    residual: float
    """Median absolute relative depth residual of all landed points."""
    overlap: float
    """Median overlap over all pair directions (whether they counted or not)."""

    def as_json(self) -> dict[str, float | int]:
        return {
            "pairs_judged": self.pairs,
            "agree": round(self.agree, 4),
            "residual": round(self.residual, 4),
            "overlap": round(self.overlap, 4),
        }


def agreement(
    samples: Sequence[DepthSample], pairs: Sequence[tuple[int, int]], hypothesis: Hypothesis
) -> Agreement:
    """``hypothesis`` scored on ``pairs`` in both directions."""
    poses = [s.pose if hypothesis.pose is None else hypothesis.pose(s.pose) for s in samples]
    shares, residuals, overlaps = [], [], []
    for i, j in pairs:
        for a, b in ((i, j), (j, i)):
            got = pair_agreement(
                samples[a],
                samples[b],
                poses[a],
                poses[b],
                depth_scale=hypothesis.depth_scale,
                focal_scale=hypothesis.focal_scale,
            )
            overlaps.append(got.overlap)
            if got.overlap >= MIN_OVERLAP:
                shares.append(got.agree)
                residuals.append(np.abs(got.residuals))
    if not shares:
        return Agreement(0, 0.0, float("nan"), float(np.median(overlaps)) if overlaps else 0.0)
    return Agreement(
        len(shares),
        float(np.median(shares)),
        float(np.median(np.concatenate(residuals))),
        float(np.median(overlaps)),
    )


def median_range(samples: Sequence[DepthSample]) -> float:
    """Median valid depth over the samples, metres (NaN with none)."""
    valid = [s.depth[s.depth > 0] for s in samples]
    values = np.concatenate(valid) if valid else np.zeros(0)
    return float(np.median(values)) if len(values) else float("nan")


def reorder_quaternion(pose: np.ndarray) -> np.ndarray:
    """The pose whose rotation reads the same four numbers in the other order: a quaternion
    written ``w x y z`` and read as ``x y z w`` gave ``pose``; this is the ``w x y z``
    reading (the sign of a quaternion does not change its rotation, so the matrix is
    enough to recover the numbers)."""
    a, b, c, d = matrix_to_quaternion(pose[:3, :3])
    out = np.array(pose, np.float64)
    out[:3, :3] = quaternion_to_matrix(np.array([b, c, d, a]))
    return out


class Mistake(StrEnum):
    """A usual way to get a recording's geometry wrong, each undone by one hypothesis."""

    POSES_INVERTED = "poses-inverted"
    """Poses written world-to-camera and read camera-to-world (or the other way)."""
    QUATERNION_ORDER = "quaternion-order"
    """A quaternion written ``w x y z`` read as ``x y z w`` (or the other way)."""
    BODY_AXES = "body-axes"
    """A body frame (x forward, y left, z up) read as an optical one."""
    OPTICAL_AXES = "optical-axes"
    """An optical frame read as a body one."""
    DEPTH_SCALE = "depth-scale"
    """Depth in other units than read (millimetres as metres, TUM's 5000 per metre as 1000)."""
    FOCAL_LENGTH = "focal-length"
    """Another camera's focal length (a default camera, another resolution's calibration)."""


DEPTH_FACTORS = (1000.0, 5000.0, 6553.5, 4000.0, 1.0)
"""Depth values of one metre the datasets and encodings use (millimetres; TUM, ETH3D, Bonn;
Replica as NICE-SLAM renders it; Matterport3D; float metres): a depth scale mistake is
one of their ratios, or a power of ten."""
FOCAL_GRID_STEP = 2.0 ** (1 / 6)
"""Ratio between neighbouring focal length factors of the search (12 %)."""
FOCAL_SCALES = tuple(
    float(f) for f in np.round(FOCAL_GRID_STEP ** np.arange(-6, 7), 4) if abs(np.log(f)) > 0.2
)
"""Focal length factors the 1-D search tries (0.5 to 2, leaving out those within 22 % of 1:
a focal length a few percent off is below what reprojection between views can tell)."""


def depth_scales() -> tuple[float, ...]:
    """Factors a depth scale mistake multiplies depth by: powers of ten and the ratios of
    :data:`DEPTH_FACTORS`, each once, without 1."""
    ratios = {round(a / b, 6) for a in DEPTH_FACTORS for b in DEPTH_FACTORS}
    ratios |= {10.0**k for k in (-3, -2, -1, 1, 2, 3)}
    return tuple(sorted(r for r in ratios if abs(np.log(r)) > 0.1))


def hypotheses(mistakes: Sequence[Mistake]) -> list[tuple[Mistake, Hypothesis]]:
    """One hypothesis per way of undoing each of ``mistakes``."""
    out: list[tuple[Mistake, Hypothesis]] = []
    for mistake in mistakes:
        if mistake is Mistake.POSES_INVERTED:
            out.append((mistake, Hypothesis("poses inverted", pose=np.linalg.inv)))
        elif mistake is Mistake.QUATERNION_ORDER:
            out.append((mistake, Hypothesis("quaternion order w x y z", pose=reorder_quaternion)))
        elif mistake is Mistake.BODY_AXES:
            out.append((mistake, Hypothesis("body camera axes", pose=_body_to_optical)))
        elif mistake is Mistake.OPTICAL_AXES:
            out.append((mistake, Hypothesis("optical camera axes", pose=_optical_to_body)))
        elif mistake is Mistake.DEPTH_SCALE:
            out += [(mistake, Hypothesis(f"depth x{s:g}", depth_scale=s)) for s in depth_scales()]
        elif mistake is Mistake.FOCAL_LENGTH:
            out += [(mistake, Hypothesis(f"focal x{f:g}", focal_scale=f)) for f in FOCAL_SCALES]
    return out


def _body_to_optical(pose: np.ndarray) -> np.ndarray:
    return pose @ BODY_FROM_OPTICAL


def _optical_to_body(pose: np.ndarray) -> np.ndarray:
    return pose @ np.linalg.inv(BODY_FROM_OPTICAL)


class Status(StrEnum):
    """What the check concluded."""

    AGREE = "agree"
    """The views agree as given, and no usual mistake reads them better."""
    MISTAKE = "mistake"
    """A usual mistake undone makes the views agree clearly better than as given."""
    DISAGREE = "disagree"
    """The views disagree as given and no usual mistake explains it."""
    UNJUDGED = "unjudged"
    """Too few pairs that moved and overlap (a still camera, a short recording)."""


PASS_AGREE = 0.7
"""Median agreeing share a reading needs to count as consistent. Right readings measured:
0.90 (slambook's real Kinect frames, estimated poses), 0.95-0.98 (the living room at every
and every fifth frame); wrong ones 0.29-0.73 (see the test suite and bench/consistency.py)."""
MARGIN = 0.1
"""How much more of the pixels a mistake undone must agree on than the reading as given
before it is named: noise moves the share by a few hundredths."""
MIN_PAIRS = 4
"""Pair directions that must overlap for a verdict."""
RANGE_M = (0.25, 25.0)
"""Median depth, metres, of a plausible indoor RGB-D recording (sensors' ranges are 0.2 to
10 m; rooms a few metres across): outside it depth is in other units."""


@dataclass(frozen=True)
class Verdict:
    """The check's conclusion, with the figures behind it."""

    status: Status
    given: Agreement
    range_m: float
    """Median depth as given, metres."""
    mistake: Mistake | None = None
    """The mistake whose undoing reads the views best, for :attr:`Status.MISTAKE`."""
    hypothesis: Hypothesis | None = None
    better: Agreement | None = None
    """The agreement with :attr:`mistake` undone."""
    views: int = 0
    pairs: int = 0
    floor: dict[str, object] | None = None
    """:func:`floor_support` of the sample (None: not looked for)."""

    @property
    def passed(self) -> bool:
        return self.status in (Status.AGREE, Status.UNJUDGED)

    def as_json(self) -> dict[str, object]:
        out: dict[str, object] = {
            "status": self.status.value,
            "views": self.views,
            "pairs_picked": self.pairs,
            "median_range_m": None if np.isnan(self.range_m) else round(self.range_m, 3),
            **self.given.as_json(),
            "tolerance": {"relative": AGREE_RELATIVE, "absolute_m": AGREE_ABSOLUTE_M},
        }
        if self.floor is not None:
            out["floor"] = self.floor
        if self.mistake is not None and self.hypothesis is not None and self.better is not None:
            out["likelier"] = {
                "mistake": self.mistake.value,
                "reading": self.hypothesis.name,
                "depth_scale": self.hypothesis.depth_scale,
                "focal_scale": self.hypothesis.focal_scale,
                **self.better.as_json(),
            }
        return out


SCREEN_PAIRS = 12
"""Pairs every hypothesis is first scored on; the best few are then scored on all."""
SCREEN_KEEP = 3
"""Hypotheses kept from the screen by each of its two rankings."""
NOISE_RESIDUAL = 0.01
"""Median relative residual of views that agree as well as sensors allow (1 %): below it, no
reading is called better for its smaller residuals alone."""
RESIDUAL_RATIO = 2.0
COVER = 0.8
"""Share of the pair directions judged as given that a better reading must judge too."""


class _VerdictBase(TypedDict):
    """The fields every :class:`Verdict` of :func:`judge` shares."""

    given: Agreement
    range_m: float
    views: int
    pairs: int


def judge(
    samples: Sequence[DepthSample],
    mistakes: Sequence[Mistake],
    *,
    runs: Sequence[int] | None = None,
    max_pairs: int = 48,
) -> Verdict:
    """The geometry of ``samples`` judged: as given, and with each of ``mistakes`` undone
    (``runs``: as :func:`pick_pairs` takes them)."""
    pairs = pick_pairs(samples, max_pairs, runs)
    given = agreement(samples, pairs, Hypothesis("as given"))
    depth_range = median_range(samples)
    base: _VerdictBase = {
        "given": given,
        "range_m": depth_range,
        "views": len(samples),
        "pairs": len(pairs),
    }
    plausible = RANGE_M[0] <= depth_range <= RANGE_M[1]
    if given.pairs < MIN_PAIRS and plausible:
        return Verdict(Status.UNJUDGED, **base)
    if plausible and given.pairs >= MIN_PAIRS and _unbeatable(given):
        return Verdict(Status.AGREE, **base)  # no reading can be clearly better: none tried
    candidates = [
        (m, h)
        for m, h in hypotheses(mistakes)
        if m is not Mistake.DEPTH_SCALE or RANGE_M[0] <= depth_range * h.depth_scale <= RANGE_M[1]
    ]
    if not plausible:  # depth in other units whatever the poses say: only a scale can fix it
        candidates = [(m, h) for m, h in candidates if m is Mistake.DEPTH_SCALE]
    best = _best(samples, pairs, candidates)
    if best is not None and (not plausible or _clearly_better(best[2], given)):
        mistake, hypothesis, got = best
        if mistake is Mistake.FOCAL_LENGTH:
            hypothesis, got = _refine_focal(samples, pairs, hypothesis, got)
        return Verdict(Status.MISTAKE, **base, mistake=mistake, hypothesis=hypothesis, better=got)
    if given.pairs < MIN_PAIRS:
        return Verdict(Status.UNJUDGED if plausible else Status.DISAGREE, **base)
    if given.agree >= PASS_AGREE and plausible:
        return Verdict(Status.AGREE, **base)
    return Verdict(Status.DISAGREE, **base)


def _best(
    samples: Sequence[DepthSample],
    pairs: Sequence[tuple[int, int]],
    candidates: Sequence[tuple[Mistake, Hypothesis]],
) -> tuple[Mistake, Hypothesis, Agreement] | None:
    """The candidate that reads the views best: every candidate scored on a few pairs, the
    best few by agreeing share and by residual scored on all, the best of those by share."""
    screen = (
        [
            pairs[k]
            for k in np.unique(np.linspace(0, len(pairs) - 1, SCREEN_PAIRS).round().astype(int))
        ]
        if len(pairs) > SCREEN_PAIRS
        else pairs
    )
    first = [(m, h, agreement(samples, screen, h)) for m, h in candidates]
    first = [c for c in first if c[2].pairs]
    by_share = sorted(first, key=lambda c: -c[2].agree)[:SCREEN_KEEP]
    by_residual = sorted(first, key=lambda c: c[2].residual)[:SCREEN_KEEP]
    best = None
    for mistake, hypothesis, _ in {id(c[1]): c for c in by_share + by_residual}.values():
        got = agreement(samples, pairs, hypothesis)
        if got.pairs >= MIN_PAIRS and (best is None or _rank(got) > _rank(best[2])):
            best = (mistake, hypothesis, got)
    return best


def _refine_focal(
    samples: Sequence[DepthSample],
    pairs: Sequence[tuple[int, int]],
    found: Hypothesis,
    got: Agreement,
) -> tuple[Hypothesis, Agreement]:
    """The focal length factor near ``found`` (the search grid's) with the smallest median
    residual, on a grid ten times finer: the value the fix names."""
    step = np.log(FOCAL_GRID_STEP)
    best = (got.residual, found, got)
    for f in np.exp(np.log(found.focal_scale) + np.linspace(-step, step, 11)):
        h = Hypothesis(f"focal x{f:.3g}", focal_scale=float(f))
        a = agreement(samples, pairs, h)
        if a.pairs >= MIN_PAIRS and a.residual < best[0]:
            best = (a.residual, h, a)
    return best[1], best[2]


def _rank(a: Agreement) -> tuple[float, float]:
    return (round(a.agree, 2), -a.residual)


def _unbeatable(given: Agreement) -> bool:
    """Whether no reading can be :func:`_clearly_better` than ``given``, whatever it scores:
    agreeing on more than ``1 - MARGIN`` of the pixels with residuals at sensor noise. Then
    trying the mistakes would change nothing, and the check costs one scoring."""
    return given.agree > 1.0 - MARGIN and given.residual < NOISE_RESIDUAL


def _clearly_better(got: Agreement, given: Agreement) -> bool:
    """Whether a mistake undone reads the views clearly better than as given: consistent
    itself, on at least :data:`COVER` of the pairs that overlap as given (a reading that makes
    the views stop overlapping dodges the evidence rather than explaining it), and either agreeing on :data:`MARGIN` more of the pixels or, agreeing as much,
    with residuals :data:`RESIDUAL_RATIO` times smaller where those as given are above sensor
    noise (:data:`NOISE_RESIDUAL`)."""
    if got.agree < PASS_AGREE or got.pairs < COVER * given.pairs:
        return False
    if given.pairs < MIN_PAIRS or got.agree >= given.agree + MARGIN:
        return True
    return (
        got.agree >= given.agree - MARGIN / 10
        and given.residual >= NOISE_RESIDUAL
        and got.residual * RESIDUAL_RATIO <= given.residual
    )


FLOOR_POINTS = 5_000
"""Depth points the floor is looked for among (evenly taken from the sample)."""
CAMERA_HEIGHT_M = (0.05, 3.0)
"""Metres above the floor a ground robot's or a hand-held camera is held at."""


def floor_support(samples: Sequence[DepthSample]) -> dict[str, object]:
    """Whether the sample's points hold a floor under its cameras, as fuse will look for it
    (:func:`care_maps.geometry.mapframe.estimate_map_frame`): the share of points on it and the
    cameras' median height above it. Depth in other units puts the cameras metres under or
    kilometres over the floor, and a floor missing altogether is what ``care fuse`` would
    ask ``--up-axis`` for: said at ingest, where the depth's units can still be named."""
    from care_maps.geometry.mapframe import FloorNotFoundError, estimate_map_frame
    from care_maps.geometry.planes import along

    clouds = []
    for s in samples:
        points = _points(s, 1.0, 1.0)
        clouds.append(points @ s.pose[:3, :3].T + s.pose[:3, 3])
    points = np.concatenate(clouds) if clouds else np.zeros((0, 3))
    if len(points) > FLOOR_POINTS:
        points = points[np.linspace(0, len(points) - 1, FLOOR_POINTS).astype(int)]
    poses = np.stack([s.pose for s in samples]) if samples else np.zeros((0, 4, 4))
    try:
        frame = estimate_map_frame(points, poses)
    except FloorNotFoundError:
        return {"found": False}
    up = np.asarray(frame.up)
    height = float(np.median(along(poses[:, :3, 3], up) - frame.floor))
    low, high = CAMERA_HEIGHT_M
    return {
        "found": True,
        "share": round(float(frame.floor_fraction), 4),
        "camera_height_m": round(height, 3),
        "plausible": bool(low <= height <= high),
    }
