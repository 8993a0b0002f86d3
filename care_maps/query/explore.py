"""Where to look again: camera poses in free space that look at what the map is least sure of.

A map is unsure of a place in several ways its columns already record (``docs/method.md``):

- **contested**: the best candidates of a class lie in different places with close
  confidence, so a query for it may go either way (per class, the top candidates kept
  :attr:`ExploreConfig.contest_radius` apart; each earns ``p_1 (1 - q_1) q_j / q_1``, with
  ``p_1`` the best confidence and ``q`` the confidences normalised over the kept ones: zero
  for a clear winner, half each for two equal rivals);
- **entropy** of the fused class distribution (the classes disagree in one place);
- **pwkl** and **stderr**: the views disagree (``+inf`` below two views counts as most);
- **few views**: little was seen of it.

Each measure becomes a rank in [0, 1] over the map's *object* cells (those whose top class is
not a room's shell, :data:`care_maps.core.vocab.STRUCTURE_NAMES`: a query asks for objects) and a cell's
uncertainty is their mean (:func:`cell_uncertainty`). Ranks, because the measures live on
scales that share nothing (nats, feature units, view counts) and have heavy tails.

:func:`choose_views` then picks viewpoints greedily: the next target is the uncertain cell
with the most uncertainty left around it (the cell uncertainty pooled by a Gaussian of
:attr:`ExploreConfig.region`), the viewpoint the free cell (with the robot's clearance, and
reachable where the caller says) between :attr:`ExploreConfig.min_range` and
:attr:`ExploreConfig.max_range` of it, with a clear line of sight, at least
:attr:`ExploreConfig.spacing` from the viewpoints already chosen, whose view cone (facing the
target) covers the most uncertainty left, nearer cells counting more. What a chosen view
covers is then counted as seen, so the next one looks elsewhere. The camera stands at the
recording's camera height and looks at the target's top (:func:`look_at`).

Pure functions of arrays: the store is read by :mod:`care_maps.query.explore_store`, drawn by
:mod:`care_maps.query.explore_viz`. Deterministic: no random draw, ties go to the lower cell index.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from care_maps.core.checks import check_numbers
from care_maps.core.config import member
from care_maps.core.errors import QueryError
from care_maps.core.vocab import STRUCTURE_NAMES
from care_maps.fuse.layout import GridLayout
from care_maps.query.confidence import log_confidence
from care_maps.query.goals import GoalConfig
from care_maps.query.map import CandidateMap

__all__ = [
    "ExploreConfig",
    "Uncertainty",
    "Viewpoint",
    "cell_indices",
    "cell_uncertainty",
    "choose_views",
    "contested",
    "look_at",
    "object_cells",
    "rank_scores",
    "raster",
]


class Uncertainty(StrEnum):
    """The measures a place's uncertainty is made of (module docstring)."""

    CONTESTED = "contested"
    """The top candidates of a class lie apart with close confidence."""
    ENTROPY = "entropy"
    """Entropy of the fused class distribution."""
    PWKL = "pwkl"
    """Mean pairwise KL between the views' class distributions."""
    STDERR = "stderr"
    """Standard error of the views' features."""
    FEW_VIEWS = "few_views"
    """Fewer views than elsewhere."""


