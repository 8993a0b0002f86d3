"""A TF buffer for a whole recording: chains of static and dynamic transforms, interpolated.

TF for a recording is small (a few transforms per frame), so ingest reads all of it in a
first pass and resolves camera poses in the second. Like tf2: every frame has one parent,
``/tf_static`` transforms hold at all times, dynamic ones are interpolated between their
stamps (linear translation, ``scipy.spatial.transform.Slerp`` rotation) and not extrapolated
beyond ``tolerance_ns`` past the first or last stamp. Unlike tf2, a ``/tf`` transform whose
samples are all one transform (published once, or again and again) is static too
(:meth:`TFBuffer.freeze_unchanging`): drivers and replays send mount chains there, and
kept dynamic such a chain would pose only the views within the tolerance of its stamps.
One sample that nothing else on the camera's chain moves stays moving, though
(:meth:`TFBuffer.thaw`): it is more likely a moving camera's only pose than a mount.

One transform per frame and stamp: the same transform repeated (``/tf_static`` republished,
a message recorded twice) adds nothing, but two different transforms for one (parent,
child, stamp) are refused, naming the topic and the stamp. Which of them holds would decide
the pose of every view near that stamp, and no rule can tell the right one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, NoReturn

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.ingest.decode import StampedTransform

if TYPE_CHECKING:  # scipy's transforms load when a chain is first interpolated: not at start-up
    from scipy.spatial.transform import Rotation, Slerp

__all__ = ["TFBuffer", "Uncovered", "check_transform"]


class Uncovered(StrEnum):
    """Why a view has no pose though TF joins the camera to the world: the moving
    transforms of the chain have no sample within the tolerance of its stamp. The values
    are the views' drop reasons (:attr:`ingest.source.ReadStats.dropped`)."""

    BEFORE_FIRST = "no_pose_before_first_transform"
    """Earlier than the first sample of a moving transform (minus the tolerance)."""
    AFTER_LAST = "no_pose_after_last_transform"
    """Later than the last sample of a moving transform (plus the tolerance)."""
    BETWEEN = "no_pose_gap"
    """After the last sample of one moving transform and before the first of another:
    the chain's transforms cover times that never overlap there."""


def check_transform(tf: StampedTransform, source: str = "TF") -> None:
    """Refuse an impossible transform: a non-finite translation, or a rotation quaternion
    that is non-finite or of (near) zero norm (it has no rotation to normalise to)."""
    where = f"{source} transform {tf.parent!r} -> {tf.child!r} at stamp {tf.stamp_ns} ns"
    if not np.all(np.isfinite(tf.translation)):
        msg = f"{where}: non-finite translation {tf.translation.tolist()}; the recording's poses are corrupt (fix them or pass --pose-source TOPIC)"
        raise IngestError(msg)
    q = np.asarray(tf.rotation, np.float64)
    if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-6:
        msg = f"{where}: rotation quaternion {q.tolist()} is {'non-finite' if not np.all(np.isfinite(q)) else 'zero'}, not a rotation; the recording's poses are corrupt (fix them or pass --pose-source TOPIC)"
        raise IngestError(msg)


