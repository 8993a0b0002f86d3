"""How a run executes, apart from what it makes: :class:`Execution`.

A map's config (:class:`care_maps.fuse.config.GridConfig`, :class:`care_maps.fuse.config.InstanceConfig`) holds
only what shapes the map, so its fingerprint is the hash of all of it. Everything that
changes how the work is done and never what comes out (where tasks run, how far reading
runs ahead, the memory a fusion may use, whether a current output is rebuilt, progress bars)
is one :class:`Execution`, passed to every stage. The CLI builds its options from both kinds
of dataclass, each field's default and docstring being the option's default and help.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from care_maps.core.checks import check_numbers
from care_maps.core.config import member
from care_maps.core.errors import CareError
from care_maps.core.store import BATCH_SIZE
from care_maps.runtime.readahead import READ_AHEAD

__all__ = ["BATCH_SIZE", "DEFAULT_EXECUTION", "Backend", "Execution"]


class Backend(StrEnum):
    """Where a dataset's tasks (one per recording, then its evaluation) run."""

    PROCESSES = "processes"
    """A local process pool of ``workers`` processes (1: one after another in this process)."""
    RAY = "ray"
    """Ray: a cluster at ``ray_address``, or a Ray started for the run when it has none."""


@dataclass(frozen=True)
class Execution:
    """How a run executes (shared by every stage, the CLI's commands and the Python API)."""

    backend: Backend = Backend.PROCESSES
    """Where a dataset's tasks run: a local process pool, or Ray."""
    workers: int | None = None
    """Local processes of a dataset's tasks (default: one per CPU; 1: one after another in
    this process)."""
    ray_address: str | None = None
    """Address of a running Ray cluster (with the ray backend; default: start a local Ray)."""
    task_cpus: float = 1.0
    """CPUs each recording's Ray task declares."""
    task_memory: int | None = 2 << 30
    """Bytes of memory each recording's Ray task declares (None: none)."""
    read_ahead: int = READ_AHEAD
    """Views prepared ahead of their use on background threads, overlapping reading the
    store with the fusion on a machine's cores (0: all in one thread). The map is the same
    either way."""
    batch_size: int = BATCH_SIZE
    """Views projected (and crops encoded) at once."""
    memory_budget: int | None = None
    """Memory a grid fusion may use, e.g. 8G or 512M (default: half of this machine's); a
    floor too large for it is fused in several passes over the views."""
    cells_per_pass: int | None = None
    """Cells fused per pass, overriding what the budget allows (tests, benchmarks)."""
    growth_state: bool = True
    """Keep a grid's streaming state beside it (``cells.state.npz``, about 5.7 KB a cell at
    100 classes), so runs appended to the store later grow the grid from their views alone;
    off: that disk is saved, and after an append the grid is built from every view."""
    overwrite: bool = False
    """Rebuild even if a current output (store, map) exists."""
    progress: bool = True
    """Show progress bars."""

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "backend", member(Backend, self.backend, CareError, "unknown backend")
        )
        check_numbers(
            CareError,
            "execution settings",
            non_negative={"read_ahead": self.read_ahead},
            at_least_one={"batch_size": self.batch_size,
                          **({} if self.workers is None else {"workers": self.workers}),
                          **({} if self.cells_per_pass is None
                             else {"cells_per_pass": self.cells_per_pass})},
            positive={"task_cpus": self.task_cpus},
        )  # fmt: skip


DEFAULT_EXECUTION = Execution()
"""Every setting at its default: the ``run`` of a stage function called without one."""