@dataclass(frozen=True)
class ExploreConfig:
    """How many views ``care explore`` proposes, what they look at and from where."""

    views: int = 8
    """Number of camera poses to propose (fewer when the map holds no more uncertain places
    that free space can see)."""
    measures: tuple[Uncertainty, ...] = tuple(Uncertainty)
    """What counts as uncertain (each a rank over the object cells; a cell's uncertainty is
    their mean)."""
    min_range: float = 0.6
    """Closest (m, floor plane) a viewpoint stands to the place it looks at."""
    max_range: float = 2.5
    """Farthest (m) a viewpoint stands from its target, and the range its view covers."""
    near_range: float = 1.2
    """Range (m) up to which a cell counts fully as seen; beyond, by ``near_range / d``:
    far surfaces are seen on fewer pixels and at grazing angles."""
    fov_deg: float = 60.0
    """Horizontal field of view (degrees) of the camera, for what a view covers."""
    spacing: float = 1.0
    """Least distance (m) between two viewpoints, so the views spread out."""
    region: float = 0.3
    """Sigma (m) of the Gaussian that pools cell uncertainty into places: a target is the
    place with the most uncertainty around it, not one odd cell."""
    camera_height: float | None = None
    """Height (m above the floor) of the camera; default: the recording's median."""
    contest_k: int = 8
    """Candidates per class compared for the ``contested`` measure."""
    contest_radius: float = GoalConfig.reach
    """Distance (m) apart of a class's compared candidates (the grid success radius)."""

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "measures", tuple(member(Uncertainty, m, QueryError, "--measures") for m in
                                    self.measures),
        )  # fmt: skip
        if not self.measures:
            msg = f"--measures: choose at least one of {', '.join(Uncertainty)}"
            raise QueryError(msg)
        positive = {
            "max_range": self.max_range, "near_range": self.near_range, "fov_deg": self.fov_deg,
            "region": self.region, "contest_radius": self.contest_radius,
        }  # fmt: skip
        if self.camera_height is not None:
            positive["camera_height"] = self.camera_height
        check_numbers(
            QueryError, "invalid explore config", positive=positive,
            non_negative={"min_range": self.min_range, "spacing": self.spacing},
            at_least_one={"views": self.views, "contest_k": self.contest_k},
        )  # fmt: skip
        if self.min_range >= self.max_range or self.fov_deg >= 180:
            msg = (
                f"invalid explore config: min_range {self.min_range} must be below max_range "
                f"{self.max_range}, fov_deg {self.fov_deg} below 180"
            )
            raise QueryError(msg)


@dataclass(frozen=True)
class Viewpoint:
    """One proposed view: where the robot stands, where the camera looks, and why."""

    position: tuple[float, float]
    """Map (x, y) of the viewpoint, on the floor."""
    yaw: float
    """Heading (rad, about z) from the viewpoint to the target."""
    camera: np.ndarray
    """(4, 4) optical camera-to-map pose (x right, y down, z forward), looking at the target."""
    target: tuple[float, float, float]
    """Map point looked at: the centre of the target cell, at its top."""
    target_cell: int
    """Map candidate (grid cell id) of the target."""
    uncertainty: float
    """Uncertainty the view covers (the cells' left-over uncertainty, nearer ones counting
    more): how much it is expected to teach the map."""
    cells: int
    """Uncertain cells in its view cone."""


def object_cells(cmap: CandidateMap) -> np.ndarray:
    """(N,) bool: cells whose top class is an object, not a room's shell (wall, floor...)."""
    shell = np.array([name.strip().lower() in STRUCTURE_NAMES for name in cmap.vocabulary])
    if cmap.num_candidates == 0 or cmap.top_classes.shape[1] == 0:
        return np.zeros(cmap.num_candidates, bool)
    return ~shell[cmap.top_classes[:, 0].astype(np.int64)]


def rank_scores(values: np.ndarray) -> np.ndarray:
    """``values`` as ranks in [0, 1]: the least 0, the greatest 1, ties sharing the higher
    rank (``+inf`` is the greatest); all equal: all 0."""
    values = np.asarray(values, np.float64)
    if values.size < 2:
        return np.zeros(values.shape)
    at_most = np.searchsorted(np.sort(values), values, side="right")  # scipy's "max" rank
    rank = (at_most - 1) / (values.size - 1)
    return np.where(values == values.min(), 0.0, rank)


def _spread_picks(xy: np.ndarray, order: np.ndarray, k: int, radius: float) -> list[int]:
    """The first ``k`` of ``order`` (candidate ids, best first) kept ``radius`` apart."""
    picks: list[int] = []
    left = order
    while len(left) and len(picks) < k:
        best = int(left[0])
        picks.append(best)
        far = np.hypot(*(xy[left] - xy[best]).T) > radius
        left = left[far]
    return picks