@dataclass
class _Edge:
    """All samples of ``parent_from_child`` for one child frame."""

    parent: str
    static: bool
    stamps: list[int] = field(default_factory=list)
    translations: list[np.ndarray] = field(default_factory=list)
    rotations: list[np.ndarray] = field(default_factory=list)
    by_stamp: dict[int, tuple[int, str | None]] = field(default_factory=dict)
    """Stamp -> (index of its sample, the topic it came on), to find a second sample."""
    frozen: bool = False
    """Static since its samples never change (:meth:`TFBuffer.freeze_unchanging`), though
    published as moving."""
    _arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    _slerp: Slerp | None = None

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stamps, translations and rotations sorted by stamp (cached); a stamp has one
        sample (:meth:`TFBuffer.add` keeps one of equal ones and refuses different ones), and
        should two remain the last one received holds."""
        if self._arrays is None:
            stamps = np.asarray(self.stamps, np.int64)
            order = np.argsort(stamps, kind="stable")
            last = np.r_[stamps[order][1:] != stamps[order][:-1], True]  # last of each stamp
            order = order[last]
            self._arrays = (
                stamps[order],
                np.asarray(self.translations, np.float64)[order],
                np.asarray(self.rotations, np.float64)[order],
            )
        return self._arrays

    def rotations_at(self, t: np.ndarray) -> Rotation:
        """The rotations at stamps ``t`` within the samples' span: scipy's ``Slerp`` between
        the samples on either side (built once per edge)."""
        from scipy.spatial.transform import Rotation, Slerp

        stamps, _, rots = self.arrays()
        if len(stamps) == 1:
            return Rotation.from_quat(np.repeat(rots, len(t), axis=0))
        if self._slerp is None:
            self._slerp = Slerp((stamps - stamps[0]).astype(np.float64), Rotation.from_quat(rots))
        return self._slerp((t - stamps[0]).astype(np.float64))

    def at(self, times: np.ndarray, tolerance_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """(N, 4, 4) ``parent_from_child`` at ``times`` and an (N,) mask of those it covers."""
        stamps, trans, rots = self.arrays()
        n = len(times)
        if self.static:
            from scipy.spatial.transform import Rotation

            T = _matrices(trans[-1:], Rotation.from_quat(rots[-1:]))
            return np.repeat(T, n, axis=0), np.ones(n, bool)
        valid = (times >= stamps[0] - tolerance_ns) & (times <= stamps[-1] + tolerance_ns)
        t = np.clip(times, stamps[0], stamps[-1])
        hi = np.clip(np.searchsorted(stamps, t, side="right"), 1, len(stamps) - 1)
        lo = hi - 1
        if len(stamps) == 1:
            hi = lo = np.zeros(n, np.int64)
        span = (stamps[hi] - stamps[lo]).astype(np.float64)
        alpha = np.where(span > 0, (t - stamps[lo]) / np.where(span > 0, span, 1.0), 0.0)
        translation = trans[lo] + alpha[:, None] * (trans[hi] - trans[lo])
        return _matrices(translation, self.rotations_at(t)), valid


_SAME = 1e-9
"""Metres (translation) and quaternion units: closer transforms count as the same one (a
republisher that recomputes a transform may differ in the last bits)."""


_UNCHANGED = 1e-6
"""Metres and quaternion units: samples of one edge this close are one transform
republished (a static chain sent on ``/tf`` by a replay or a driver)."""


def _unchanging(edge: _Edge) -> bool:
    """Whether every sample of ``edge`` is its first one again (within :data:`_UNCHANGED`)."""
    t = np.asarray(edge.translations, np.float64)
    q = np.asarray(edge.rotations, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    gap = np.minimum(np.abs(q - q[0]).max(axis=1), np.abs(q + q[0]).max(axis=1))
    return bool((np.abs(t - t[0]).max(axis=1) <= _UNCHANGED).all() and (gap <= _UNCHANGED).all())


def _same_transform(edge: _Edge, index: int, tf: StampedTransform) -> bool:
    """Whether ``tf`` is the edge's sample ``index`` again (q and -q are one rotation)."""
    t0, q0 = edge.translations[index], edge.rotations[index]
    q0 = q0 / np.linalg.norm(q0)
    q1 = np.asarray(tf.rotation, np.float64) / np.linalg.norm(tf.rotation)
    rotation_gap = min(np.abs(q1 - q0).max(), np.abs(q1 + q0).max())
    return bool(np.abs(tf.translation - t0).max() <= _SAME and rotation_gap <= _SAME)


def _refuse_conflict(
    edge: _Edge, index: int, first_topic: str | None, tf: StampedTransform, topic: str | None
) -> NoReturn:
    """Raise the one line naming both transforms at one stamp and where they came from."""

    def text(translation: np.ndarray, rotation: np.ndarray, where: str | None) -> str:
        on = f" on {where}" if where else ""
        return f"translation {np.asarray(translation).tolist()} rotation {np.asarray(rotation).tolist()}{on}"

    on = f" on {topic}" if topic else ""
    msg = (
        f"TF transform {tf.parent!r} -> {tf.child!r} at stamp {tf.stamp_ns} ns{on}: two "
        f"different transforms at one stamp ({text(edge.translations[index], edge.rotations[index], first_topic)}, "
        f"then {text(tf.translation, tf.rotation, topic)}); TF gives one transform per frame "
        "and stamp, so the poses there are ambiguous (fix the recording's transforms, or pass "
        "--pose-source TOPIC)"
    )
    raise IngestError(msg)


def _matrices(translation: np.ndarray, rotation: Rotation) -> np.ndarray:
    T = np.zeros((len(translation), 4, 4))
    T[:, :3, :3] = rotation.as_matrix()
    T[:, :3, 3] = translation
    T[:, 3, 3] = 1.0
    return T


