"""The one interface between the filter's stages and the renderer.

The stages never import a renderer. They ask the round's backend for

- :meth:`FilterBackend.prepare_views`: one prepared view per input camera, as a *view set*
  (``views[j]``, ``len(views)``, ``views.sees(j, gaussians)``, ``views.release()``,
  ``views.stats(derived=...)``);
- :meth:`FilterBackend.verifier`: the :class:`~clearsplat.filter.verify.Verifier` that scores
  removals on those views;

and everything else they need of the renderer goes through the methods of a prepared view,
which both renderers implement with the same results and checks
(:class:`clearsplat.render.PreparedView` and :class:`clearsplat.render.gsplat.GsplatView`):

=====================================================  =========================================
``render(keep=)``                                      a whole image of a subset
``render_pair(keep=, first=, tiles=, start=)``         two subsets in one pass (R_i and R_i^-i)
``rerender(base, keep=, tiles=)``                      ``base`` composited again in ``tiles``
``rerender_tiles(keep=, removals=, base=)``            one tile patch per removal
``tiles_touched(gaussians)``                           the tiles a removal can change
``centres_inside()``                                   (N,) bool, centres inside the image
``tile_pixels(tiles)``                                  flat pixel indices of tiles
``contributions(mask, keep=)``                         blending weights at a region's pixels
``camera``, ``tile_size``, ``grid``, ``num_visible``   the view's geometry
=====================================================  =========================================

:class:`NativeBackend` is the CPU rasterizer (``config.device == "cpu"``): views within a
memory budget, incremental verification on tile patches, the views and renders of one round
handed on to the next. :class:`DeviceBackend` is gsplat on a CUDA device: whole-image
verification renders, nothing handed on. :class:`TorchBackend` (``config.backend="torch"``)
is the native rasterizer's math in batched torch ops on ``config.device`` (CPU or CUDA):
incremental verification, every removal of a view re-composited in one batch
(:class:`clearsplat.render.torch_view.TorchView`). :func:`backend_for` picks one from the
config; no other module of the filter decides which renderer answers.
"""

from __future__ import annotations

import numpy as np

from .._memory import available_memory, check_memory, estimate_filter_memory
from ..errors import ClearsplatError
from .config import FilterConfig
from .verify import Verifier
from .views import PreparedViews

__all__ = ["FilterBackend", "NativeBackend", "DeviceBackend", "TorchBackend", "HeldView",
           "backend_for"]


class FilterBackend:
    """What the filter's stages ask of a renderer (see the module docstring).

    Attributes
    ----------
    incremental : bool
        Verification re-composites only the tiles a removal touches, and leaves out the views
        it cannot change.
    hands_on : bool
        A round's views and renders can be handed to the next round (:class:`Carry
        <clearsplat.filter.rounds.Carry>`).
    """

    incremental = False
    hands_on = False

    def __init__(self, config: FilterConfig):
        self.config = config

    def check_memory(self, scene, previous=None) -> None:
        """Refuse a round that cannot fit in memory (before any work)."""

    def prepare_views(self, scene, previous=None, hoods=None, index=None):
        """One prepared view per input camera of ``scene``, as a view set, and the tiles per
        view that ``previous`` (the round before) must composite again: ``(views, touched)``,
        ``touched`` filled as views are read. ``hoods``: per camera j, the (V,) bool views
        whose Gaussians its view holds (:func:`~clearsplat.filter.neighbours.neighbourhoods`;
        None: all). ``index``: the round's :class:`~clearsplat.filter.association.ViewIndex`,
        which builds those Gaussian masks faster (optional)."""
        raise NotImplementedError

    def verifier(self, views, images: list, *, epsilon: float, hole_alpha: float) -> Verifier:
        """The scorer of removals on ``views`` against ``images``."""
        return Verifier(views, images, epsilon=epsilon, incremental=self.incremental,
                        hole_alpha=hole_alpha)


class NativeBackend(FilterBackend):
    """The native CPU rasterizer (:func:`clearsplat.render.prepare`)."""

    def __init__(self, config: FilterConfig):
        super().__init__(config)
        self.incremental = bool(config.incremental)
        self.hands_on = self.incremental
        self.budget = None if config.view_memory is None else int(config.view_memory * 1e9)

    def check_memory(self, scene, previous=None) -> None:
        available = None
        if previous is not None:
            # What the previous round hands on becomes this round's views as they are taken
            # (and its renders are dropped view by view): count it as available.
            free = available_memory()
            available = None if free is None else free + previous.nbytes()
        check_memory(estimate_filter_memory(len(scene), scene.cameras, view_budget=self.budget),
                     available=available)

    def prepare_views(self, scene, previous=None, hoods=None, index=None):
        from ..render import prepare
        threads = self.config.num_threads
        touched: dict = {}      # view -> tiles the previous round's removals touched there

        source = None if previous is None else previous.source

        def make(i: int):
            old = None if previous is None else previous.views.take(i)
            if old is not None:
                touched[i] = old.tiles_touched(~previous.keep)
                return old.restrict(previous.keep)
            if source is not None:      # from the whole scene: ``scene`` holds no copy
                whole, kept = source
                held = kept if hoods is None else kept & held_mask(whole, hoods, i)
                return prepare(whole, scene.cameras[i], keep=held,
                               num_threads=threads).restrict(kept)
            return prepare(scene, scene.cameras[i], keep=held_mask(scene, hoods, i, index),
                           num_threads=threads)

        budget = self.budget
        if budget is not None and previous is not None:
            # Room for what stays held while this round runs (Carry.reserve), from the views
            # handed on as well.
            budget = max(budget - previous.reserve, 0)
            previous.views.make_room(previous.reserve)
        views = PreparedViews(len(scene), scene.cameras, make, budget=budget,
                              skip_unseen=self.incremental)
        return views, touched


