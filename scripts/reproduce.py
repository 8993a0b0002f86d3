"""Regenerate every number and figure of docs/results.md, from scratch.

1. Two Matterport-like datasets (``care sample make --preset matterport-like``) on seeds
   20 and 77, with the generator's statistics and measured first attempts.
2. The full evaluation of each (every strategy, criterion and k, both protocols), with
   the pre-registered tables (``evaluate.report.preregistered``) in ``results.md``.
3. The sweep of perception settings (``research.sweep``) on a third, smaller dataset.
4. ``OUT/results_section.md``: the tables docs/results.md shows, and ``OUT/sweep.png``
   (copy it to ``docs/sweep.png``).

The steps are :mod:`research.reproduce`. Every step skips what is already done, so an
interrupted run resumes. Run it with ``nice``: about 45 minutes on two busy cores with the
default sizes.

    python scripts/reproduce.py OUT [--scenes 4] [--sweep-scenes 2] [--seeds 20 77]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from research.reproduce import main

if __name__ == "__main__":
    main()
