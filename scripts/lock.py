"""Write ``requirements.lock``: the exact version of every package the project needs (its
dependencies, the ``dev`` extra's, theirs, and so on), read from this environment, and no
other. ``scripts/install.sh`` installs under it, and the output digests
(``tests/data/outputs.json``) are made and checked under it (the test skips, saying so,
where the installed versions differ: Parquet bytes, float sums and PNGs change with library
releases). Refresh after changing ``pyproject.toml``'s dependencies: ``python
scripts/lock.py``.
"""

from __future__ import annotations

import re
from importlib import metadata
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "requirements.lock"
PROJECT = "care-maps"
EXTRAS = ("dev",)


def _name(text: str) -> str:
    return re.sub(r"[-_.]+", "-", text).lower()


def closure(project: str = PROJECT, extras: tuple[str, ...] = EXTRAS) -> dict[str, str]:
    """Name -> installed version of every package ``project[extras]`` needs, transitively."""
    found: dict[str, str] = {}
    todo = [(project, frozenset(extras))]
    while todo:
        name, wanted = todo.pop()
        dist = metadata.distribution(name)
        key = _name(dist.metadata["Name"])
        if key in found and not wanted:
            continue
        if key != _name(project):
            found[key] = dist.version
        for text in dist.requires or []:
            req = Requirement(text)
            env = default_environment()
            if req.marker is not None:
                needed = any(req.marker.evaluate({**env, "extra": e}) for e in wanted or {""})
                if not needed:
                    continue
            child = _name(req.name)
            if child not in found:
                try:
                    metadata.distribution(child)
                except metadata.PackageNotFoundError:
                    continue  # optional on this platform and absent
                todo.append((child, frozenset(req.extras)))
    return found


def main() -> None:
    pins = closure()
    header = (
        "# The exact versions of the project's dependency closure (care-maps[dev]), written by\n"
        "# scripts/lock.py from the environment the output digests were made in; install.sh\n"
        "# installs under it. Nothing outside the closure is listed.\n"
    )
    LOCK.write_text(header + "".join(f"{n}=={v}\n" for n, v in sorted(pins.items())))
    print(f"{LOCK.name}: {len(pins)} packages")


if __name__ == "__main__":
    main()
