"""``requirements.lock`` is the project's own dependency closure: every package
care-maps[dev] needs, transitively, and nothing else (a freeze of a development machine
would pin packages a user never needs, and clash with theirs)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _lock_module():
    spec = importlib.util.spec_from_file_location("care_lock", ROOT / "scripts" / "lock.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_lock_is_the_closure() -> None:
    lock = _lock_module()
    pins = dict(
        line.split("==")
        for line in (ROOT / "requirements.lock").read_text().splitlines()
        if "==" in line and not line.startswith("#")
    )
    closure = lock.closure()
    if {n: closure.get(n) for n in pins} != pins:
        pytest.skip("this environment is not the lock's (other versions installed)")
    assert set(pins) == set(closure)
