"""The ``labels`` encoder: the perception model (:mod:`care_maps.world.perception.model`) applied to a
recording's class and instance images (:mod:`care_maps.world.perception` explains the mechanisms).

Registered as the ``care_maps.core.encoders`` entry point ``labels`` (``pyproject.toml``), so the
core finds it by name without importing the sample world.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

from care_maps.core.encoders.base import Encoder, EncoderOptions, RecordingContext, l2_normalise
from care_maps.core.encoders.sentence import DIM, SentenceBackend, SentenceModel, sentence_model
from care_maps.core.errors import EncoderError
from care_maps.core.frames import Frame
from care_maps.core.vocab import STRUCTURE_NAMES
from care_maps.world.perception.counters import gaussian, uniform
from care_maps.world.perception.model import (
    PerceptionModel,
    SimilarityModel,
    perception_model,
    recorded_perception,
)

__all__ = ["LabelsEncoder"]


class LabelsEncoder(Encoder):
    """Simulated VLM features from a recording's class and instance images.

    Reads ``options.perception`` (a :class:`~care_maps.world.perception.model.PerceptionPreset`,
    optionally with overrides), ``options.seed``
    (the biases and noise), and ``options.weights``: ``"hashed"`` for the dependency-free
    text embeddings, a sentence-transformers BERT model directory, or None for the bundled
    all-MiniLM-L6-v2 (falling back to hashed vectors if it is not installed).
    """

    name = "labels"
    dim = DIM
    supports_crops = False

    def __init__(self, options: EncoderOptions | None = None, model: PerceptionModel | None = None):
        options = options or EncoderOptions()
        self.spec: str | None = None
        if model is None:
            self.spec = str(options.perception)
            model, _ = perception_model(self.spec)
        self.model = model
        self.scene_seed: int | None = None
        self.scene_classes: tuple[str, ...] = ()
        self.seed = int(options.seed)
        if options.weights == "hashed":
            self.text_model: SentenceModel = sentence_model(SentenceBackend.HASHED)
        elif options.weights:
            if not Path(options.weights).is_dir():
                msg = f"labels encoder: --weights {options.weights}: not a model directory (or 'hashed')"
                raise EncoderError(msg)
            self.text_model = sentence_model(SentenceBackend.MINILM, str(options.weights))
        else:
            self.text_model = sentence_model(SentenceBackend.AUTO)
        self.version = f"1+{self.text_model.backend}"
        self.label_names: tuple[str, ...] = ()

    # -- text ----------------------------------------------------------------------------

    def encode_text(self, names: Sequence[str]) -> np.ndarray:
        return self.text_model.embed(list(names))

    # -- recording -----------------------------------------------------------------------

    def prepare(self, context: RecordingContext) -> None:
        """Take the perception model the sample world recorded (with ``--perception
        default``), embed the recording's class names and fix each class's confusers."""
        record = recorded_perception(context.source) if context.source else {}
        if self.spec is not None:
            self.model, _ = perception_model(self.spec, record.get("perception"))
        seed = record.get("scene_seed")
        self.scene_seed = int(seed) if isinstance(seed, int) else None
        self.scene_classes = tuple(record.get("scene_classes") or ())
        self.set_label_names(context.label_names, source=str(context.source))

    def set_label_names(self, names: Sequence[str], source: str = "recording") -> None:
        """Class names indexed by the ``class`` image; what :meth:`prepare` does."""
        names = tuple(names)
        if not names:
            msg = (
                f"{source}: no class names (/care/class_names); the labels encoder needs a "
                "sample-world recording (`care sample make`); use --encoder clip for others"
            )
            raise EncoderError(msg)
        self.label_names = names
        self.text = self.text_model.embed(names)
        n = len(names)
        self.is_object = np.array([nm.lower() not in STRUCTURE_NAMES for nm in names])
        sim = self.text @ self.text.T
        allowed = self.is_object[None, :] & ~np.eye(n, dtype=bool)
        masked = np.where(allowed, sim, -np.inf)
        self.nearest = np.where(allowed.any(1), np.argmax(masked, axis=1), np.arange(n))
        tau = max(self.model.confusion_temperature, 1e-6)
        logits = np.where(allowed, (sim - sim.max(1, keepdims=True)) / tau, -np.inf)
        weights = np.exp(logits)
        weights[~allowed.any(1)] = np.eye(n)[~allowed.any(1)]
        self.confusion_cdf = np.cumsum(weights / weights.sum(1, keepdims=True), axis=1)
        # exactly round(rate * object classes) classes, the first by a seeded hash order
        crc = np.array([zlib.crc32(nm.encode()) for nm in names], np.uint64)
        pool = self.is_object
        draw = uniform(self.seed, crc, 11)
        if self.model.class_bias_per_scene:
            scene = self.scene_seed if self.scene_seed is not None else zlib.crc32(source.encode())
            draw = uniform(self.seed, crc, 12, np.uint64(scene & 0xFFFFFFFFFFFFFFFF))
            present = set(self.scene_classes)
            if present:
                pool = pool & np.array([nm in present for nm in names])
        order = np.argsort(np.where(pool, draw, np.inf))
        n_biased = round(self.model.class_bias_rate * int(pool.sum()))
        self.class_biased = np.zeros(n, bool)
        self.class_biased[order[:n_biased]] = True
        if self.model.similarity_model is SimilarityModel.CLIP_LIKE:
            self._clip_geometry()

    def _clip_geometry(self) -> None:
        """The fixed directions of the CLIP-like similarity: an orthonormal basis of the
        class texts' span, the modality-gap direction (a seeded random unit vector with that
        span projected out) and the common text direction (the normalised mean text)."""
        text = np.asarray(self.text, np.float64)
        basis, _ = np.linalg.qr(text.T)
        rank = int(np.linalg.matrix_rank(text))
        self.text_basis = basis[:, :rank]
        zero = np.zeros(1, np.uint64)
        self.gap = self._off_text(gaussian(self.seed, zero, zero, 41, DIM))[0]
        mean = text.mean(0)
        self.common = mean / max(float(np.linalg.norm(mean)), 1e-12)

    def _off_text(self, vectors: np.ndarray) -> np.ndarray:
        """``vectors`` with the span of the class texts projected out, unit length (a
        vector inside the span, which only a vocabulary of ``DIM`` or more names allows,
        is kept as it is, normalised)."""
        off = vectors - (vectors @ self.text_basis) @ self.text_basis.T
        small = np.linalg.norm(off, axis=-1) < 1e-6 * np.linalg.norm(vectors, axis=-1)
        return l2_normalise(np.where(small[:, None], vectors, off))

    # -- persistent bias -----------------------------------------------------------------

    def biased(self, instance_ids: np.ndarray, class_ids: np.ndarray) -> np.ndarray:
        """(N,) bool: is each (instance, true class) perceived as another class in every view."""
        self._need_names()
        inst = np.asarray(instance_ids, np.int64)
        cls = np.asarray(class_ids, np.int64)
        own = uniform(self.seed, inst.astype(np.uint64), 7) < self.model.instance_bias_rate
        return (inst > 0) & self.is_object[cls] & (own | self.class_biased[cls])

    def perceived_class(self, instance_ids: np.ndarray, class_ids: np.ndarray) -> np.ndarray:
        """(N,) class id each instance is persistently perceived as (its own if unbiased)."""
        cls = np.asarray(class_ids, np.int64)
        return np.where(self.biased(instance_ids, cls), self.nearest[cls], cls)

    # -- images --------------------------------------------------------------------------

    def encode_views(self, frames: Sequence[Frame]) -> np.ndarray:
        self._need_names()
        if not frames:
            return np.zeros((0, 1, 1, DIM), np.float32)
        shapes = {(f.height, f.width) for f in frames}
        if len(shapes) > 1:
            return np.concatenate([self.encode_views([f]) for f in frames])
        for f in frames:
            for key in ("instance", "class"):
                if key not in f.extras:
                    msg = (
                        f"view at stamp {f.stamp_ns}: no {key!r} label image; the labels "
                        "encoder needs sample-world recordings (/camera/instance, /camera/class)"
                    )
                    raise EncoderError(msg)
        return self._encode_batch(frames)

    def _encode_batch(self, frames: Sequence[Frame]) -> np.ndarray:
        m = self.model
        B = len(frames)
        H, W = frames[0].height, frames[0].width
        fh, fw = max(1, round(H / m.stride)), max(1, round(W / m.stride))
        n_cell = fh * fw
        inst = np.stack([f.extras["instance"] for f in frames]).astype(np.int64)
        cls = np.stack([f.extras["class"] for f in frames]).astype(np.int64)
        if cls.max() >= len(self.label_names):
            msg = (
                f"class id {int(cls.max())} in a class image but only {len(self.label_names)} "
                "class names on /care/class_names"
            )
            raise EncoderError(msg)
        stamps = np.array([int(f.stamp_ns) for f in frames], np.uint64)

        # Segments: an instance (id > 0) or a structure class (instance 0) of one view,
        # found by counting keys (O(pixels), no sort); numbered contiguously per view.
        n_cls = len(self.label_names)
        span = _INSTANCE_SPAN + n_cls
        key = np.where(inst > 0, inst, _INSTANCE_SPAN + cls)
        del inst  # per-pixel arrays of the whole batch: each one held costs 8 bytes a pixel
        key += np.arange(B, dtype=np.int64)[:, None, None] * span
        key = key.ravel()
        present = np.flatnonzero(np.bincount(key, minlength=B * span))
        lut = np.zeros(B * span, np.int64)
        lut[present] = np.arange(len(present))
        inv = lut[key]
        del key
        S = len(present)
        seg_view = present // span
        seg_inst = np.where(present % span < _INSTANCE_SPAN, present % span, 0)
        seg_cls = np.zeros(S, np.int64)
        seg_cls[inv] = cls.ravel()
        del cls
        first = np.searchsorted(seg_view, np.arange(B))
        local = inv - first[seg_view[inv]]
        s_max = int(np.bincount(seg_view, minlength=B).max())

        depth = np.stack([f.depth_m for f in frames]).astype(np.float64)
        depth[~np.isfinite(depth)] = 0.0
        level = self._noise_level(frames, inv, S, depth, H, W)
        del depth
        vectors = self._segment_vectors(
            seg_view, seg_inst, seg_cls, stamps, level, np.bincount(inv, minlength=S)
        )

        # Cell mixtures: pixel counts per (view, cell, local segment), area-normalised.
        rows = (np.arange(H) * fh) // H
        cols = (np.arange(W) * fw) // W
        cell = (rows[:, None] * fw + cols[None, :]).ravel()
        flat_cell = (np.arange(B)[:, None] * n_cell + cell[None, :]).ravel()
        flat_cell *= s_max
        flat_cell += local
        del local
        counts = np.bincount(flat_cell, minlength=B * n_cell * s_max).reshape(B, n_cell, s_max)
        del flat_cell
        area = np.bincount(inv, minlength=S).astype(np.float64)
        seg_area = np.zeros((B, s_max))
        seg_area[seg_view, np.arange(S) - first[seg_view]] = area
        weight = counts / np.maximum(seg_area, 1.0)[:, None, :] ** m.area_exponent
        weight /= np.maximum(weight.sum(-1, keepdims=True), 1e-12)
        if m.bleed > 0:
            grid = weight.reshape(B, fh, fw, s_max)
            blurred = gaussian_filter(
                grid, sigma=(0, m.bleed_sigma, m.bleed_sigma, 0), mode="nearest"
            )
            weight = ((1 - m.bleed) * grid + m.bleed * blurred).reshape(B, n_cell, s_max)
        seg_vec = np.zeros((B, s_max, DIM))
        seg_vec[seg_view, np.arange(S) - first[seg_view]] = vectors
        feats = np.matmul(weight.astype(np.float32), seg_vec.astype(np.float32))
        # noise and normalisation in place: the (B, cells, d) maps are the largest arrays of
        # the batch, and a copy per step tripled its peak memory (one generator per view
        # stamp keeps the noise of a view the same in any batch)
        if m.cell_noise > 0:
            for view, stamp in zip(feats, stamps, strict=True):
                noise = np.random.default_rng([self.seed, int(stamp), 3]).standard_normal(
                    (n_cell, DIM), dtype=np.float32
                )
                view += m.cell_noise * noise / np.sqrt(DIM)
        norm = np.linalg.norm(feats, axis=-1, keepdims=True)
        feats /= np.where(norm > 0, norm, 1.0)
        return feats.reshape(B, fh, fw, DIM)

    def _noise_level(
        self, frames: Sequence[Frame], inv: np.ndarray, S: int, depth: np.ndarray, H: int, W: int
    ) -> np.ndarray:
        """(S,) view-dependent noise level of every segment, in [0, 1]."""
        m = self.model
        valid = (depth > 0).ravel()
        n_valid = np.bincount(inv, weights=valid, minlength=S)
        z_mean = np.bincount(inv, weights=depth.ravel(), minlength=S) / np.maximum(n_valid, 1)
        # surface angles on every other pixel: a mean over a segment needs no more
        sub = depth[:, ::2, ::2]
        cos = _view_cosines(frames, sub, step=2).ravel()
        inv_sub = inv.reshape(depth.shape)[:, ::2, ::2].ravel()
        valid_sub = (sub > 0).ravel()
        n_sub = np.bincount(inv_sub, weights=valid_sub, minlength=S)
        cos_mean = np.bincount(inv_sub, weights=np.where(valid_sub, cos, 0.0), minlength=S)
        cos_mean = np.where(n_sub > 0, cos_mean / np.maximum(n_sub, 1), 1.0)
        border = np.zeros((H, W), bool)
        border[[0, -1], :] = True
        border[:, [0, -1]] = True
        on_border = np.broadcast_to(border, depth.shape).ravel()
        area = np.bincount(inv, minlength=S).astype(np.float64)
        trunc = np.minimum(1.0, np.bincount(inv, weights=on_border, minlength=S) / np.sqrt(area))
        small = (
            np.clip(1.0 - area / (m.small_fraction * H * W), 0.0, 1.0)
            if m.small_fraction > 0
            else 0.0
        )
        level = (
            m.base_noise
            + m.distance_gain * np.maximum(0.0, z_mean - m.distance_free)
            + m.grazing_gain * (1.0 - cos_mean)
            + m.truncation_gain * trunc
            + m.small_gain * small
        )
        return np.clip(level, 0.0, 1.0)

    def _segment_vectors(
        self,
        seg_view: np.ndarray,
        seg_inst: np.ndarray,
        seg_cls: np.ndarray,
        stamps: np.ndarray,
        level: np.ndarray,
        area: np.ndarray,
    ) -> np.ndarray:
        """(S, d) feature of each segment in its view: perceived class, confuser, noise."""
        m = self.model
        biased = self.biased(seg_inst, seg_cls)
        perceived = np.where(biased, self.nearest[seg_cls], seg_cls)
        stamp = stamps[seg_view]
        if m.view_bias_rate > 0:
            perceived = self._view_bias(seg_view, seg_inst, seg_cls, stamp, area, perceived)
        ids = seg_inst.astype(np.uint64) * np.uint64(1 << 17) + seg_cls.astype(np.uint64)
        u_conf = uniform(self.seed, stamp, ids, 21)
        u_mix = uniform(self.seed, stamp, ids, 22)
        confuser = np.minimum(
            (self.confusion_cdf[perceived] < u_conf[:, None]).sum(1), len(self.label_names) - 1
        )
        gain = m.confusion_gain * np.where(biased, m.bias_noise_scale, 1.0)
        mix = np.minimum(1.0, gain * level * u_mix)
        mix = np.where(self.is_object[seg_cls] & (seg_inst > 0), mix, 0.0)
        vec = (1 - mix)[:, None] * self.text[perceived] + mix[:, None] * self.text[confuser]
        if m.segment_noise > 0:
            gauss = gaussian(self.seed, stamp, ids, 23, DIM)
            vec = vec + (m.segment_noise * level)[:, None] * gauss / np.sqrt(DIM)
        vec = l2_normalise(vec)
        if m.similarity_model is SimilarityModel.CLIP_LIKE:
            vec = self._clip_like(vec, ids, stamp)
        return vec

    def _clip_like(self, vec: np.ndarray, ids: np.ndarray, stamp: np.ndarray) -> np.ndarray:
        """(S, d) CLIP-like image features of segments whose text mixtures are ``vec``:
        the gap direction, a small share of the mixture and of the common text direction,
        the segment's own direction (off the text span, the same in every view) and
        isotropic noise per view, normalised (:class:`SimilarityModel`)."""
        m = self.model
        out = m.clip_gap_weight * self.gap + m.clip_text_weight * vec
        out = out + m.clip_common_weight * self.common
        if m.clip_instance_weight > 0:
            own = self._off_text(gaussian(self.seed, ids, np.zeros_like(ids), 43, DIM))
            out = out + m.clip_instance_weight * own
        if m.clip_noise > 0:
            noise = gaussian(self.seed, stamp, ids, 45, DIM) / np.sqrt(DIM)
            out = out + m.clip_noise * noise
        return l2_normalise(out)

    def _view_bias(
        self,
        seg_view: np.ndarray,
        seg_inst: np.ndarray,
        seg_cls: np.ndarray,
        stamp: np.ndarray,
        area: np.ndarray,
        perceived: np.ndarray,
    ) -> np.ndarray:
        """``perceived`` with view-biased instances misread in some views: as the class of
        the largest other object segment of the view (context), else their nearest class."""
        m = self.model
        inst = seg_inst.astype(np.uint64)
        obj = (seg_inst > 0) & self.is_object[seg_cls]
        chosen = uniform(self.seed, inst, 31) < m.view_bias_rate
        misread = obj & chosen & (uniform(self.seed, inst, stamp, 32) < m.view_bias_views)
        if not misread.any():
            return perceived
        other = self.nearest[seg_cls]
        if m.view_bias_context:
            # the two largest object segments of each view: a segment's context is the
            # largest one that is not itself, if its class differs
            key = np.where(obj, area, -1)
            order = np.lexsort((-key, seg_view))
            sv = seg_view[order]
            start = np.searchsorted(sv, sv, side="left")
            rank = np.arange(len(order)) - start
            n_view = int(seg_view.max()) + 1 if len(seg_view) else 0
            top = np.full((n_view, 2), -1)
            keep = rank < 2
            top[sv[keep], rank[keep]] = order[keep]
            top[top >= 0] = np.where(obj[top[top >= 0]], top[top >= 0], -1)
            own = np.arange(len(seg_view))
            first, second = top[seg_view, 0], top[seg_view, 1]
            ctx = np.where(first == own, second, first)
            ok = ctx >= 0
            ctx_cls = np.where(ok, seg_cls[np.maximum(ctx, 0)], -1)
            other = np.where(ok & (ctx_cls != seg_cls), ctx_cls, other)
        return np.where(misread, other, perceived)

    def _need_names(self) -> None:
        if not self.label_names:
            msg = "labels encoder used before prepare(): it needs the recording's class names"
            raise EncoderError(msg)


def _view_cosines(frames: Sequence[Frame], depth: np.ndarray, step: int = 1) -> np.ndarray:
    """(B, h, w) |cos| between view rays and surface normals from a depth image sampled
    every ``step`` pixels.

    Coordinates one at a time (not an (B, h, w, 3) stack): the same arithmetic with a third
    of the temporaries at any moment.
    """
    _B, h, w = depth.shape
    K = np.stack([np.asarray(f.K, np.float64) for f in frames])
    u = (np.arange(w) * step)[None, None, :]
    v = (np.arange(h) * step)[None, :, None]
    P = (
        (u - K[:, 0, 2, None, None]) / K[:, 0, 0, None, None] * depth,
        (v - K[:, 1, 2, None, None]) / K[:, 1, 1, None, None] * depth,
        depth,
    )
    du = [np.gradient(c, axis=2) for c in P]
    dv = [np.gradient(c, axis=1) for c in P]
    n = [du[(i + 1) % 3] * dv[(i + 2) % 3] - du[(i + 2) % 3] * dv[(i + 1) % 3] for i in range(3)]
    del du, dv
    num = np.abs(n[0] * P[0] + n[1] * P[1] + n[2] * P[2])
    den = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    den *= np.sqrt(P[0] * P[0] + P[1] * P[1] + P[2] * P[2])
    return np.where(den > 0, num / np.maximum(den, 1e-12), 1.0)


_INSTANCE_SPAN = 1 << 16
"""Segment keys below this are instance ids; above, ``span + class id`` of structure."""
