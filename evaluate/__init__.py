"""evaluate stage."""

from __future__ import annotations

from typing import Any

__all__ = ["evaluate"]


def __getattr__(name: str) -> Any:
    """The stage function(s) (``evaluate``), imported on first use: the
    package's light modules stay light to import."""
    if name in __all__:
        from evaluate.api import evaluate  # noqa: F401

        return locals()[name]
    msg = f"module {__name__!r} has no attribute {name!r}"
    raise AttributeError(msg)