def contested(cmap: CandidateMap, keep: np.ndarray, k: int, radius: float) -> np.ndarray:
    """(N,) how much each cell is a contested answer of some class (module docstring), over
    the object classes and the cells of ``keep``."""
    out = np.zeros(cmap.num_candidates)
    ids = np.flatnonzero(keep)
    if k < 2 or len(ids) < 2:
        return out
    classes = [
        y for y, name in enumerate(cmap.vocabulary) if name.strip().lower() not in STRUCTURE_NAMES
    ]
    xy = cmap.positions[ids, :2].astype(np.float64)
    pool = min(len(ids), 64 * k)  # enough to find k places a radius apart in any real map
    for lo in range(0, len(classes), 32):  # (32, N) rows at a time: bounded memory
        rows = log_confidence(cmap, np.array(classes[lo : lo + 32]))[:, ids]
        for row in rows:
            top = np.argpartition(-row, pool - 1)[:pool] if pool < len(row) else np.arange(len(row))
            top = top[np.lexsort((top, -row[top]))]  # best first, ties by lower id
            picks = _spread_picks(xy, top, k, radius)
            p = np.exp(row[picks].astype(np.float64))
            if len(picks) < 2 or p.sum() <= 0:
                continue
            q = p / p.sum()
            out[ids[picks]] += p[0] * (1.0 - q[0]) * q / q[0]
    return out


def cell_uncertainty(
    cmap: CandidateMap, config: ExploreConfig | None = None, keep: np.ndarray | None = None
) -> np.ndarray:
    """(N,) uncertainty of each cell in [0, 1]: the mean rank of ``config.measures`` over
    the object cells (:func:`object_cells`, or ``keep``); 0 elsewhere."""
    config = config or ExploreConfig()
    keep = object_cells(cmap) if keep is None else np.asarray(keep, bool)
    out = np.zeros(cmap.num_candidates)
    if not keep.any():
        return out
    columns = {
        Uncertainty.ENTROPY: lambda: cmap.entropy,
        Uncertainty.PWKL: lambda: cmap.pwkl,
        Uncertainty.STDERR: lambda: cmap.stderr,
        Uncertainty.FEW_VIEWS: lambda: -cmap.num_views.astype(np.float64),
        Uncertainty.CONTESTED: lambda: contested(
            cmap, keep, config.contest_k, config.contest_radius
        ),
    }
    for measure in config.measures:
        out[keep] += rank_scores(np.asarray(columns[measure](), np.float64)[keep])
    return out / len(config.measures)


def cell_indices(layout: GridLayout, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ix, iy) of the cells whose centres are ``xy`` (N, 2) map metres."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    cell = np.rint((xy - np.asarray(layout.origin)) / layout.cell_size - 0.5).astype(np.int64)
    return cell[:, 0], cell[:, 1]


def raster(layout: GridLayout, xy: np.ndarray, values: np.ndarray, fill: float = 0.0):
    """(nx, ny) raster of per-cell ``values`` at cell centres ``xy`` (``fill`` elsewhere)."""
    out = np.full(layout.shape, fill, np.float64)
    ix, iy = cell_indices(layout, xy)
    ok = (ix >= 0) & (ix < layout.shape[0]) & (iy >= 0) & (iy < layout.shape[1])
    out[ix[ok], iy[ok]] = np.asarray(values, np.float64)[ok]
    return out


