"""The perception model's knobs, its presets and how a preset is named on the command line.

Light on purpose (numpy and the standard library): the CLI takes its ``--perception``
choices from :class:`PerceptionPreset` without loading the encoder.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.errors import EncoderError

__all__ = [
    "CLIP_LIKE_KNOBS",
    "PERCEPTION_PRESETS",
    "PerceptionModel",
    "PerceptionPreset",
    "SimilarityModel",
    "perception_model",
    "recorded_perception",
]


class SimilarityModel(StrEnum):
    """How a segment's perceived text mixture becomes its image feature."""

    DIRECT = "direct"
    """The feature is the (noisy) text mixture itself: cosine near 1 to the perceived
    class, so at logit scale 100 nearly every view puts all its mass on one class. The
    model of every release before ``clip_like``; unchanged bit for bit."""
    CLIP_LIKE = "clip_like"
    """CLIP's geometry: the feature is mostly a direction orthogonal to every class text
    (the modality gap) plus a small share of the text mixture and of the vocabulary's
    common direction, so cosines to class texts sit near 0.3 with small margins
    (:mod:`care_maps.world.perception.likeness` holds the published targets and measures them)."""


@dataclass(frozen=True)
class PerceptionModel:
    """How wrong the simulated VLM is, and why. ``ideal()`` switches everything off."""

    instance_bias_rate: float = 0.10
    """Chance of each instance to be perceived as its nearest other class in every view."""
    class_bias_rate: float = 0.10
    """Fraction of the object classes of a recording (rounded; scene-wide: every instance of
    them) perceived as their nearest other class in every view."""
    bias_noise_scale: float = 0.3
    """Multiplies the view-dependent noise of a biased instance (its mistake is confident)."""
    class_bias_per_scene: bool = False
    """Draw the biased classes per scene (hash of the scene's seed, among the classes the
    scene holds) rather than once per encoder seed for the whole vocabulary."""
    view_bias_rate: float = 0.0
    """Chance of each instance to be misread from some viewpoints (view-dependent bias)."""
    view_bias_views: float = 0.5
    """Fraction of a view-biased instance's views in which it is misread."""
    view_bias_context: bool = True
    """A misread view reads the class of the largest other object in that view (its
    context); False: the instance's nearest class by text embedding."""
    base_noise: float = 0.15
    """Noise level of a large, near, frontal, fully visible segment."""
    distance_gain: float = 0.12
    """Noise level added per metre of mean segment depth beyond ``distance_free``."""
    distance_free: float = 1.5
    """Mean depth (metres) up to which distance adds no noise."""
    grazing_gain: float = 0.35
    """Noise added times ``1 - mean |cos|`` of the angle between view rays and normals."""
    truncation_gain: float = 0.4
    """Noise added times the segment's truncation (its pixels on the image border
    relative to the square root of its area, capped at 1)."""
    small_gain: float = 0.3
    """Noise added times ``1 - area / (small_fraction * image area)`` for small segments."""
    small_fraction: float = 0.004
    """Segment area (fraction of the image) below which it counts as small."""
    confusion_gain: float = 1.6
    """A segment's feature moves towards its view's confuser by ``min(1, confusion_gain *
    level * u)``, ``u`` uniform per view: past one half the view reads as the confuser, so
    segments whose level stays high in most views (small, far) are misread after fusion too."""
    confusion_temperature: float = 0.05
    """Softmax temperature over text similarities that draws a view's confuser: lower
    keeps confusions among the nearest classes."""
    segment_noise: float = 0.15
    """Scale of isotropic noise added to a segment's vector per view (times its level)."""
    cell_noise: float = 0.03
    """Scale of isotropic noise per cell and view (texture of the feature map)."""
    bleed: float = 0.35
    """Weight of the blurred neighbourhood in a cell's mixture (features bleed across
    mask boundaries); 0 = sharp masks."""
    bleed_sigma: float = 1.0
    """Gaussian sigma of that blur, in cells."""
    area_exponent: float = 1.0
    """A segment's weight in a cell is its pixel count there over its area to this power."""
    stride: int = 8
    """Pixels per feature-map cell side."""
    similarity_model: SimilarityModel = SimilarityModel.DIRECT
    """``direct`` (the text mixture is the feature) or ``clip_like`` (CLIP-like
    image-text similarities; the ``clip_*`` knobs below apply only to it). Each segment's
    feature becomes ``normalise(clip_gap_weight * gap + clip_text_weight * mixture +
    clip_common_weight * common + clip_instance_weight * own + clip_noise * noise)``."""
    clip_gap_weight: float = 0.65
    """Weight of the modality-gap direction: one unit vector per encoder seed, orthogonal
    to every class text of the recording, shared by every segment."""
    clip_text_weight: float = 0.2
    """Weight of the segment's text mixture (today's feature: perceived class, confuser,
    segment noise). Margins between classes scale with it: ``clip_text_weight * (1 -
    text similarity)`` before noise."""
    clip_common_weight: float = 0.3
    """Weight of the vocabulary's common text direction (the normalised mean of the class
    texts): it raises every class's cosine alike, more for classes near the centroid."""
    clip_instance_weight: float = 0.55
    """Weight of a direction particular to each instance (or structure class), orthogonal
    to every class text and the same in every view: what an image holds beyond its class
    name, so different objects' features are not all alike."""
    clip_noise: float = 0.4
    """Norm of the isotropic noise added per segment and view: jitter of every class's
    similarity (about ``clip_noise / sqrt(d)`` in cosine) and view-to-view spread."""

    @classmethod
    def ideal(cls) -> PerceptionModel:
        """No bias, no noise, no bleeding: every visible instance reads as its true class."""
        zero: dict[str, Any] = {
            f.name: 0.0
            for f in fields(cls)
            if f.name.endswith(("_rate", "_gain", "_noise")) or f.name == "bleed"
        }
        return replace(cls(), **zero)

    def with_values(self, values: Mapping[str, Any]) -> PerceptionModel:
        """This model with ``values`` (field name -> value, strings parsed by the field's
        type); an unknown name or a bad value is one :class:`EncoderError` naming it."""
        types: dict[str, type] = {f.name: type(f.default) for f in fields(self)}
        out = {}
        for key, value in values.items():
            if key not in types:
                msg = f"perception knob {key!r}: unknown; choose from {', '.join(types)}"
                raise EncoderError(msg)
            out[key] = _parse(key, value, types[key])
        return replace(self, **out)


