"""The metadata keys a map's tables carry about how they were made: one spelling for the
builder (:mod:`care_maps.fuse.build`) and for every command that reads them back (``care fuse``
reuses a map's recorded settings).

Only the standard library is imported: the CLI reads a map's settings on every
``care fuse`` call.
"""

from __future__ import annotations

from collections.abc import Mapping

__all__ = [
    "CLOUD_CONFIG_KEY",
    "STORE_KEY",
    "build_key",
    "config_json_key",
    "config_key",
    "recorded_settings",
]

STORE_KEY = b"care.store.created"
"""The stamp of the store a map was built from (:func:`care_maps.fuse.frame.store_stamp`)."""
CLOUD_CONFIG_KEY = b"care.cloud.config"
"""The fingerprint of the scene-cloud settings ``scene_points.parquet`` was made with."""


def build_key(kind: str) -> bytes:
    """Metadata key of the id of the build a ``kind`` map's table came from (its store's
    stamp and the config it was built with, as one hash): every table of one build carries
    the same id, and a recompute keeps it, so a table of another build (copied, or left by
    an older map) is told from the map's own (:mod:`care_maps.fuse.provenance`)."""
    return f"care.{kind}.build".encode()


def config_key(kind: str) -> bytes:
    """Metadata key of the fingerprint of the config a ``kind`` map was built with."""
    return f"care.{kind}.config".encode()


def config_json_key(kind: str) -> bytes:
    """Metadata key of the JSON of the config a ``kind`` map was built with."""
    return f"care.{kind}.config_json".encode()


def recorded_settings(metadata: Mapping[bytes, bytes], kind: str) -> bytes | None:
    """The settings JSON a ``kind`` map's table ``metadata`` records (None: none). A table
    without :func:`config_json_key` gives its :func:`config_key` value, used where it
    holds the JSON itself (:func:`care_maps.core.config.recorded_fields` reads nothing from a hash)."""
    return metadata.get(config_json_key(kind)) or metadata.get(config_key(kind))
