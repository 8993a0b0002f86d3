"""The kinds of map a store holds, named once for every stage.

The fuse stage builds them, the query stage reads them, replanning and the evaluation treat
each its own way; all of them compare against these members rather than spelling the
names. A :class:`MapKind` is a ``str``, so metadata keys, table columns and JSON written
with one read the plain name (``grid``, ``instances``).
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["MapKind"]


class MapKind(StrEnum):
    """The two maps a store holds (:data:`care_maps.query.map.MAP_TABLES` names each one's table)."""

    INSTANCES = "instances"
    """OpenMask3D-like instance map."""
    GRID = "grid"
    """VLMaps-like top-down grid map."""
