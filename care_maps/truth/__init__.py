"""Ground truth of labelled scenes: one model (:mod:`care_maps.truth.model`), its geometry
(:mod:`care_maps.truth.geometry`), one reader/writer module per file format (:mod:`care_maps.truth.formats`)
and the format-independent entry points (:mod:`care_maps.truth.load`).

It sits below both the sample world (which exports its ground truth in every format) and the
evaluation (which reads any of them)."""
