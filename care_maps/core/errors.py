"""One error tree for the project, so the CLI can turn any of them into one line and an exit code.

Raise with a message that names the file, topic or field and says what to do, e.g.
``msg = f"{path}: no image topic; topics present: {topics}. Pass --rgb TOPIC."``
``raise IngestError(msg) from err``.
"""

from __future__ import annotations

__all__ = [
    "CareError",
    "EncoderError",
    "EvalError",
    "FuseError",
    "GroundTruthError",
    "IngestError",
    "OutputError",
    "QueryError",
    "ReplanError",
    "StoreError",
    "WorldError",
]


class CareError(Exception):
    """Base of every error the project raises on bad input or configuration."""


class IngestError(CareError):
    """A recording cannot be read, synchronised or turned into views."""


class EncoderError(CareError):
    """An encoder cannot be loaded or cannot encode its input."""


class OutputError(CareError):
    """An output path cannot be written safely (not ours, an input, locked, disk full)."""


class StoreError(CareError):
    """A feature store or map table is missing, incomplete or of another schema version."""


class FuseError(CareError):
    """Maps cannot be built from a store."""


class QueryError(CareError):
    """A query cannot be answered from a map."""


class ReplanError(CareError):
    """A replan strategy or candidate set is misconfigured."""


class WorldError(CareError):
    """The procedural sample world cannot be generated, rendered or recorded."""


class EvalError(CareError):
    """A dataset evaluation cannot be run."""


class GroundTruthError(WorldError):
    """Ground truth cannot be read, is malformed, or does not match the map it should label.

    A :class:`WorldError` because the sample world's ground truth is one of its formats."""
