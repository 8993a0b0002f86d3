"""RANSAC plane fitting that finds the same plane on every machine, run and thread count.

open3d's ``segment_plane`` draws its hypotheses on an OpenMP pool: with the same seed it
returns a different plane (and inlier count) with one thread or two, and from one run to the
next. The floor of the map frame and the structure planes of the geometric proposals came
from it, so an instance map built in a Ray worker differed from the serial run's, and a test
comparing two frame conventions of one recording failed now and then. Here every hypothesis
is drawn from one seeded numpy generator in batches of a fixed order, scored by its inlier
count (an integer, the same however the scoring is chunked: three products and a sum per
point), the first of the best wins, and the winner is refined by a least-squares fit to its
inliers, as open3d does. Ranking on a random subset of the points first and stopping once
enough triples were drawn (open3d's own rule) keeps it within a few times open3d's time
on one thread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Plane", "along", "fit_plane"]

_CHUNK = 4_000_000
"""Point-hypothesis distances held at once while scoring (~32 MB of float64)."""

_SCORE_POINTS = 4096
"""Hypotheses are ranked by their inliers among this many random points of the cloud."""

_BATCH = 64
"""Hypotheses drawn and ranked at a time; drawing stops between batches."""

_FINALISTS = 16
"""The best-ranked hypotheses whose inliers are then counted on every point."""


@dataclass(frozen=True)
class Plane:
    """``normal . x + offset = 0``, with a unit normal whose largest component is positive.

    Attributes:
        normal: (3,) float64 unit normal.
        offset: signed offset along the normal.
        inliers: int64 indices of the points within the fit distance of the refined plane.
    """

    normal: np.ndarray
    offset: float
    inliers: np.ndarray

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Absolute distance of each point to the plane."""
        return np.abs(along(points, self.normal) + self.offset)


def along(points: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """``points @ axis``, or ``points @ axes`` for (3, k) axes, without BLAS: a threaded BLAS
    may round a product differently with another thread count (edge tiles take another
    kernel), and a point on the fit distance would then flip in or out."""
    p = np.asarray(points, np.float64)
    a = np.asarray(axis, np.float64)
    if a.ndim == 1:
        return p[:, 0] * a[0] + p[:, 1] * a[1] + p[:, 2] * a[2]
    return p[:, 0, None] * a[0] + p[:, 1, None] * a[1] + p[:, 2, None] * a[2]


def _canonical(normal: np.ndarray, offset: float) -> tuple[np.ndarray, float]:
    sign = 1.0 if normal[int(np.argmax(np.abs(normal)))] >= 0 else -1.0
    return normal * sign, offset * sign


def _least_squares(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The total-least-squares plane of ``points``: the centroid and the covariance's
    eigenvector of smallest eigenvalue."""
    centre = points.mean(axis=0)
    centred = points - centre
    cov = np.einsum("ni,nj->ij", centred, centred)  # no BLAS: one summation order
    _, vectors = np.linalg.eigh(cov)
    normal = vectors[:, 0]
    return _canonical(normal, -float(normal @ centre))


def fit_plane(
    points: np.ndarray,
    distance: float,
    iterations: int,
    rng: np.random.Generator,
    *,
    confidence: float = 0.99999999,
) -> Plane | None:
    """The plane with most points within ``distance``, from at most ``iterations`` triples.

    Hypotheses are drawn and scored in batches, in a fixed order, on a random subset of
    :data:`_SCORE_POINTS` points; drawing stops once ``confidence`` that a triple of inliers
    of the best plane so far was drawn is reached (open3d's rule). The best
    :data:`_FINALISTS` are then counted on every point, the first of the best wins, and it is
    refined. Returns ``None`` for fewer than three points or when every triple is
    degenerate (collinear or repeated points).
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    n = len(points)
    if n < 3:
        return None
    subset = points if n <= _SCORE_POINTS else points[rng.choice(n, _SCORE_POINTS, False)]
    normals_seen: list[np.ndarray] = []
    offsets_seen: list[np.ndarray] = []
    scores: list[np.ndarray] = []
    drawn, best = 0, 0
    while drawn < iterations:
        size = min(_BATCH, iterations - drawn)
        drawn += size
        normals, offsets = _hypotheses(points, rng.integers(0, n, size=(size, 3)))
        if len(normals) == 0:
            continue
        counts = _count(subset, normals, offsets, distance)
        normals_seen.append(normals)
        offsets_seen.append(offsets)
        scores.append(counts)
        best = max(best, int(counts.max()))
        share = best / len(subset)
        if share >= 1.0 or drawn >= _needed(share, confidence):
            break
    if not scores:
        return None
    normals, offsets = np.concatenate(normals_seen), np.concatenate(offsets_seen)
    score = np.concatenate(scores)
    finalists = np.argsort(-score, kind="stable")[:_FINALISTS]  # stable: draw order on ties
    exact = _count(points, normals[finalists], offsets[finalists], distance)
    winner = int(finalists[int(np.argmax(exact))])  # the first finalist of the best
    normal, offset = _canonical(normals[winner], float(offsets[winner]))
    inliers = np.flatnonzero(np.abs(along(points, normal) + offset) <= distance)
    if len(inliers) >= 3:
        refined_normal, refined_offset = _least_squares(points[inliers])
        refined = np.flatnonzero(np.abs(along(points, refined_normal) + refined_offset) <= distance)
        if len(refined) >= len(inliers):  # keep the refinement only where it explains more
            normal, offset, inliers = refined_normal, refined_offset, refined
    return Plane(normal, offset, inliers.astype(np.int64))


def _hypotheses(points: np.ndarray, triples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals and offsets of the planes through each non-degenerate triple."""
    a, b, c = points[triples[:, 0]], points[triples[:, 1]], points[triples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-12
    normals = normals[ok] / norms[ok, None]
    return normals, -np.einsum("ij,ij->i", normals, a[ok])


def _count(points: np.ndarray, normals: np.ndarray, offsets: np.ndarray, distance: float):
    """Points within ``distance`` of each plane (an exact integer, however it is chunked)."""
    counts = np.zeros(len(normals), np.int64)
    step = max(1, _CHUNK // max(len(points), 1))
    for s in range(0, len(normals), step):
        d = np.abs(along(points, normals[s : s + step].T) + offsets[s : s + step])
        counts[s : s + step] = np.count_nonzero(d <= distance, axis=0)
    return counts


def _needed(share: float, confidence: float) -> float:
    """Triples to draw for ``confidence`` that one is all inliers of a plane holding
    ``share`` of the points."""
    hit = share**3
    if hit <= 0.0:
        return float("inf")
    if hit >= 1.0:
        return 0.0
    return math.log(1.0 - confidence) / math.log(1.0 - hit)
