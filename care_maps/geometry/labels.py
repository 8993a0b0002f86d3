"""Which labels of a 3-D scene to draw so that none lands on another.

A viewer draws a box's label at its anchor whatever the zoom; where several instances
overlap (segments of one wall, a sofa and its cushions) their labels pile into one unreadable
block. :func:`spread_labels` keeps the label of the most important instance of every
neighbourhood and hides the others (they stay selectable, and their label shows on hover).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["LABELS_ACROSS", "LABEL_GAP", "label_gap", "spread_labels"]

LABEL_GAP = 0.5
"""Least metres between the anchors of two drawn labels: a label of about ten characters at
the distance a room is viewed from."""
LABELS_ACROSS = 12
"""Labels of about ten characters that fit side by side across an overview of a scene."""


def label_gap(anchors: np.ndarray) -> float:
    """Metres between drawn labels for a scene with these anchors: an overview shows the
    whole scene, so a label covers about 1/:data:`LABELS_ACROSS` of its widest horizontal
    extent (a house needs a wider gap than a room); at least :data:`LABEL_GAP`."""
    anchors = np.asarray(anchors, np.float64).reshape(-1, 3)
    if len(anchors) < 2:
        return LABEL_GAP
    extent = float(np.ptp(anchors[:, :2], axis=0).max())
    return max(LABEL_GAP, extent / LABELS_ACROSS)


def spread_labels(anchors: np.ndarray, priority: np.ndarray, gap: float = LABEL_GAP) -> np.ndarray:
    """Boolean mask of the labels to draw, greedily by ``priority`` (highest first, ties by
    index): a label is drawn unless a drawn one lies within ``gap`` of its anchor on the
    floor plane (x, y: labels stacked in height overlap in a view from above).

    So no two drawn anchors are within ``gap`` of each other, and every hidden label has a
    drawn one of higher priority within ``gap``."""
    anchors = np.asarray(anchors, np.float64).reshape(-1, 3)[:, :2]
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
