"""Encoder plugins by name. Modules are imported lazily: ``clip`` pulls in transformers."""

from __future__ import annotations

import importlib

from care.encoders.base import Encoder, EncoderOptions, RecordingContext, l2_normalise
from care.errors import EncoderError

__all__ = [
    "ENCODERS",
    "Encoder",
    "EncoderOptions",
    "RecordingContext",
    "l2_normalise",
    "make_encoder",
]

ENCODERS: dict[str, str] = {
    "clip": "care.encoders.clip:ClipEncoder",
    "labels": "care.encoders.labels:LabelsEncoder",
    "precomputed": "care.encoders.precomputed:PrecomputedEncoder",
}
"""Encoder name -> ``module:class``; the class takes one :class:`EncoderOptions`."""


def make_encoder(name: str, options: EncoderOptions | None = None) -> Encoder:
    """Instantiate the encoder registered as ``name``."""
    if name not in ENCODERS:
        msg = f"unknown encoder {name!r}; choose one of {', '.join(sorted(ENCODERS))}"
        raise EncoderError(msg)
    module_name, cls_name = ENCODERS[name].split(":")
    cls = getattr(importlib.import_module(module_name), cls_name)
    return cls(options or EncoderOptions())
