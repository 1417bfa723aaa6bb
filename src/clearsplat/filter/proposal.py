"""Distractor proposal: exclusion renders, similarity, support, and candidate regions.

Paper, "Distractor Proposal". For input view i we compare the input image with the
exclusion render R_i^-i (camera i rendered without the Gaussians predicted from view i)
on a patch grid, keep patches that the other views support, and split the low-similarity
patches into two ranges whose 8-connected components become candidate regions.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..features import upsample_nearest
from .masks import label8

#: Views whose image pairs :func:`propose` stacks at once for the extractor.
_SIMILARITY_BATCH = 8

__all__ = [
    "ViewProposal", "Region", "cell_index_map", "patch_means", "support_condition",
    "proposal_ranges", "connected_regions", "propose_view", "propose",
]


@dataclass(eq=False)
class Region:
    """One connected component of a proposal range in one view.

    Attributes
    ----------
    view : int
        The input view it was found in [i_k].
    range : int
        1 for the first similarity range (s < tau1), 2 for the second [r_k].
    cells : (h, w) bool
        The component on the feature grid.
    shape : (H, W)
        The image size.
    pixels : (H, W) bool
        The component upsampled to the image (nearest neighbour) [M_k]: made from ``cells``
        on each read (read-only), so that a region holds 1/256 of the image's bytes.
    """

    view: int
    range: int
    cells: np.ndarray
    shape: tuple

    @property
    def pixels(self) -> np.ndarray:
        out = upsample_nearest(self.cells, *self.shape)
        out.flags.writeable = False
        return out


@dataclass(eq=False)
class ViewProposal:
    """Everything the proposal stage computed for one input view.

    Attributes
    ----------
    view : int
    similarity : (h, w) float32
        Feature similarity between the input and the exclusion render [s_i].
    support : (h, w) bool
        The support condition [g_i]: opacity above eta and a farther surface revealed.
    ranges : (h, w) int8
        0 outside both ranges, 1 for B_i^1, 2 for B_i^2.
    regions : list of Region
    mask1, mask2 : (H, W) bool
        Unions of the first- and second-range regions [M_i^1, M_i^2].
    unreliable : (H, W) bool or None
        Pixels that verification also leaves out (:func:`~clearsplat.filter.verify.range_masks`).
    exclusion : (H, W, 3) float32 or None
        What the similarity compared the input with (kept for the diagnostic pictures): the
        exclusion render R_i^-i, or the reveal reference in its place (``reveal_reference``).
    """

    view: int
    similarity: np.ndarray
    support: np.ndarray
    ranges: np.ndarray
    regions: list = field(default_factory=list)
    mask1: np.ndarray | None = None
    mask2: np.ndarray | None = None
    unreliable: np.ndarray | None = None
    exclusion: np.ndarray | None = None

    @property
    def support_pixels(self) -> np.ndarray:
        """The support condition upsampled to image resolution, (H, W) bool."""
        h, w = self.mask1.shape
        return upsample_nearest(self.support, h, w)


def cell_index_map(grid_shape: tuple[int, int], height: int, width: int) -> np.ndarray:
    """Index of the grid cell each pixel belongs to, (H, W) int64.

    Consistent with :func:`clearsplat.features.upsample_nearest`.
    """
    h, w = grid_shape
    ids = np.arange(h * w, dtype=np.int64).reshape(h, w)
    return upsample_nearest(ids, height, width)


def patch_means(values: np.ndarray, cells: np.ndarray, num_cells: int,
                valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-cell mean of ``values`` over the pixels where ``valid`` holds.

    Returns ``(mean, count)`` as flat arrays of length ``num_cells``; the mean is 0 where the
    count is 0.
    """
    c = cells.ravel()
    v = values.ravel().astype(np.float64)
    if valid is not None:
        keep = valid.ravel()
        c, v = c[keep], v[keep]
    total = np.bincount(c, weights=v, minlength=num_cells)
    count = np.bincount(c, minlength=num_cells)
    mean = np.divide(total, count, out=np.zeros(num_cells), where=count > 0)
    return mean, count


def support_condition(alpha_excluded: np.ndarray, depth_full: np.ndarray,
                      depth_excluded: np.ndarray, grid_shape: tuple[int, int], *,
                      eta: float) -> np.ndarray:
    """The support condition g_i on the feature grid, (h, w) bool.

    A patch is supported when the mean accumulated opacity of the exclusion render exceeds
    ``eta`` and, over the pixels with valid (positive) depth in both renders, the mean depth
    before exclusion is nearer than after. Patches without such pixels fail.
    """
    height, width = alpha_excluded.shape
    cells = cell_index_map(grid_shape, height, width)
    n = grid_shape[0] * grid_shape[1]
    a_mean, _ = patch_means(alpha_excluded, cells, n)
    both = (depth_full > 0) & (depth_excluded > 0)
    z_before, count = patch_means(depth_full, cells, n, both)
    z_after, _ = patch_means(depth_excluded, cells, n, both)
    ok = (a_mean > eta) & (count > 0) & (z_before < z_after)
    return ok.reshape(grid_shape)


