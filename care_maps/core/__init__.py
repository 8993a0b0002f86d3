"""CARe maps shared core: errors, typed records, geometry, the feature store, encoders, Rerun helpers.

Nothing here imports a stage package (ingest, fuse, query, replan, world, evaluate).
"""

__version__ = "0.1.0"
