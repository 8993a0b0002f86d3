"""The sample world: procedural scenes with ground truth, rendered into real recordings.

``scene`` (floor plan + furniture from ``catalogue``), ``trajectory`` (exploration path),
``render`` (open3d ray casting), ``record`` (recordings and datasets via ingest's writer),
``groundtruth`` (the file beside each recording), ``viz`` (Rerun view of the scenes).
"""
