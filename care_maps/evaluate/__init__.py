"""evaluate stage."""

from __future__ import annotations

from care_maps.runtime.lazy import lazy_exports

__all__ = ["evaluate"]

__getattr__ = lazy_exports(__name__, {"evaluate": "care_maps.evaluate.api"})
