"""Query stage: a map's candidates as arrays, confidence of target classes, free text to classes."""

from __future__ import annotations

from care_maps.query.confidence import confidence, log_confidence, rank_by_confidence
from care_maps.query.map import MEASURES, CandidateMap, load_map, map_from_table
from care_maps.query.text import TextMatch, resolve_text

__all__ = [
    "MEASURES",
    "CandidateMap",
    "TextMatch",
    "confidence",
    "load_map",
    "log_confidence",
    "map_from_table",
    "rank_by_confidence",
    "resolve_text",
]
