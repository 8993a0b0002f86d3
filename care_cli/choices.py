"""Typed choices of the CLI, made from the registries so ``--help`` lists them and typer
refuses anything else before a command runs (one source: the registry).

The registries of proposals, instance features and perception presets live in modules that
import torch or open3d; every ``care`` call would pay seconds for them, so their names are
listed here and ``tests/faults/test_options.py`` checks they equal the registries.
"""

from __future__ import annotations

from enum import Enum

from care.encoders import ENCODERS
from query.map import MAP_TABLES
from replan import CRITERIA, STRATEGIES

__all__ = [
    "Criterion",
    "EncoderName",
    "InstanceFeatures",
    "MapKind",
    "Perception",
    "ProposalMethod",
    "Strategy",
    "registry_enum",
]


PERCEPTION_PRESETS = ("default", "ideal")
"""Names of ``care.encoders.labels.PERCEPTION_PRESETS``."""
PROPOSERS = ("geometric", "labels")
"""Names of ``fuse.proposals.PROPOSERS``."""
INSTANCE_FEATURES = ("masked", "crops")
"""``fuse.instances.INSTANCE_FEATURES``."""


def registry_enum(name: str, keys: object) -> type[Enum]:
    """A ``str`` enum whose members are a registry's names (value = name)."""
    return Enum(name, {str(k): str(k) for k in keys}, type=str)  # type: ignore[return-value]


Strategy = registry_enum("Strategy", STRATEGIES)
Criterion = registry_enum("Criterion", CRITERIA)
MapKind = registry_enum("MapKind", MAP_TABLES)
EncoderName = registry_enum("EncoderName", ENCODERS)
Perception = registry_enum("Perception", PERCEPTION_PRESETS)
ProposalMethod = registry_enum("ProposalMethod", PROPOSERS)
InstanceFeatures = registry_enum("InstanceFeatures", INSTANCE_FEATURES)
