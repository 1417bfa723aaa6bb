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

from dataclasses import dataclass

import numpy as np

from ..scene import Scene
from .association import view_members

__all__ = ["covisibility", "ViewPlan", "view_plan"]

#: Gaussians sampled per view for the co-visibility (evenly over the view's members).
_SAMPLES = 4096


def covisibility(scene: Scene, *, samples: int = _SAMPLES) -> np.ndarray:
    """(V, V) float64: ``C[j, v]``, the share of view v's Gaussians (a sample of at most
    ``samples``, evenly spaced in index order) whose centres camera j sees in front of it and
    inside its image (``C[v, v]`` included)."""
    v_count = scene.num_views
    out = np.zeros((v_count, v_count))
    means = scene.gaussians.means
    picks = []
    for members in view_members(scene):
        picks.append(members[np.linspace(0, members.size - 1,
                                         min(samples, members.size)).astype(int)])
    sizes = np.array([p.size for p in picks])
    if not sizes.any():
        return out
    # Every view's sample at once, per camera (the arithmetic of Camera.project).
    pts = means[np.concatenate(picks)].astype(np.float64)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    has = sizes > 0
    for j, cam in enumerate(scene.cameras):
        pc = cam.to_camera(pts)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = cam.K[0, 0] * pc[:, 0] / z + cam.K[0, 2]
            v = cam.K[1, 1] * pc[:, 1] / z + cam.K[1, 2]
            inside = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        counts = np.add.reduceat(inside.astype(np.int64), starts[has])
        out[j, has] = counts / sizes[has]
    return out


@dataclass(eq=False)
class ViewPlan:
    """Which views each camera's renders hold, and which views verify each view's candidates.

    Attributes
    ----------
    hoods : list of (V,) bool, or None
        Per camera j, the views whose Gaussians its renders hold (S(j)); None: every view.
    verifiers : list of list of int, or None
        Per view i, its verification views V_i; None: chosen from the exclusion renders'
        counts, as the paper does.
    """

    hoods: list | None
    verifiers: list | None


#: ``neighbours="auto"``: bounded neighbourhoods of this many views ...
DENSE_NEIGHBOURS = 7
#: ... from this many input views on (docs/method.md, "Dense captures").
DENSE_MIN_VIEWS = 24


def dense_options(num_views: int, neighbours, verify_views: str) -> tuple[int | None, str]:
    """``FilterConfig.neighbours`` and ``verify_views`` for a scene of ``num_views`` views,
    with ``"auto"`` resolved: :data:`DENSE_NEIGHBOURS` neighbours from :data:`DENSE_MIN_VIEWS`
    views on, every view below; mutual verification views where the neighbourhoods bound
    anything (fewer neighbours than other views), the paper's V_i otherwise."""
    if neighbours == "auto":
        neighbours = DENSE_NEIGHBOURS if num_views >= DENSE_MIN_VIEWS else None
    if verify_views == "auto":
        bounded = neighbours is not None and neighbours < num_views - 1
        verify_views = "mutual" if bounded else "centres"
    return neighbours, verify_views


def view_plan(scene: Scene, *, neighbours: int | None, verify_views: str,
              num_verify_views: int, leave_out: int = 0) -> ViewPlan | None:
    """The :class:`ViewPlan` of ``FilterConfig.neighbours`` and ``verify_views``; None for the
    paper's (every view held, V_i from the counts of the exclusion renders).

    Views within ``leave_out`` places of view i (``FilterConfig.leave_out``) are left out of
    its exclusion render anyway: they are neither its neighbours nor its verifiers.
    """
    v_count = scene.num_views
    bounded = neighbours is not None and neighbours < v_count - 1
    if not bounded and verify_views == "centres":
        return None
    c = covisibility(scene)
    shared = c + c.T
    # V_i: the views that see the most of view i's Gaussians (the paper), or that share the
    # most of its field of view both ways ("mutual").
    score = c if verify_views == "centres" else shared
    verifiers = [sorted((j for j in range(v_count) if abs(j - v) > leave_out),
                        key=lambda j: (-score[j, v], j))[:num_verify_views]
                 for v in range(v_count)]
    if not bounded:
        return ViewPlan(None, verifiers if verify_views != "centres" else None)
    hoods = [np.zeros(v_count, dtype=bool) for _ in range(v_count)]
    for j in range(v_count):
        hoods[j][j] = True
        others = sorted((k for k in range(v_count) if abs(k - j) > leave_out),
                        key=lambda k: (-shared[j, k], k))
        hoods[j][others[:neighbours]] = True
    for v in range(v_count):     # the views that verify v hold v
        for j in verifiers[v]:
            hoods[j][v] = True
    return ViewPlan(hoods, verifiers)
