"""What a grid keeps so that it can grow: its cells' streaming state, saved beside it.

Grid fusion is a sum of per-view contributions merged in view order
(:class:`care_maps.fuse.accumulate.CandidateSums`), so a map of views ``0..N-1`` extended by
views ``N..M-1`` is the map of views ``0..M-1`` if the merge continues from the state the
first ``N`` left: the same operations on the same numbers in the same order, bit for bit.
``cells.state.npz`` holds that state (the sums, the cell index, the layers) with what it
belongs to:

- ``build``: the build id of the ``cells.parquet`` it was written with (a state beside
  another build's map is not used);
- ``runs``: the fingerprints of the store's exploration runs the map was built from, and
  ``num_views``: how many views they hold; a store whose runs begin with them (runs were
  appended, :mod:`care_maps.ingest.runs`) grows the map by the views after, while a removed or
  replaced run rebuilds it;
- ``frame``: the map frame the views were fused in (a frame found again rebuilds).

It is written only where the whole state fitted one pass of the memory budget (else the next
change rebuilds), and costs :meth:`CandidateSums.bytes_per_candidate` a cell on disk.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from care_maps.core.outputs import write_atomic
from care_maps.core.store import Store, run_records

__all__ = ["STATE_FILE", "GridState", "frame_of", "load_state", "save_state", "store_runs"]

STATE_FILE = "cells.state.npz"


@dataclass(frozen=True)
class GridState:
    """A grid's streaming state and what it was built from (see the module docstring)."""

    build: bytes
    config: bytes
    """The grid config's fingerprint and the vocabulary it was built for."""
    runs: tuple[str, ...]
    num_views: int
    frame: bytes
    keys: np.ndarray
    """(N,) packed cell key of each cell id."""
    sums: tuple[np.ndarray, np.ndarray, np.ndarray]
    """:meth:`CandidateSums.state`."""
    z_max: np.ndarray
    rgb: np.ndarray
    num_pixels: np.ndarray


def store_runs(store: Store) -> tuple[str, ...]:
    """The fingerprints of ``store``'s runs, in view order."""
    return tuple(str(run.fingerprint) for run in run_records(store.meta))


def frame_of(stamp: bytes) -> bytes:
    """The map-frame part of a store stamp (:func:`care_maps.fuse.frame.store_stamp`)."""
    return stamp.partition(b"|")[2]


ZIP_TIME = (1980, 1, 1, 0, 0, 0)
"""Every member's date in the state's zip file: the same state, the same bytes (``np.savez``
stamps each member with the time it was written)."""


def save_state(path: Path, state: GridState) -> None:
    """Write ``state`` to ``path`` atomically, an ``.npz`` file ``np.load`` reads (one
    ``.npy`` member per array, stored, dated :data:`ZIP_TIME`). Not listed in the store's
    marker: it is a cache, not a map (``care check`` has nothing to say of it), and each
    member's CRC-32, checked as it is read, finds it damaged (:func:`load_state`)."""
    arrays = {
        "build": np.frombuffer(state.build, np.uint8),
        "config": np.frombuffer(state.config, np.uint8),
        "runs": np.array(state.runs, dtype=str),
        "num_views": np.int64(state.num_views),
        "frame": np.frombuffer(state.frame, np.uint8),
        "keys": state.keys,
        "moments": state.sums[0],
        "classes": state.sums[1],
        "scalars": state.sums[2],
        "z_max": state.z_max,
        "rgb": state.rgb,
        "num_pixels": state.num_pixels,
    }

    def write(tmp: Path) -> None:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as saved:
            for name, array in arrays.items():
                member = zipfile.ZipInfo(f"{name}.npy", date_time=ZIP_TIME)
                with saved.open(member, "w", force_zip64=True) as out:
                    np.lib.format.write_array(out, np.asanyarray(array), allow_pickle=False)

    write_atomic(path, write)


def load_state(path: Path) -> GridState | None:
    """The state saved at ``path``; None when there is none or it cannot be read, a member
    whose CRC-32 does not match included (the map is then built from every view, which is
    always right)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as saved:
            return GridState(
                build=saved["build"].tobytes(),
                config=saved["config"].tobytes(),
                runs=tuple(str(r) for r in saved["runs"]),
                num_views=int(saved["num_views"]),
                frame=saved["frame"].tobytes(),
                keys=saved["keys"],
                sums=(saved["moments"], saved["classes"], saved["scalars"]),
                z_max=saved["z_max"],
                rgb=saved["rgb"],
                num_pixels=saved["num_pixels"],
            )
    except Exception:  # a cache: whatever a damaged file raises, the map is rebuilt
        # (zipfile and numpy raise RuntimeError, NotImplementedError, zlib.error or
        # MemoryError for some damaged headers, before any CRC is checked)
        return None
