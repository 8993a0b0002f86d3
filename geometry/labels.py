"""Which labels of a 3-D scene to draw so that none lands on another.

A viewer draws a box's label at its anchor whatever the zoom; where several instances
overlap (segments of one wall, a sofa and its cushions) their labels pile into one unreadable
block. :func:`spread_labels` keeps the label of the most important instance of every
neighbourhood and hides the others (they stay selectable, and their label shows on hover).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["LABEL_GAP", "spread_labels"]

LABEL_GAP = 0.5
"""Metres between the anchors of two drawn labels: a label of about ten characters at the
distance a room is viewed from."""


def spread_labels(anchors: np.ndarray, priority: np.ndarray, gap: float = LABEL_GAP) -> np.ndarray:
    """Boolean mask of the labels to draw, greedily by ``priority`` (highest first, ties by
    index): a label is drawn unless a drawn one lies within ``gap`` of its anchor.

    So no two drawn anchors are within ``gap`` of each other, and every hidden label has a
    drawn one of higher priority within ``gap``."""
    anchors = np.asarray(anchors, np.float64).reshape(-1, 3)
    order = np.lexsort((np.arange(len(anchors)), -np.asarray(priority, np.float64)))
    tree = cKDTree(anchors)
    shown = np.zeros(len(anchors), bool)
    hidden = np.zeros(len(anchors), bool)
    for i in order:
        if hidden[i]:
            continue
        shown[i] = True
        hidden[tree.query_ball_point(anchors[i], gap)] = True
    return shown
