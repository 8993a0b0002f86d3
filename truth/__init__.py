"""Ground truth of labelled scenes: one model (:mod:`truth.model`), its geometry
(:mod:`truth.geometry`), one reader/writer module per file format (:mod:`truth.formats`)
and the format-independent entry points (:mod:`truth.load`).

It sits below both the sample world (which exports its ground truth in every format) and the
evaluation (which reads any of them)."""
