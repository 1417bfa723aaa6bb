"""Bounded neighbourhoods: which input views each camera's renders hold.

The paper's exclusion render R_i^-i composites the Gaussians of every other view. With N views
every pass of the filter is then N cameras times all Gaussians, and at dense captures R_i^-i
also holds every other view's passers-by, the front-most of which hides the surface that
should reveal view i's own distractor. With ``FilterConfig.neighbours = K`` each camera j
renders only the Gaussians of the views in its neighbourhood S(j):

- j itself, whose Gaussians R_j^-j leaves out;
- the K other views that share the most of j's field of view (co-visibility below);
- every view v that j verifies: j among the ``num_verify_views`` views that see the most of
  v's Gaussians, so that each candidate's removal still changes its verifying renders.

Co-visibility is measured on a sample of each view's Gaussians: ``C[j, v]`` is the share of
view v's sampled centres that camera j sees in front of it and inside its image; views i and j
share ``C[i, j] + C[j, i]``. With at most K + 1 views every S(j) holds every view and the
filter is exactly the paper's.
"""

from __future__ import annotations

import numpy as np

from ..scene import Scene

__all__ = ["covisibility", "neighbourhoods"]

#: Gaussians sampled per view for the co-visibility (evenly over the view's members).
_SAMPLES = 4096


def covisibility(scene: Scene, *, samples: int = _SAMPLES) -> np.ndarray:
    """(V, V) float64: ``C[j, v]``, the share of view v's Gaussians (a sample of at most
    ``samples``, evenly spaced in index order) whose centres camera j sees in front of it and
    inside its image (``C[v, v]`` included)."""
    v_count = scene.num_views
    order = np.argsort(scene.view_id, kind="stable")
    bounds = np.searchsorted(scene.view_id[order], np.arange(v_count + 1))
    out = np.zeros((v_count, v_count))
    means = scene.gaussians.means
    for v in range(v_count):
        members = order[bounds[v]:bounds[v + 1]]
        if members.size == 0:
            continue
        pick = members[np.linspace(0, members.size - 1, min(samples, members.size)).astype(int)]
        pts = means[pick].astype(np.float64)
        for j, cam in enumerate(scene.cameras):
            uv, z = cam.project(pts)
            with np.errstate(invalid="ignore"):
                inside = ((z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width)
                          & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height))
            out[j, v] = np.count_nonzero(inside) / pick.size
    return out


def neighbourhoods(scene: Scene, neighbours: int | None, num_verify_views: int
                   ) -> list[np.ndarray] | None:
    """Per camera j, the (V,) bool views its renders hold (S(j), see the module), or None when
    every view's renders hold every view (``neighbours`` None or at least V - 1).

    Ties in co-visibility go to the lower view index.
    """
    v_count = scene.num_views
    if neighbours is None or neighbours >= v_count - 1:
        return None
    c = covisibility(scene)
    shared = c + c.T
    hoods = [np.zeros(v_count, dtype=bool) for _ in range(v_count)]
    for j in range(v_count):
        hoods[j][j] = True
        others = sorted((j2 for j2 in range(v_count) if j2 != j), key=lambda k: (-shared[j, k], k))
        hoods[j][others[:neighbours]] = True
    for v in range(v_count):     # the views that verify v hold v
        verifiers = sorted((j for j in range(v_count) if j != v), key=lambda j: (-c[j, v], j))
        for j in verifiers[:num_verify_views]:
            hoods[j][v] = True
    return hoods
