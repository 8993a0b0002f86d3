"""Encoder plugins by name: the ``care_maps.core.encoders`` entry points of every installed package.

A package adds an encoder by declaring it in its ``pyproject.toml``::

    [project.entry-points."care_maps.encoders"]
    myvlm = "mypackage.encoder:MyEncoder"

where ``MyEncoder`` subclasses :class:`Encoder` and takes one :class:`EncoderOptions`. This
project declares its own encoders the same way (``clip``, ``precomputed``, and ``labels``,
the sample world's simulated perception), so the core names none of them and a user's
encoder is found exactly like a built-in one.

Lazy: the names come from the installed metadata on first use, and a class is imported only
when :func:`make_encoder` builds it, so importing this module pulls in neither torch
(``clip``) nor the sample world (``labels``).
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable, Iterator, Mapping
from typing import cast

from care_maps.core.encoders.base import (
    Encoder,
    EncoderOptions,
    Precision,
    RecordingContext,
    l2_normalise,
)
from care_maps.core.errors import EncoderError

__all__ = [
    "ENCODERS",
    "ENTRY_POINT_GROUP",
    "Encoder",
    "EncoderOptions",
    "EncoderRegistry",
    "Precision",
    "RecordingContext",
    "l2_normalise",
    "make_encoder",
]

ENTRY_POINT_GROUP = "care_maps.encoders"
"""The entry-point group an installed package declares its encoders in."""


class EncoderRegistry(Mapping[str, str]):
    """Encoder name -> ``module:attr`` of each entry point of ``group``, sorted by name.

    The entry points are read on first use and kept; where two packages declare one name,
    the first found on ``sys.path`` wins, as with any entry-point lookup.
    """

    def __init__(self, group: str = ENTRY_POINT_GROUP) -> None:
        self.group = group
        self._found: dict[str, importlib.metadata.EntryPoint] | None = None

    def _entry_points(self) -> dict[str, importlib.metadata.EntryPoint]:
        if self._found is None:
            found: dict[str, importlib.metadata.EntryPoint] = {}
            for ep in importlib.metadata.entry_points(group=self.group):
                found.setdefault(ep.name, ep)
            self._found = dict(sorted(found.items()))
        return self._found

    def __getitem__(self, name: str) -> str:
        return self._entry_points()[name].value

    def __iter__(self) -> Iterator[str]:
        return iter(self._entry_points())

    def __len__(self) -> int:
        return len(self._entry_points())

    def load(self, name: str) -> type[Encoder]:
        """The encoder class registered as ``name``, imported now.

        Raises:
            EncoderError: no installed package registers ``name`` (the line lists those
                that are), or its entry point is not an :class:`Encoder` subclass.
        """
        found = self._entry_points()
        if name not in found:
            names = ", ".join(found) or "none (install the package: pip install -e .)"
            msg = f"unknown encoder {name!r}; choose one of {names}"
            raise EncoderError(msg)
        cls = found[name].load()
        if not (isinstance(cls, type) and issubclass(cls, Encoder)):
            msg = f"encoder {name!r} ({found[name].value}): not a subclass of care_maps.core.encoders.Encoder"
            raise EncoderError(msg)
        return cls

    def refresh(self) -> None:
        """Read the entry points again on next use (a package installed since)."""
        self._found = None


ENCODERS = EncoderRegistry()
"""Every installed encoder: name -> ``module:class``; the class takes one :class:`EncoderOptions`."""


def make_encoder(name: str, options: EncoderOptions | None = None) -> Encoder:
    """Instantiate the encoder registered as ``name``; a precision it does not run in is
    one error naming the option, before any model is loaded."""
    options = options or EncoderOptions()
    found = ENCODERS.load(name)
    if options.precision not in found.precisions:
        runs = ", ".join(sorted(found.precisions))
        msg = f"--precision {options.precision}: encoder {name!r} runs in {runs} only"
        raise EncoderError(msg)
    # a registered encoder class takes one EncoderOptions (the base declares no __init__)
    return cast("Callable[[EncoderOptions], Encoder]", found)(options)
