"""Expansion: a verified candidate grows to the Gaussians around its region.

Paper, "Candidate Verification": a candidate that passes its individual test is expanded to
hat C_k, the Gaussians of its region dilated by ``dilation`` pixels within the support g_i,
so that the soft edge of a distractor goes with it. With refinement it also takes every
8-connected group of pixels touching the region whose Gaussians stand in front of the
static reference, within the cells of low similarity; beyond the candidate's own Gaussians
it takes those in front of the static reference by depth, and those whose colour is beyond
the view's colour noise (:mod:`.explained`).
"""

from __future__ import annotations

import numpy as np

from ..features import upsample_nearest
from .masks import dilate, label8, touched_components

__all__ = ["expand", "growth_labels"]


def expand(state, candidates: list, proposals: list, region_map, refinement) -> None:
    """Set ``c.expanded`` (hat C_k, (M,) int64) of every candidate in ``candidates``.

    Parameters
    ----------
    state : RoundState
    candidates : list of Candidate
    proposals : list of ViewProposal
        Their views' proposals (the support g_i, the similarity s_i).
    region_map : RegionMap
        Regions to Gaussians.
    refinement : Refinement
        The Gaussians in front of the reference (the expansion keeps only these) and their
        pixels.
    """
    config, revealing = state.config, refinement.revealing
    # Beyond the candidate's own Gaussians, only those in front by depth and those whose
    # colour is beyond the view's colour noise (Refinement.expandable).
    expandable = refinement.expandable
    grow = revealing is not None
    labels: dict = {}       # view -> its groups of pixels in front, made once
    support: dict = {}      # view -> the support upsampled to pixels, made once
    for c in candidates:
        if c.view not in support:
            support[c.view] = proposals[c.view].support_pixels
            if grow:
                labels[c.view] = growth_labels(refinement.front_pixels[c.view],
                                               proposals[c.view].similarity, state.tau2)
        pixels = dilate(c.pixels, config.dilation) & support[c.view]
        if grow:    # and every group that it touches
            pixels = pixels | touched_components(labels[c.view], pixels)
        g = region_map(c.view, pixels)
        if expandable is not None:
            c.expanded = g[expandable[g] | np.isin(g, c.gaussians)]
        else:
            c.expanded = g if revealing is None else g[revealing[g]]


def growth_labels(front: np.ndarray, similarity: np.ndarray, tau2: float) -> np.ndarray:
    """(H, W) int labels of the 8-connected groups of ``front`` (the view's pixels whose
    Gaussians stand in front of the static reference) within the cells of ``similarity``
    (the view's feature grid) below ``tau2``; 0 outside them. The support is judged per
    patch, and a distractor's patches where the other views render little drop out of the
    paper's expansion: an accepted candidate also takes every group it touches."""
    low = upsample_nearest(similarity < tau2, *front.shape)
    return label8(front & low)[0]
