"""Where the `labels` perception model's mistakes come from, on a sample-world recording.

Ingests the recording with the ``labels`` encoder (``--perception`` preset, default
``default``), builds the instance map with oracle masks (``labels`` proposals, so mask
errors do not blur the picture) and prints two tables (:mod:`research.perception_breakdown`):

1. per ground-truth instance, whether the fused top-1 class is right, and for the wrong
   ones whether the instance is persistently biased (seen as its confuser in every view)
   or unbiased and misread through view-dependent noise;
2. per class query (protocol ``class``), the first attempt (max confidence) and, for each
   failure, its cause: the retrieved instance is biased *into* the target, every instance
   of the target is biased *away* from it, or neither (noise).

    python scripts/perception_breakdown.py [RECORDING] [--perception default|ideal]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from research.perception_breakdown import main

if __name__ == "__main__":
    main()
