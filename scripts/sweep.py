"""``python scripts/sweep.py``: the command line of :mod:`care_maps.research.sweep` (its docstring says
what it does), run from a checkout."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from care_maps.research.sweep import main

if __name__ == "__main__":
    main()
