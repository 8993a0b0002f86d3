"""The ingest stage as one function: a recording in, a feature store out."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from care.encoders import Encoder
from care.store import Store
from ingest.pipeline import IngestConfig, run_ingest

__all__ = ["ingest"]


def ingest(recording: Path, config: IngestConfig, *, encoder: Encoder | None = None) -> Store:
    """Ingest ``recording`` into the store ``config.out`` and open it.

    Everything the store depends on is in the arguments (``config.recording`` is replaced by
    ``recording``); an up-to-date store (same recording content and options) is returned
    without any work, or a model loaded. ``encoder``: an already built encoder instance.
    """
    run_ingest(replace(config, recording=Path(recording)), encoder)
    return Store(config.out)