class DeviceViews(list):
    """The view set of :class:`DeviceBackend`: every view held, every view visited."""

    def sees(self, j: int, gaussians) -> bool:
        return True

    def release(self) -> None:
        pass

    def stats(self, *, derived: int) -> dict:
        return {}


class DeviceBackend(FilterBackend):
    """gsplat on a CUDA device (:func:`clearsplat.render.gsplat.prepare_gsplat_views`): one
    upload of the Gaussians shared by the views; the host holds only images and masks, so
    there is no memory check here."""

    def prepare_views(self, scene, previous=None, hoods=None, index=None):
        from ..render.gsplat import prepare_gsplat_views
        views = prepare_gsplat_views(scene, scene.cameras, device=self.config.device)
        if hoods is not None:
            views = [HeldView(v, held_mask(scene, hoods, j, index))
                     for j, v in enumerate(views)]
        return DeviceViews(views), {}


class HeldView:
    """A prepared view that renders only the ``held`` ((N,) bool) Gaussians: every keep mask
    it is given is narrowed to them (None: all of them). The device backend's bounded
    neighbourhoods (the native backend prepares its views on the subset instead; both render
    the same Gaussians)."""

    def __init__(self, view, held: np.ndarray):
        self._view, self._held = view, held

    def __getattr__(self, name):
        return getattr(self._view, name)

    def _k(self, keep):
        return self._held if keep is None else (np.asarray(keep) & self._held)

    def render(self, *, keep=None, **kwargs):
        return self._view.render(keep=self._k(keep), **kwargs)

    def render_pair(self, *, keep, first=None, **kwargs):
        return self._view.render_pair(keep=self._k(keep), first=self._k(first), **kwargs)

    def rerender(self, base, *, keep, **kwargs):
        return self._view.rerender(base, keep=self._k(keep), **kwargs)

    def render_layers(self, layers, **kwargs):
        if isinstance(layers, np.ndarray) and layers.dtype != np.bool_:   # layer ids
            return self._view.render_layers(np.where(self._held, layers, -1), **kwargs)
        return self._view.render_layers([self._k(m) for m in layers], **kwargs)

    def tiles_touched(self, gaussians):
        g = np.asarray(gaussians)
        g = g & self._held if g.dtype == np.bool_ else g[self._held[g]]
        return self._view.tiles_touched(g)

    def centres_inside(self):
        return self._view.centres_inside() & self._held

    def contributions(self, mask, *, keep=None):
        return self._view.contributions(mask, keep=self._k(keep))


class TorchBackend(FilterBackend):
    """The native rasterizer's math in torch on ``config.device``
    (:class:`clearsplat.render.torch_view.TorchView`): one upload of the Gaussians shared by
    the views, each view projected once; incremental verification with all removals of a view
    in one batched call; views not handed on."""

    def __init__(self, config: FilterConfig):
        super().__init__(config)
        self.incremental = bool(config.incremental)
        try:
            from ..render.torch_view import import_torch
            import_torch(config.device)
        except ImportError as e:
            raise ClearsplatError(f"'torch' on {config.device!r}: {e}", field="backend") from None

    def prepare_views(self, scene, previous=None, hoods=None, index=None):
        from ..render.torch_view import prepare_torch, upload_torch
        gaussians = upload_torch(scene, device=self.config.device)

        def make(i: int):
            return prepare_torch(gaussians, scene.cameras[i],
                                 keep=held_mask(scene, hoods, i, index))

        views = PreparedViews(len(scene), scene.cameras, make, budget=None,
                              skip_unseen=self.incremental)
        return views, {}


def held_mask(scene, hoods, j: int, index=None) -> np.ndarray | None:
    """(N,) bool: the Gaussians of the views in camera j's neighbourhood ``hoods[j]``, and the
    shared ones (None without ``hoods``), through ``index`` (a ViewIndex of ``scene``) where
    given."""
    if hoods is None:
        return None
    if index is None:
        return np.append(hoods[j], True)[scene.view_id]     # SHARED (-1): the last entry
    held = index.views_mask(hoods[j], len(scene))
    held[index.shared] = True
    return held


def backend_for(config: FilterConfig) -> FilterBackend:
    """The backend of ``config.backend``; ``"auto"``: native on ``"cpu"``, gsplat on a CUDA
    device."""
    if config.backend == "torch":
        return TorchBackend(config)
    return NativeBackend(config) if config.device == "cpu" else DeviceBackend(config)
