"""Expansion: a verified candidate grows to the Gaussians around its region.

Paper, "Candidate Verification": a candidate that passes its individual test is expanded to
hat C_k, the Gaussians of its region dilated by ``dilation`` pixels within the support g_i,
so that the soft edge of a distractor goes with it. With refinement it also takes every
8-connected group of pixels touching the region whose Gaussians stand in front of the
static reference, within the cells of low similarity; beyond the candidate's own Gaussians
it takes those in front of the static reference by depth, and with ``refine.EXPAND_QUANTILE``
also those whose colour differs from the other views' by more than the view's static content
does.
"""

from __future__ import annotations

import numpy as np

from ..features import upsample_nearest
from .masks import dilate, label8, touched_components

__all__ = ["expand", "grow_connected"]


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
    # Beyond the candidate's own Gaussians, only those in front by depth,
    # and with ``refine.EXPAND_QUANTILE`` those whose colour is far beyond the static content's.
    expandable = refinement.expandable
    grow = revealing is not None
    labels: dict = {}
    support: dict = {}      # view -> the support upsampled to pixels, made once
    for c in candidates:
        if c.view not in support:
            support[c.view] = proposals[c.view].support_pixels
        pixels = dilate(c.pixels, config.dilation) & support[c.view]
        if grow:
            pixels = grow_connected(pixels, c.view, labels, refinement.front_pixels[c.view],
                                    proposals[c.view], state.tau2)
        g = region_map(c.view, pixels)
        if expandable is not None:
            c.expanded = g[expandable[g] | np.isin(g, c.gaussians)]
        else:
            c.expanded = g if revealing is None else g[revealing[g]]


def grow_connected(pixels: np.ndarray, view: int, labels: dict, front: np.ndarray, proposal,
                   tau2) -> np.ndarray:
    """``pixels`` with every 8-connected component that it touches of ``front`` (the view's
    (H, W) pixels whose Gaussians stand in front of the static reference), within the cells of
    similarity below tau2 (the support is judged per patch, and a distractor's patches where
    the other views render little drop out of the paper's expansion); ``labels`` caches the
    components per view."""
    if view not in labels:
        grow = front.copy()
        h, w = grow.shape
        grow &= upsample_nearest(proposal.similarity < tau2, h, w)
        labels[view] = label8(grow)[0]
    return pixels | touched_components(labels[view], pixels)