def proposal_ranges(similarity: np.ndarray, support: np.ndarray, *, tau1: float, tau2: float,
                    second_range: bool = True, single_threshold: bool = False) -> np.ndarray:
    """Label each supported patch 1 (s < tau1), 2 (tau1 <= s < tau2) or 0.

    ``single_threshold`` puts everything below tau2 in range 1 (the paper's ablation);
    ``second_range=False`` drops range 2.
    """
    ranges = np.zeros(similarity.shape, dtype=np.int8)
    if single_threshold:
        ranges[(similarity < tau2) & support] = 1
        return ranges
    ranges[(similarity < tau1) & support] = 1
    if second_range:
        ranges[(similarity >= tau1) & (similarity < tau2) & support] = 2
    return ranges


def connected_regions(ranges: np.ndarray, which: int) -> list[np.ndarray]:
    """8-connected components of ``ranges == which``, as (h, w) bool masks, in label order."""
    labels, count = label8(ranges == which)
    return [labels == k for k in range(1, count + 1)]

def propose_view(view: int, similarity: np.ndarray, alpha_excluded: np.ndarray,
                 depth_full: np.ndarray, depth_excluded: np.ndarray, *, eta: float,
                 tau1: float, tau2: float, second_range: bool = True,
                 single_threshold: bool = False) -> ViewProposal:
    """The proposal of one input view from its similarity map and renders.

    Parameters
    ----------
    view : int
    similarity : (h, w) float
        s_i on the feature grid.
    alpha_excluded : (H, W) float
        Accumulated opacity of R_i^-i.
    depth_full, depth_excluded : (H, W) float
        Expected depth of R_i and R_i^-i (0 where nothing was hit).
    """
    height, width = alpha_excluded.shape
    support = support_condition(alpha_excluded, depth_full, depth_excluded,
                                similarity.shape, eta=eta)
    ranges = proposal_ranges(similarity, support, tau1=tau1, tau2=tau2,
                             second_range=second_range, single_threshold=single_threshold)
    out = ViewProposal(view=view, similarity=similarity.astype(np.float32), support=support,
                       ranges=ranges)
    for r in (1, 2):
        out.regions.extend(Region(view=view, range=r, cells=cells, shape=(height, width))
                           for cells in connected_regions(ranges, r))
    # The union of a range's components is the range.
    out.mask1, out.mask2 = (upsample_nearest(ranges == r, height, width) for r in (1, 2))
    return out


def propose(state, renders, extractor) -> list[ViewProposal]:
    """The proposal of every input view (the paper's "Distractor Proposal").

    Parameters
    ----------
    state : RoundState
    renders : ExclusionRenders
        R_i and R_i^-i of every view (compared with the scene's input images).
    extractor : FeatureExtractor
        Gives the similarity s_i between each input and its exclusion render.

    Returns
    -------
    list of ViewProposal, one per view: s_i, the support g_i, the ranges B_i^1 and B_i^2 and
    their regions M_k.
    """
    # R_i^-i, or the reveal reference that stands in for it (``reveal_reference``).
    config, excl, full = state.config, renders.reference, renders.full
    images = state.scene.images
    sims = []
    # A few views at a time: two stacks of every view's image would hold 2 x V images at
    # once (0.18 GB at 64 views of 256x448); the similarity of a pair does not depend on
    # the others in its batch.
    for start in range(0, state.num_views, _SIMILARITY_BATCH):
        part = range(start, min(start + _SIMILARITY_BATCH, state.num_views))
        pair = (np.stack([images[i] for i in part]), np.stack([excl[i].rgb for i in part]))
        # Threads as the rasterizer's (config.num_threads), for extractors that use them.
        sims.extend(extractor.similarity(*pair, workers=config.num_threads)
                    if getattr(extractor, "pairs_in_threads", False)
                    else extractor.similarity(*pair))
    state.lap("features")
    proposals = []
    for i in range(state.num_views):
        proposals.append(propose_view(
            i, sims[i], excl[i].alpha, full[i].depth, excl[i].depth, eta=config.eta,
            tau1=state.tau1, tau2=state.tau2, second_range=config.second_range,
            single_threshold=config.single_threshold))
        proposals[-1].exclusion = excl[i].rgb
    return proposals
