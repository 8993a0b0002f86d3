"""CARe maps: robot recordings in, open-vocabulary semantic maps, queries and context-aware
replanning out.

One import namespace. The stages are its subpackages, each on its layer (a layer imports
only those below it; ``tests/test_layers.py``):

- :mod:`care_maps.core`: errors, the store, frames, keys, encoders, outputs, Rerun helpers;
- :mod:`care_maps.runtime`: processes, threads, signals, budgets (how work runs);
- :mod:`care_maps.geometry`: transforms, planes and the views' consistency (pure maths);
- :mod:`care_maps.ingest`: recordings and dataset folders into a store;
- :mod:`care_maps.truth` and :mod:`care_maps.world`: ground truth, and the sample world;
- :mod:`care_maps.fuse`: the grid and instance maps;
- :mod:`care_maps.query` and :mod:`care_maps.replan`: answers and the next goal;
- :mod:`care_maps.evaluate` and :mod:`care_maps.research`: evaluations and studies;
- :mod:`care_maps.cli`: the ``care`` program on top.

The bundled sample recording and vocabularies are package data (``care_maps/data``).
"""