def look_at(eye: npt.ArrayLike, target: npt.ArrayLike) -> np.ndarray:
    """(4, 4) optical camera-to-map pose (x right, y down, z forward) at ``eye`` looking at
    ``target`` with no roll (x stays level); straight down when ``target`` lies below."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    forward = target - eye
    forward /= max(np.linalg.norm(forward), 1e-12)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-9:  # looking straight down or up: x along map x
        right = np.array([1.0, 0.0, 0.0]) if forward[2] < 0 else np.array([-1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, np.cross(forward, right), forward
    pose[:3, 3] = eye
    return pose


@dataclass(frozen=True)
class _Floor:
    """What :func:`choose_views` works on, as rasters of the grid."""

    layout: GridLayout
    interest: np.ndarray
    """(nx, ny) uncertainty left to see."""
    heights: np.ndarray
    """(nx, ny) top of each cell (m; 0 unobserved): what may block a line of sight."""
    stand: np.ndarray
    """(M, 2) map (x, y) of the cells a viewpoint may stand on."""

    def centres(self, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
        size, (ox, oy) = self.layout.cell_size, self.layout.origin
        return np.stack([ox + (ix + 0.5) * size, oy + (iy + 0.5) * size], axis=-1)

    def clear_sight(self, eyes: np.ndarray, target: np.ndarray, height: float) -> np.ndarray:
        """(M,) bool: nothing rises above the sight line from each eye (at ``height``) to
        ``target`` (x, y, z), cells within two cell sizes of the target aside."""
        size = self.layout.cell_size
        dist = np.hypot(*(eyes - target[:2]).T)
        steps = max(int(np.ceil(dist.max() / (size / 2))), 1) if len(eyes) else 1
        t = np.linspace(0.0, 1.0, steps + 1)[None, :]
        px = eyes[:, :1] + (target[0] - eyes[:, :1]) * t
        py = eyes[:, 1:] + (target[1] - eyes[:, 1:]) * t
        line = height + (target[2] - height) * t
        ix = np.floor((px.reshape(-1) - self.layout.origin[0]) / size).astype(np.int64)
        iy = np.floor((py.reshape(-1) - self.layout.origin[1]) / size).astype(np.int64)
        nx, ny = self.layout.shape
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        top = np.zeros(ix.shape)
        top[inside] = self.heights[ix[inside], iy[inside]]
        top = top.reshape(px.shape)
        near_target = (dist[:, None] * (1 - t)) <= 2 * size
        return ~((top > line + 1e-6) & ~near_target).any(axis=1)


def _coverage(
    floor: _Floor, eyes: np.ndarray, target: np.ndarray, config: ExploreConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(M,) uncertainty each eye's view cone (facing ``target``) covers, nearer cells counting
    more, and (M,) how many uncertain cells it holds."""
    ix, iy = np.nonzero(floor.interest > 0)
    cells = floor.centres(ix, iy)
    reach = np.hypot(*(cells - target[:2]).T) <= 2 * config.max_range
    cells, weight = cells[reach], floor.interest[ix[reach], iy[reach]]
    gain, count = np.zeros(len(eyes)), np.zeros(len(eyes), np.int64)
    half = math.radians(config.fov_deg) / 2
    block = max(1, (1 << 21) // max(len(cells), 1))  # (block, cells) pairs: bounded memory
    for lo in range(0, len(eyes), block):
        eye = eyes[lo : lo + block, None, :]
        look = target[:2] - eye[:, 0]
        look /= np.maximum(np.linalg.norm(look, axis=1, keepdims=True), 1e-12)
        rel = cells[None] - eye
        dist = np.linalg.norm(rel, axis=2)
        cos = np.einsum("mkc,mc->mk", rel, look) / np.maximum(dist, 1e-12)
        seen = (dist <= config.max_range) & (cos >= math.cos(half))
        clarity = np.minimum(1.0, config.near_range / np.maximum(dist, 1e-12))
        gain[lo : lo + block] = (seen * clarity * weight[None]).sum(axis=1)
        count[lo : lo + block] = seen.sum(axis=1)
    return gain, count


def _seen_by(floor: _Floor, view: Viewpoint, config: ExploreConfig) -> np.ndarray:
    """(nx, ny) bool: the cells in ``view``'s cone, within range."""
    nx, ny = floor.layout.shape
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    rel = floor.centres(ix, iy) - np.asarray(view.position)
    dist = np.hypot(rel[..., 0], rel[..., 1])
    look = np.array([math.cos(view.yaw), math.sin(view.yaw)])
    cos = (rel @ look) / np.maximum(dist, 1e-12)
    return (dist <= config.max_range) & (cos >= math.cos(math.radians(config.fov_deg) / 2))


def _pooled(floor: _Floor, config: ExploreConfig) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    sigma = config.region / floor.layout.cell_size
    pooled = gaussian_filter(floor.interest, sigma, mode="constant", truncate=3.0)
    return np.where(floor.interest > 0, pooled, 0.0)  # a target is an uncertain cell itself


def _best_view(
    floor: _Floor, target: np.ndarray, chosen: list[Viewpoint], height: float,
    config: ExploreConfig, target_cell: int,
) -> Viewpoint | None:  # fmt: skip
    """The viewpoint that sees most of what is left around ``target`` (None: none can)."""
    dist = np.hypot(*(floor.stand - target[:2]).T)
    ok = (dist >= config.min_range) & (dist <= config.max_range)
    for view in chosen:
        ok &= np.hypot(*(floor.stand - np.asarray(view.position)).T) >= config.spacing
    eyes = floor.stand[ok]
    if not len(eyes):
        return None
    eyes = eyes[floor.clear_sight(eyes, target, height)]
    if not len(eyes):
        return None
    gain, count = _coverage(floor, eyes, target, config)
    best = int(np.argmax(gain))  # ties: the first, the lower cell
    eye = eyes[best]
    yaw = math.atan2(target[1] - eye[1], target[0] - eye[0])
    return Viewpoint(
        (float(eye[0]), float(eye[1])), yaw, look_at([eye[0], eye[1], height], target),
        (float(target[0]), float(target[1]), float(target[2])), target_cell,
        float(gain[best]), int(count[best]),
    )  # fmt: skip


def choose_views(
    interest: np.ndarray,
    heights: np.ndarray,
    stand: np.ndarray,
    layout: GridLayout,
    *,
    camera_height: float,
    config: ExploreConfig | None = None,
    cell_ids: np.ndarray | None = None,
) -> list[Viewpoint]:
    """Up to ``config.views`` viewpoints that look at the most of ``interest`` (module
    docstring).

    Args:
        interest: (nx, ny) uncertainty of each cell (0: nothing to learn there).
        heights: (nx, ny) top of each cell in metres (0 where unobserved).
        stand: (nx, ny) bool, the cells a viewpoint may stand on (free, with the robot's
            clearance, reachable).
        layout: the grid the rasters are of.
        camera_height: metres above the floor of the camera.
        cell_ids: (nx, ny) map candidate of each cell (-1: none), for
            :attr:`Viewpoint.target_cell`.
    """
    config = config or ExploreConfig()
    shape = tuple(layout.shape)
    for name, array in (("interest", interest), ("heights", heights), ("stand", stand)):
        if np.shape(array) != shape:
            msg = f"{name} raster of shape {np.shape(array)}, the grid's is {shape}"
            raise QueryError(msg)
    ix, iy = np.nonzero(np.asarray(stand, bool))
    step = max(1, round(0.1 / layout.cell_size))  # viewpoints on a lattice of about 10 cm
    lattice = (ix % step == 0) & (iy % step == 0)
    # no cells to stand on yet: ``base`` is only for the lattice's centres
    base = _Floor(
        layout, np.array(interest, np.float64), np.asarray(heights, np.float64), np.empty((0, 2))
    )
    floor = _Floor(layout, base.interest, base.heights, base.centres(ix[lattice], iy[lattice]))
    views: list[Viewpoint] = []
    for _ in range(50 * config.views):  # each round adds a view or clears a target
        if len(views) >= config.views or not (floor.interest > 0).any():
            break
        pooled = _pooled(floor, config)
        tx, ty = np.unravel_index(int(np.argmax(pooled)), shape)
        if pooled[tx, ty] <= 0:
            break
        xy = floor.centres(np.array(tx), np.array(ty))
        target = np.array([xy[0], xy[1], min(float(floor.heights[tx, ty]), camera_height)])
        cell = -1 if cell_ids is None else int(cell_ids[tx, ty])
        view = _best_view(floor, target, views, camera_height, config, cell)
        if view is None:  # nothing can see this place: leave it
            gone = np.hypot(*(floor.centres(*np.indices(shape)) - xy).transpose(2, 0, 1))
            floor.interest[gone <= 2 * config.region] = 0.0
            continue
        views.append(view)
        floor.interest[_seen_by(floor, view, config)] = 0.0
    return views
