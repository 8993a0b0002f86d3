"""Typed choices of the CLI: the registries' enums, so ``--help`` lists them and typer
refuses anything else before a command runs (one source: the enum the registry is keyed by).

The enums live in light modules (configs, registries) so every ``care`` call can import
them; the encoders' and perception presets' registries are dicts whose names become enums
here.
"""

from __future__ import annotations

from enum import Enum, StrEnum

from care.encoders import ENCODERS
from evaluate.config import QueryProtocol
from evaluate.groundtruth import UnknownClasses
from fuse.config import InstanceFeatures, ProposalMethod
from query.map import MapKind
from replan.strategies import Criterion, StrategyName

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
"""The CLI's name of :class:`replan.strategies.StrategyName`."""

PERCEPTION_PRESETS = ("default", "ideal")
"""Names of ``care.encoders.labels.PERCEPTION_PRESETS`` (that module imports torch; the
fault suite checks the two agree)."""


def registry_enum(name: str, keys: object) -> type[Enum]:
    """A ``str`` enum whose members are a registry's names (value = name)."""
    return StrEnum(name, {str(k).upper(): str(k) for k in keys})  # type: ignore[return-value]


EncoderName = registry_enum("EncoderName", ENCODERS)
Perception = registry_enum("Perception", PERCEPTION_PRESETS)
