"""When CARe helps: the paired gain of each measure over a grid of perception settings.

Re-encodes a sample-world dataset under each setting of (bias rate, bias noise scale,
view-dependent bias, view noise), builds both maps, plays the paper's pre-registered rules
and max confidence, and writes ``OUT/sweep.parquet`` and ``OUT/sweep.png``
(:mod:`research.sweep`). A re-run resumes: the stores of finished settings are kept.

    python scripts/sweep.py DATASET OUT [--design oat|grid] [--values bias_rate=0.1,0,0.3 ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from research.sweep import main

if __name__ == "__main__":
    main()