CLIP_LIKE_KNOBS: tuple[str, ...] = (
    "similarity_model",
    *(f.name for f in fields(PerceptionModel) if f.name.startswith("clip_")),
)
"""The knobs of the CLIP-like similarity (recorded only where it is chosen: a dataset of
the direct model records what it always did)."""


def _parse(key: str, value: Any, kind: type) -> Any:
    """``value`` as a ``kind`` (bool, int, float or a string enum), from a string or a
    number."""
    if issubclass(kind, StrEnum):
        try:
            return kind(str(value).strip())
        except ValueError as err:
            choices = ", ".join(c.value for c in kind)
            msg = f"perception knob {key}={value!r}: choose one of {choices}"
            raise EncoderError(msg) from err
    try:
        if kind is bool:
            if isinstance(value, bool):
                return value
            text = str(value).strip().lower()
            if text not in ("true", "false", "1", "0", "on", "off"):
                raise ValueError(text)
            return text in ("true", "1", "on")
        number = kind(value) if kind is float else int(str(value))
    except (TypeError, ValueError) as err:
        msg = f"perception knob {key}={value!r}: not a {kind.__name__}"
        raise EncoderError(msg) from err
    if isinstance(number, float) and not np.isfinite(number):
        msg = f"perception knob {key}={value!r}: not a finite number"
        raise EncoderError(msg)
    if number < 0:
        msg = f"perception knob {key}={value!r}: must not be negative"
        raise EncoderError(msg)
    return number


class PerceptionPreset(StrEnum):
    """Named perception models, selectable by ``EncoderOptions.perception``."""

    DEFAULT = "default"
    IDEAL = "ideal"


PERCEPTION_PRESETS: dict[PerceptionPreset, PerceptionModel] = {
    PerceptionPreset.DEFAULT: PerceptionModel(),
    PerceptionPreset.IDEAL: PerceptionModel.ideal(),
}
"""The model of each preset."""


def perception_model(
    spec: str, recorded: Mapping[str, Any] | None = None
) -> tuple[PerceptionModel, bool]:
    """The model of ``spec`` (``"NAME"`` or ``"NAME:key=value,..."``) and whether it came
    from ``recorded`` (a dataset's recorded model, used when NAME is ``default``)."""
    name, _, overrides = str(spec).partition(":")
    if name not in PERCEPTION_PRESETS:
        msg = f"perception preset {name!r}: choose one of {', '.join(PERCEPTION_PRESETS)}"
        raise EncoderError(msg)
    model, from_record = PERCEPTION_PRESETS[PerceptionPreset(name)], False
    if name == PerceptionPreset.DEFAULT and recorded:
        model, from_record = PerceptionModel().with_values(recorded), True
    values = {}
    for item in filter(None, (p.strip() for p in overrides.split(","))):
        key, eq, value = item.partition("=")
        if not eq:
            msg = f"perception override {item!r}: write key=value"
            raise EncoderError(msg)
        values[key.strip()] = value.strip()
    return model.with_values(values), from_record


def recorded_perception(source: Path) -> dict[str, Any]:
    """What the sample world recorded beside ``source`` for the perception model: the
    ground-truth JSON's ``info.perception`` (field -> value) and ``info.scene`` (its seed and
    classes); empty where there is none (any other recording).

    The file name follows :func:`care_maps.truth.formats.native.gt_paths` (the core cannot import it).
    """
    source = Path(source)
    stem = source.stem if source.suffix else source.name
    path = source.with_name(f"{stem}.gt.json")
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    info = doc.get("info") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        return {}
    scene = info.get("scene") or {}
    classes = sorted({str(r.get("class_name")) for r in doc.get("instances") or []})
    return {
        "perception": info.get("perception") or {},
        "scene_seed": scene.get("seed"),
        "scene_classes": classes,
    }
