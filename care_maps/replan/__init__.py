"""Replan stage: choose the next candidate after a failed attempt (``docs/method.md``'s strategies)."""

from __future__ import annotations

from care_maps.replan.attempts import (
    DEFAULT_EXCLUDE_RADIUS,
    Attempts,
    Choice,
    ReplanConfig,
    next_goal,
    run_attempts,
)
from care_maps.replan.expected import expected_random_success
from care_maps.replan.strategies import (
    CRITERIA,
    STRATEGIES,
    Pick,
    Situation,
    Strategy,
    candidate_set,
)

__all__ = [
    "CRITERIA",
    "DEFAULT_EXCLUDE_RADIUS",
    "STRATEGIES",
    "Attempts",
    "Choice",
    "Pick",
    "ReplanConfig",
    "Situation",
    "Strategy",
    "candidate_set",
    "expected_random_success",
    "next_goal",
    "run_attempts",
]
