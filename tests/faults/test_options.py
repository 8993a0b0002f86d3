"""The CLI's typed choices are the registries' names (care_maps.cli.choices lists a few by hand
to keep torch and open3d out of every ``care`` call)."""

from __future__ import annotations

import pytest


def test_choices_match_registries() -> None:
    from care_maps.cli import choices
    from care_maps.core.encoders import ENCODERS
    from care_maps.fuse.instances import INSTANCE_FEATURES
    from care_maps.fuse.proposals import PROPOSERS
    from care_maps.query.map import MAP_TABLES
    from care_maps.replan import CRITERIA, STRATEGIES
    from care_maps.world.perception.model import PERCEPTION_PRESETS

    pairs = [
        (choices.Strategy, STRATEGIES),
        (choices.Criterion, CRITERIA),
        (choices.MapKind, MAP_TABLES),
        (choices.EncoderName, ENCODERS),
        (choices.Perception, PERCEPTION_PRESETS),
        (choices.ProposalMethod, PROPOSERS),
        (choices.InstanceFeatures, INSTANCE_FEATURES),
    ]
    for enum, registry in pairs:
        assert [m.value for m in enum] == list(registry), enum


@pytest.mark.slow
def test_help_lists_the_choices(care) -> None:
    code, out, _ = care("replan", "--help")
    assert code == 0
    for name in ("min_stderr", "max_entropy", "category"):
        assert name in out
