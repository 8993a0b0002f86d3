"""The sample world's perception: a simulated vision-language model with known, named
failure modes, served as the ``labels`` encoder plugin.

Sample-world recordings carry a per-pixel class image and instance image. The encoder
(:class:`care_maps.world.perception.encoder.LabelsEncoder`) turns them into dense feature maps in the
same form as the ``clip`` encoder, as a vision-language model would perceive the view, so
that everything downstream (fuse, query, replan, evaluate) runs unchanged while the
mistakes are under control.

Text side: sentence embeddings of the class names (:mod:`care_maps.core.encoders.sentence`,
all-MiniLM-L6-v2 where installed). Similar names have similar embeddings, so every
confusion below follows meaning: a table is mistaken for a coffee table or a desk, not
for a toilet.

Image side, per view (a (fh, fw, d) map, one cell per ``stride`` x ``stride`` pixels):

1. Every *segment* (a visible instance, or a structure class where the instance id is 0)
   gets one feature vector for this view: the embedding of its *perceived* class, mixed
   with a confusable class by a view-dependent amount, plus a little isotropic noise.
2. A cell's feature is the mixture of the vectors of the segments whose pixels it holds,
   each weighted by ``pixels in cell / segment area ** area_exponent`` (a small object
   owns the cells it appears in, as a VLM's attention would), optionally *bled* with its
   neighbours' mixtures (a spatial blur), then L2-normalised.

The mechanisms the paper argues about (``PerceptionModel``), each switched on and off by
its own knob:

- **persistent bias**: a fraction of instances, and a fraction of classes scene-wide (all
  their instances), are perceived as their nearest other class by text embedding, in every
  view and with little noise: a confident, consistent mistake ("query table, grounding
  chair"). Multi-view fusion cannot undo it; it is what uncertainty measures must see
  through by other means. ``class_bias_per_scene`` draws the biased classes per scene (from
  the scene's seed, among the classes it holds) instead of once per encoder seed;
  ``bias_noise_scale`` sets how confident the biased mistake is (1 = as noisy as any other).
- **view-dependent bias** (``view_bias_rate``): an instance misread in some of its views,
  as the class of the largest other object in the same view (its context: a pillow read as
  the bed it lies on, a cup as the table). Fusion mixes the two readings; the per-view
  spread is large, which is the inconsistency CARe's measures look for.
- **view-dependent noise**: a level in [0, 1] per segment and view that grows with the
  segment's mean distance, with how grazing the surfaces are seen (normals from depth),
  with truncation at the image border and for small segments; the segment's feature is
  pulled towards a confuser drawn (per view) from the classes similar to it by that level
  times a per-view uniform draw. Plus bleeding of neighbouring segments near mask
  boundaries. These mistakes change from view to view, so fusion averages them out and
  the per-view spread (standard error, pairwise KL) is large.

Everything random is a hash (:mod:`care_maps.world.perception.counters`) of ``options.seed`` with
instance ids, class names and view stamps, so a recording encodes to the same features on
every run, and a biased instance is biased in every view.

Sample-world datasets record their perception model (``care sample make --preset``) in the
ground truth beside each recording; with ``--perception default`` the encoder uses the
recorded one (:func:`care_maps.world.perception.model.recorded_perception`). ``perception`` may
also carry overrides, ``"NAME:key=value,key=value"``
(:func:`care_maps.world.perception.model.perception_model`), as sweeps use it.

Modules: ``model`` (the knobs, the presets and their specs; light enough for the CLI to
import), ``encoder`` (the encoder, registered as the ``care_maps.core.encoders`` entry point
``labels``), ``counters`` (the counter-based random numbers).
"""
