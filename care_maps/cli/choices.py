"""Typed choices of the CLI: the registries' enums, so ``--help`` lists them and typer
refuses anything else before a command runs (one source: the enum the registry is keyed by).

The enums live in light modules (configs, registries) so every ``care`` call can import
them; the encoders' registry (installed entry points, read without importing any encoder)
becomes an enum here. The perception presets are the sample world's
(:class:`care_maps.world.perception.model.PerceptionPreset`, a module that loads no encoder):
``EncoderOptions.perception`` stays a plain string that the ``labels`` encoder validates,
so no stage needs the sample world, and the CLI, downstream of every package, lists them.
"""

from __future__ import annotations

from enum import Enum, StrEnum

from care_maps.core.encoders import ENCODERS
from care_maps.core.maps import MapKind
from care_maps.evaluate.config import QueryProtocol
from care_maps.evaluate.groundtruth import UnknownClasses
from care_maps.fuse.config import InstanceFeatures, ProposalMethod
from care_maps.replan.strategies import Criterion, StrategyName
from care_maps.world.perception.model import PerceptionPreset

__all__ = [
    "Criterion",
    "EncoderName",
    "InstanceFeatures",
    "MapKind",
    "Perception",
    "ProposalMethod",
    "QueryProtocol",
    "Strategy",
    "UnknownClasses",
    "registry_enum",
]

Strategy = StrategyName
"""The CLI's name of :class:`care_maps.replan.strategies.StrategyName`."""

Perception = PerceptionPreset
"""The CLI's name of :class:`care_maps.world.perception.model.PerceptionPreset` (``--perception``)."""


def registry_enum(name: str, keys: object) -> type[Enum]:
    """A ``str`` enum whose members are a registry's names (value = name)."""
    return StrEnum(name, {str(k).upper(): str(k) for k in keys})  # type: ignore[return-value]


EncoderName = registry_enum("EncoderName", ENCODERS)
