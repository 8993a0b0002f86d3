"""Validation of numeric settings, shared by every config's ``__post_init__``.

A NaN passes ``x > 0``-style checks in neither direction, so each rule here tests
finiteness first; the error lists every bad field at once.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from care_maps.core.errors import CareError

__all__ = ["check_numbers"]


def check_numbers(
    error: type[CareError],
    what: str,
    *,
    positive: Mapping[str, float] | None = None,
    non_negative: Mapping[str, float] | None = None,
    finite: Mapping[str, float] | None = None,
    at_least_one: Mapping[str, int] | None = None,
) -> None:
    """Raise ``error`` naming every field that is not finite or out of its range."""
    bad: list[str] = []

    def fin(v: float) -> bool:
        try:
            return math.isfinite(float(v))
        except (TypeError, ValueError):
            return False

    for name, v in (positive or {}).items():
        if not (fin(v) and v > 0):
            bad.append(f"{name}={v} (must be a finite number > 0)")
    for name, v in (non_negative or {}).items():
        if not (fin(v) and v >= 0):
            bad.append(f"{name}={v} (must be a finite number >= 0)")
    for name, v in (finite or {}).items():
        if not fin(v):
            bad.append(f"{name}={v} (must be finite)")
    for name, v in (at_least_one or {}).items():
        if not (isinstance(v, int) and v >= 1):
            bad.append(f"{name}={v} (must be an integer >= 1)")
    if bad:
        msg = f"invalid {what}: {'; '.join(bad)}"
        raise error(msg)