class TFBuffer:
    """Transforms by child frame; answers ``target_from_source`` at any stamps."""

    def __init__(self) -> None:
        self._edges: dict[str, _Edge] = {}

    def add(self, tf: StampedTransform, *, static: bool, topic: str | None = None) -> None:
        """Add one sample (from ``topic``, for messages); a frame that changes parent is an
        error (TF is a tree), and so is a second, different transform at a stamp the edge
        already has (the same transform again is kept once)."""
        if tf.child is None or tf.child == tf.parent:
            return
        check_transform(tf)
        edge = self._edges.get(tf.child)
        if edge is None:
            edge = self._edges[tf.child] = _Edge(tf.parent, static)
        elif edge.parent != tf.parent:
            msg = f"TF frame {tf.child!r} has two parents, {edge.parent!r} and {tf.parent!r}; TF must be a tree (pick the pose source with --pose-source)."
            raise IngestError(msg)
        edge.static = edge.static and static
        stamp = int(tf.stamp_ns)
        if stamp in edge.by_stamp:
            index, first_topic = edge.by_stamp[stamp]
            if _same_transform(edge, index, tf):
                return
            _refuse_conflict(edge, index, first_topic, tf, topic)
        edge.by_stamp[stamp] = (len(edge.stamps), topic)
        edge.stamps.append(stamp)
        edge.translations.append(tf.translation)
        edge.rotations.append(tf.rotation)
        edge._arrays = edge._slerp = None

    def freeze_unchanging(self) -> list[str]:
        """Make static every edge whose samples are all one transform, wherever it was
        published: a mount chain that a driver, a ``static_transform_publisher`` replay or a
        converted bag sends on ``/tf`` (once, or again and again) is as static as one on
        ``/tf_static``. Kept dynamic, one such sample holds only within the tolerance of its
        stamp, and every view away from it is dropped unposed. Returns the children made
        static."""
        frozen = []
        for child, edge in self._edges.items():
            if not edge.static and _unchanging(edge):
                edge.static = edge.frozen = True
                edge._arrays = edge._slerp = None
                frozen.append(child)
        return sorted(frozen)

    def moving(self, frame: str | None = None) -> list[str]:
        """Children of the edges whose samples change: all of them, or those on ``frame``'s
        chain up to its root (what moves ``frame`` in its tree)."""
        children = self._edges if frame is None else self._chain(frame)[:-1]
        return sorted(c for c in children if not self._edges[c].static)

    def lone(self, frame: str) -> list[str]:
        """Children of the edges on ``frame``'s chain made static from a single sample."""
        return sorted(
            c
            for c in self._chain(frame)[:-1]
            if self._edges[c].frozen and len(self._edges[c].by_stamp) == 1
        )

    def thaw(self, children: list[str]) -> None:
        """Make these frozen edges moving again: one sample that is all TF says of where the
        camera is, with nothing else moving it, is a moving camera's only sample rather
        than a mount, and stretched over the recording it would give every view its pose."""
        for child in children:
            edge = self._edges[child]
            edge.static = edge.frozen = False
            edge._arrays = edge._slerp = None

    def describe_edge(self, child: str) -> str | None:
        """``parent->child`` and whether it moves (None: TF has no transform into ``child``)."""
        edge = self._edges.get(child)
        if edge is None:
            return None
        return f"{'static' if edge.static else 'moving'} transform {edge.parent}->{child}"

    def drop(self, child: str) -> None:
        """Forget the transform into ``child`` (a pose source replaces it)."""
        self._edges.pop(child, None)

    @property
    def frames(self) -> set[str]:
        """Every frame named as a parent or child."""
        return set(self._edges) | {e.parent for e in self._edges.values()}

    def parent(self, frame: str) -> str | None:
        edge = self._edges.get(frame)
        return None if edge is None else edge.parent

    def root(self, frame: str) -> str:
        """The top of the tree holding ``frame``."""
        return self._chain(frame)[-1]

    def _chain(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self._edges:
            chain.append(self._edges[chain[-1]].parent)
            if len(chain) > len(self._edges) + 1:
                msg = f"TF has a cycle through frame {frame!r}; the recording's transforms are inconsistent."
                raise IngestError(msg)
        return chain

    def _up(
        self, chain: list[str], times: np.ndarray, tolerance_ns: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """``chain[-1]_from_chain[0]`` at ``times`` and where every edge covers them."""
        T = np.repeat(np.eye(4)[None], len(times), axis=0)
        valid = np.ones(len(times), bool)
        for child in chain[:-1]:
            edge_T, edge_valid = self._edges[child].at(times, tolerance_ns)
            T = edge_T @ T
            valid &= edge_valid
        return T, valid

    def describe(self) -> str:
        """``child<-parent`` of every edge, for error messages."""
        return ", ".join(f"{e.parent}->{c}" for c, e in sorted(self._edges.items())) or "none"

    def check_connected(self, target: str, source: str) -> None:
        """Raise the error a user can act on when no chain joins ``source`` to ``target``."""
        present = ", ".join(sorted(self.frames)) or "none"
        for role, frame in (("camera", source), ("world", target)):
            if frame not in self.frames:
                msg = f"no transform from camera frame {source!r} to world frame {target!r}: {role} frame {frame!r} is not in TF (frames present: {present}); pass --camera-frame/--world-frame, --pose-source, or --static-pose."
                raise IngestError(msg)
        if self.root(source) != self.root(target):
            msg = f"no transform from camera frame {source!r} to world frame {target!r}: they are in separate TF trees, {self.describe_tree(source)} and {self.describe_tree(target)}; record the transform that joins them, or pass --world-frame or --camera-frame."
            raise IngestError(msg)

    def tree(self, frame: str) -> list[str]:
        """Every frame of the TF tree holding ``frame``, root first."""
        root = self.root(frame)
        return [root, *sorted(f for f in self.frames if f != root and self.root(f) == root)]

    def describe_tree(self, frame: str) -> str:
        """``frame``'s tree for messages: its root and its frames."""
        tree = self.tree(frame)
        return f"the tree of {frame!r} rooted at {tree[0]!r} ({', '.join(tree)})"

    def _joining(self, target: str, source: str) -> list[str]:
        """Children of the edges on the path joining ``source`` to ``target``."""
        self.check_connected(target, source)
        up_source, up_target = self._chain(source), self._chain(target)
        common = next(f for f in up_source if f in set(up_target))
        return up_source[: up_source.index(common)] + up_target[: up_target.index(common)]

    def sample_stamps(self, target: str, source: str) -> np.ndarray:
        """Sorted stamps (ns) of the moving transforms on the chain joining ``source`` to
        ``target``: where TF itself says where ``source`` is (empty: a static chain)."""
        children = self._joining(target, source)
        stamps = [self._edges[c].arrays()[0] for c in children if not self._edges[c].static]
        return np.unique(np.concatenate(stamps)) if stamps else np.zeros(0, np.int64)

    def spans(self, target: str, source: str) -> dict[str, tuple[int, int]]:
        """First and last stamp (ns) of each moving transform joining ``source`` to
        ``target``, by child frame: the poses exist where all of them overlap."""
        spans = {}
        for child in self._joining(target, source):
            edge = self._edges[child]
            if not edge.static:
                stamps = edge.arrays()[0]
                spans[child] = (int(stamps[0]), int(stamps[-1]))
        return spans

    def uncovered(self, target: str, source: str, time: int, tolerance_ns: int = 0) -> Uncovered:
        """Why :meth:`lookup` has no pose at ``time``: before the first or after the last
        sample of the moving transforms, or between two of them that never overlap."""
        spans = self.spans(target, source).values()
        before = any(time < first - tolerance_ns for first, _ in spans)
        after = any(time > last + tolerance_ns for _, last in spans)
        if before and after:
            return Uncovered.BETWEEN
        return Uncovered.AFTER_LAST if after else Uncovered.BEFORE_FIRST

    def lookup(
        self, target: str, source: str, times: np.ndarray, tolerance_ns: int = 0
    ) -> tuple[np.ndarray, np.ndarray]:
        """(N, 4, 4) ``target_from_source`` at ``times`` (ns) and an (N,) mask of valid ones.

        Invalid where a dynamic transform on the chain has no sample within
        ``tolerance_ns`` of the interval it must interpolate over.
        """
        self.check_connected(target, source)
        times = np.atleast_1d(np.asarray(times, np.int64))
        up_source, up_target = self._chain(source), self._chain(target)
        common = next(f for f in up_source if f in set(up_target))
        root_from_source, v1 = self._up(
            up_source[: up_source.index(common) + 1], times, tolerance_ns
        )
        root_from_target, v2 = self._up(
            up_target[: up_target.index(common) + 1], times, tolerance_ns
        )
        return np.linalg.inv(root_from_target) @ root_from_source, v1 & v2
