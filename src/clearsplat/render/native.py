"""The CPU backend: the native rasterizer's prepared views (subsets and exact incremental
re-renders).

The forward pass of the original 3DGS code (EWA splatting, 16x16 tiles, front-to-back alpha
compositing); every convention is on one page, ``docs/conventions.md`` ("Rasterization").
:func:`prepare_view` does projection, binning and sorting once; the :class:`PreparedView` it
returns renders any subset (``keep``) and, exactly, only the tiles a removal can change
(:meth:`PreparedView.rerender`, :meth:`PreparedView.rerender_tiles`);
:meth:`PreparedView.pruned` drops what no render keeping a given set of Gaussians can reach;
:meth:`PreparedView.restrict` (in place) and :meth:`PreparedView.subset` give the view of a
subset scene without projecting again.

A subset never changes the order of the remaining Gaussians (ties in depth are broken by
Gaussian index), so rendering with ``keep`` equals rendering the subset scene bit for bit.
"""

from __future__ import annotations

import weakref
from typing import Sequence

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import Gaussians, RenderSettings
from . import _kernels
from .base import (TILE, Contributions, RenderResult, TilePatch, _check_background,
                   _check_indices, _check_keep, _check_layers, _TiledView, sh_to_evaluate)

__all__ = ["PreparedView", "prepare_view", "check_threads"]

# The last keep mask a view gathered, and its gather: (view, copy of keep, keep over the
# visible Gaussians). The filter renders one view with the same keep several times in a row
# (a verifying view's two ranges); comparing N bytes in order costs a tenth of gathering them
# in depth order. One slot for all views (a copy per view would hold V x N bytes), emptied
# when its view is gone.
_EMPTY: tuple = (lambda: None, None, None)
_last_keep: tuple = _EMPTY


def _forget_dead(ref) -> None:
    global _last_keep
    if _last_keep[0] is ref:
        _last_keep = _EMPTY


def check_threads(num_threads) -> int:
    if num_threads is None:
        return _kernels.max_threads()
    if isinstance(num_threads, bool) or not isinstance(num_threads, (int, np.integer)) \
            or num_threads < 1:
        raise ClearsplatError(f"expected a positive int, got {num_threads!r}", field="num_threads")
    return int(num_threads)




# -- prepared view ---------------------------------------------------------------------------
class PreparedView(_TiledView):
    """One camera with projection, tile binning and depth sort done (visible Gaussians only).

    Made by :func:`prepare`. Stores the visible Gaussians compactly (about 60 bytes each plus
    4 bytes per (tile, Gaussian) pair), so many views of millions of Gaussians fit in memory.

    Attributes
    ----------
    camera : Camera
    tile_size : int
        16.
    grid : (int, int)
        Rows and columns of tiles. Tile id ``t`` covers rows ``16 * (t // cols)`` ... and
        columns ``16 * (t % cols)`` ... .
    num_visible : int
        Gaussians that survive culling in this view.
    num_gaussians : int
        Gaussians in the scene (the length ``keep`` masks must have).
    memory_bytes : int
        Bytes held by the arrays of this view.
    """

    def __init__(self, *, camera: Camera, num_gaussians: int, splats, rects, index, offsets,
                 lists, num_threads: int):
        self.camera = camera
        self.num_gaussians = int(num_gaussians)
        self._splats, self._rects, self._index = splats, rects, index
        self._offsets, self._lists = offsets, lists
        self._num_threads = num_threads
        # Gaussian index -> visible id, built on demand: (map,) over every Gaussian (-1: not
        # visible) or (sorted visible Gaussian indices, their visible ids), int32 each.
        self._by_index = None
        self._floor = None  # (V,) bool over the held Gaussians that renders must keep (pruned)

    # -- properties ------------------------------------------------------------------------
    @property
    def num_visible(self) -> int:
        return int(self._index.shape[0])

    @property
    def visible(self) -> np.ndarray:
        """(V,) int64 indices of the visible Gaussians, front to back."""
        return self._index.astype(np.int64)

    @property
    def memory_bytes(self) -> int:
        arrays = [self._splats, self._rects, self._index, self._offsets, self._lists]
        arrays += [a for a in (self._floor,) if a is not None]
        arrays += list(self._by_index or ())
        # A restricted view holds the front of its arrays, and the whole of them in memory.
        return int(sum(a.base.nbytes if isinstance(a.base, np.ndarray) else a.nbytes
                       for a in arrays))

    def centres_inside(self) -> np.ndarray:
        """(N,) bool: the visible Gaussians whose projected centre lies inside the image.

        Culled Gaussians (behind the near plane, below alpha 1/255, off-image) are False.
        """
        return _kernels.centres_inside(self._splats, self._index, self.num_gaussians,
                                       self.camera.width, self.camera.height)

    def __repr__(self) -> str:
        return (f"PreparedView({self.camera.width}x{self.camera.height}, "
                f"{self.num_visible} of {self.num_gaussians} Gaussians visible, "
                f"{self.memory_bytes / 2**20:.1f} MiB)")

    # -- helpers ---------------------------------------------------------------------------
    def _keep(self, keep, field: str = "keep") -> np.ndarray | None:
        """(V,) bool keep over the visible Gaussians, or None."""
        global _last_keep
        keep = _check_keep(keep, self.num_gaussians, field)
        keep_v = None
        if keep is not None:
            view, mask, gathered = _last_keep     # one read: another thread may replace it
            if view() is self and np.array_equal(mask, keep):
                keep_v = gathered
            else:
                keep_v = _kernels.take_mask(keep, self._index, self._num_threads)
                keep_v.flags.writeable = False
                _last_keep = (weakref.ref(self, _forget_dead), keep.copy(), keep_v)
        if keep_v is not None and self._floor is not None and (self._floor & ~keep_v).any():
            raise ClearsplatError("this view was pruned for renders that keep every Gaussian of "
                                  "its floor, and this one leaves some out", field=field)
        return keep_v

    def _check_removed(self, ids: np.ndarray, field: str) -> None:
        """A pruned view renders removals only of Gaussians outside its floor."""
        if self._floor is not None and ids.size and self._floor[ids].any():
            raise ClearsplatError("this view was pruned for renders that keep every Gaussian of "
                                  "its floor, and this removal takes some away", field=field)

    def _ids(self, gaussians, field: str) -> np.ndarray:
        """Sorted unique visible ids (int32) of the given Gaussians (invisible ones dropped)."""
        a = np.asarray(gaussians)
        if a.dtype == np.bool_:
            # A mask over all Gaussians: its visible part, in visible order, is already unique.
            if a.shape != (self.num_gaussians,):
                raise ClearsplatError(f"expected a ({self.num_gaussians},) bool mask, got shape "
                                      f"{a.shape}", field=field)
            if 16 * np.count_nonzero(a) >= self.num_visible:
                # Dense: one gather over the visible Gaussians beats a lookup per index.
                seen = _kernels.take_mask(a, self._index, self._num_threads)
                return np.flatnonzero(seen).astype(np.int32)
            idx = np.flatnonzero(a)
        else:
            idx = _check_indices(a, self.num_gaussians, field)
        if self._by_index is None:
            if 3 * self.num_visible >= self.num_gaussians:
                # A view that sees much of the scene: a Gaussian -> visible id map (-1: not
                # visible), quicker to build than a sort.
                vid = np.full(self.num_gaussians, -1, dtype=np.int32)
                vid[self._index] = np.arange(self.num_visible, dtype=np.int32)
                self._by_index = (vid,)
            else:
                # A view of a small part (a neighbourhood of a dense capture): its visible
                # Gaussians sorted by index, in memory of their number, not the scene's.
                self._by_index = _kernels.sort_index(self._index, self._num_threads)
        if len(self._by_index) == 1:
            ids = self._by_index[0][idx]
            ids = ids[ids >= 0]
        else:
            by_index, ids_by_index = self._by_index
            if by_index.size == 0:
                return np.empty(0, dtype=np.int32)
            # Queried in the map's own dtype: a wider one would copy the map on every call.
            at = np.minimum(np.searchsorted(by_index, idx.astype(by_index.dtype)),
                            by_index.size - 1)
            ids = ids_by_index[at[by_index[at] == idx]]
        if ids.size < 4096:     # a sort and one comparison: np.unique costs more when small
            ids = np.sort(ids)
            if ids.size > 1:
                ids = ids[np.concatenate(([True], ids[1:] != ids[:-1]))]
            return ids.astype(np.int32)
        flags = np.zeros(self.num_visible, dtype=bool)   # a scatter beats sorting large sets
        flags[ids] = True
        return np.flatnonzero(flags).astype(np.int32)

    def _tile_pixels(self, tiles: np.ndarray):
        """Row and column indices (T, 16, 1), (T, 1, 16) clipped into the image, and validity."""
        cols = self.grid[1]
        rows = (tiles // cols)[:, None] * TILE + np.arange(TILE)
        cols_ = (tiles % cols)[:, None] * TILE + np.arange(TILE)
        valid = (rows < self.camera.height)[:, :, None] & (cols_ < self.camera.width)[:, None, :]
        rows = np.minimum(rows, self.camera.height - 1)[:, :, None]
        cols_ = np.minimum(cols_, self.camera.width - 1)[:, None, :]
        return rows, cols_, valid

    # -- rendering -------------------------------------------------------------------------
    def render(self, *, keep=None, background=(0.0, 0.0, 0.0)) -> RenderResult:
        """Render the view, optionally only the Gaussians where ``keep`` is True.

        Parameters
        ----------
        keep : (N,) bool, optional
            Gaussians to render (all by default). Equal, bit for bit, to rendering the subset.
        background : 3 floats
            Colour behind the Gaussians.

        Returns
        -------
        RenderResult
        """
        keep_v = self._keep(keep)
        bg = _check_background(background)
        h, w = self.camera.height, self.camera.width
        out = RenderResult(np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32),
                           np.empty((h, w), np.float32))
        _kernels.composite(self._splats, self._offsets, self._lists, keep_v,
                          np.arange(self.num_tiles, dtype=np.int32), w, h, bg, *out,
                          self._num_threads)
        return out

    def render_layers(self, layers, *, tiles=None, background=(0.0, 0.0, 0.0)) -> list:
        """Each of ``layers`` rendered on its own, in one pass over the tile lists: equal, bit
        for bit, to ``[self.render(keep=m) for m in layers]``, and each Gaussian's footprint
        is evaluated once, for its own layer.

        Parameters
        ----------
        layers : sequence of (N,) bool, or (N,) int
            Disjoint subsets of the Gaussians (at most 127): one mask per layer, or each
            Gaussian's layer id (-1: in none; layers 0 to the largest id), which is cheaper.
        tiles : int array of tile ids, optional
            Composite only these tiles: the renders are exact there, zero elsewhere.
        background : 3 floats

        Returns
        -------
        list of RenderResult, one per layer
        """
        labels, count = _check_layers(layers, self.num_gaussians)
        bg = _check_background(background)
        code = labels[self._index]
        if (self._floor is not None and count and self._floor.any()
                and (count > 1 or (code[self._floor] != 0).any())):
            raise ClearsplatError("this view was pruned for renders that keep every Gaussian of "
                                  "its floor, and a layer leaves some out", field="layers")
        h, w = self.camera.height, self.camera.width
        tiles = (np.arange(self.num_tiles, dtype=np.int32) if tiles is None
                 else self._check_tiles(tiles))
        rgb, alpha, depth = _kernels.composite_layers(self._splats, self._offsets, self._lists,
                                                      code, count, tiles, w, h, bg,
                                                      self._num_threads)
        return [RenderResult(rgb[k], alpha[k], depth[k]) for k in range(count)]

    def render_pair(self, *, keep, first=None, tiles=None, start: RenderResult | None = None,
                    background=(0.0, 0.0, 0.0)) -> tuple[RenderResult, RenderResult]:
        """Two renders in one pass over the tile lists: ``first`` (all Gaussians when None) and
        ``keep``.

        Equal, bit for bit, to ``(self.render(keep=first), self.render(keep=keep))`` and
        cheaper: each Gaussian's footprint is evaluated once for both (the filter's R_i and
        R_i^-i, or a base and the base without a removal).

        Parameters
        ----------
        keep : (N,) bool
        first : (N,) bool, optional
        tiles : int array of tile ids, optional
            Composite only these tiles; the other pixels of both outputs hold ``start``'s
            values (zeros without ``start``). For incremental use: the result is exact only in
            ``tiles``.
        start : RenderResult, optional
        background : 3 floats

        Returns
        -------
        (RenderResult, RenderResult)
        """
        keep_v = self._keep(keep)
        if keep_v is None:
            raise ClearsplatError("expected an (N,) bool mask", field="keep")
        first_v = self._keep(first, "first")
        bg = _check_background(background)
        tiles = (np.arange(self.num_tiles, dtype=np.int32) if tiles is None
                 else self._check_tiles(tiles))
        h, w = self.camera.height, self.camera.width

        def outputs():
            if start is not None:
                base = self._check_result(start)
                return RenderResult(*(np.array(a, dtype=np.float32, order="C", copy=True)
                                      for a in base))
            return RenderResult(np.zeros((h, w, 3), np.float32), np.zeros((h, w), np.float32),
                                np.zeros((h, w), np.float32))

        a, b = outputs(), outputs()
        _kernels.composite_pair(self._splats, self._offsets, self._lists, first_v, keep_v, tiles,
                               w, h, bg, a, b, self._num_threads)
        return a, b

    def tiles_touched(self, gaussians) -> np.ndarray:
        """Tiles whose lists hold any of ``gaussians``: the only tiles their removal can change.

        Parameters
        ----------
        gaussians : int array of Gaussian indices, or (N,) bool mask
            Gaussians not visible in this view touch nothing.

        Returns
        -------
        (T,) int32 sorted unique tile ids.
        """
        ids = self._ids(gaussians, "gaussians")
        _, tiles = _kernels.tiles_touched(self._rects, np.array([0, ids.size], np.int64), ids,
                                         self.grid[1], self.grid[0], self._num_threads)
        return tiles

    def rerender(self, base: RenderResult, *, keep, tiles,
                 background=(0.0, 0.0, 0.0)) -> RenderResult:
        """A copy of ``base`` with only ``tiles`` re-composited using ``keep``.

        Equals ``render(keep=keep)`` exactly when ``tiles`` covers
        :meth:`tiles_touched` of every Gaussian whose keep differs from ``base``'s.

        Parameters
        ----------
        base : RenderResult
            A render of this view (with the same ``background``).
        keep : (N,) bool or None
        tiles : int array of tile ids
        background : 3 floats

        Returns
        -------
        RenderResult
        """
        base = self._check_result(base)
        keep_v = self._keep(keep)
        tiles = self._check_tiles(tiles)
        bg = _check_background(background)
        out = RenderResult(*(np.array(a, dtype=np.float32, order="C", copy=True) for a in base))
        _kernels.composite(self._splats, self._offsets, self._lists, keep_v, tiles,
                          self.camera.width, self.camera.height, bg, *out, self._num_threads)
        return out

    def rerender_tiles(self, *, keep, removals: Sequence, tiles_list: Sequence | None = None,
                       background=(0.0, 0.0, 0.0), base: RenderResult | None = None
                       ) -> list[TilePatch]:
        """Batched exact incremental renders, one per removal, of only the tiles it changes.

        For removal ``r`` (Gaussian indices dropped on top of ``~keep``), the tiles
        :meth:`tiles_touched` ``(r)`` (or ``tiles_list[r]``) are re-composited. All
        (removal, tile) pairs run in parallel.

        Parameters
        ----------
        keep : (N,) bool or None
            The base subset (None: all Gaussians).
        removals : sequence of int arrays (or (N,) bool masks)
        tiles_list : sequence of int arrays, optional
            Tiles to re-composite per removal instead of the touched ones.
        background : 3 floats
        base : RenderResult, optional
            This view's render of ``keep`` with ``background`` (for example from
            :meth:`render`). Within a tile, only the pixels inside the pixel boxes of the
            removed Gaussians are then composited and the others copied from ``base``: the
            same result, since compositing never visits a Gaussian outside its box, and much
            less work for removals that cover part of a tile. A ``base`` that is not that
            render gives wrong patches.

        Returns
        -------
        list of TilePatch, one per removal. Use :meth:`gather` for the same tiles of a full
        image and :meth:`scatter` to paste a patch into a render.
        """
        keep_v = self._keep(keep)
        bg = _check_background(background)
        removals = list(removals)
        ids = [self._ids(r, f"removals[{i}]") for i, r in enumerate(removals)]
        for i, a in enumerate(ids):
            self._check_removed(a, f"removals[{i}]")
        rem_offsets = np.zeros(len(ids) + 1, dtype=np.int64)
        rem_offsets[1:] = np.cumsum([a.size for a in ids])
        rem_ids = np.concatenate(ids) if ids else np.empty(0, np.int32)
        if tiles_list is None:
            task_offsets, task_tiles = _kernels.tiles_touched(
                self._rects, rem_offsets, rem_ids, self.grid[1], self.grid[0], self._num_threads)
        else:
            tiles_list = list(tiles_list)
            if len(tiles_list) != len(removals):
                raise ClearsplatError(f"{len(tiles_list)} tile lists for {len(removals)} removals",
                                      field="tiles_list")
            sets = [self._check_tiles(t, f"tiles_list[{i}]") for i, t in enumerate(tiles_list)]
            task_offsets = np.zeros(len(sets) + 1, dtype=np.int64)
            task_offsets[1:] = np.cumsum([s.size for s in sets])
            task_tiles = np.concatenate(sets) if sets else np.empty(0, np.int32)
        if base is not None:
            h, w = self.camera.height, self.camera.width
            if not isinstance(base, RenderResult) or base.rgb.shape != (h, w, 3):
                raise ClearsplatError(f"expected a RenderResult of this view ({h}x{w})",
                                      field="base")
            base = (base.rgb, base.alpha, base.depth)
        rgb, alpha, depth = _kernels.composite_patches(
            self._splats, self._offsets, self._lists, self._rects, keep_v, rem_offsets, rem_ids,
            task_offsets, task_tiles, self.camera.width, self.camera.height, bg,
            self._num_threads, base=base)
        return [TilePatch(task_tiles[a:b], rgb[a:b], alpha[a:b], depth[a:b])
                for a, b in zip(task_offsets[:-1], task_offsets[1:])]

    def gather(self, image, tiles) -> np.ndarray:
        """The pixels of ``tiles`` in a full image, shaped like a patch.

        Parameters
        ----------
        image : (H, W, ...) array
        tiles : (T,) int tile ids

        Returns
        -------
        (T, 16, 16, ...) array, 0 outside the image.
        """
        image = np.asarray(image)
        if image.shape[:2] != (self.camera.height, self.camera.width):
            raise ClearsplatError(f"expected an image of {self.camera.height}x{self.camera.width}, "
                                  f"got shape {image.shape}", field="image")
        tiles = np.asarray(tiles)
        if tiles.size and (tiles.min() < 0 or tiles.max() >= self.num_tiles):
            raise ClearsplatError(f"tile id out of range 0..{self.num_tiles - 1}", field="tiles")
        rows, cols, valid = self._tile_pixels(tiles.astype(np.int64).reshape(-1))
        out = image[rows, cols]
        out[~valid] = 0
        return out

    def scatter(self, patch: TilePatch, base: RenderResult) -> RenderResult:
        """A copy of ``base`` with the tiles of ``patch`` pasted in."""
        base = self._check_result(base)
        rows, cols, valid = self._tile_pixels(np.asarray(patch.tiles, dtype=np.int64))
        out = RenderResult(*(np.array(a, copy=True) for a in base))
        r = np.broadcast_to(rows, valid.shape)[valid]
        c = np.broadcast_to(cols, valid.shape)[valid]
        out.rgb[r, c] = patch.rgb[valid]
        out.alpha[r, c] = patch.alpha[valid]
        out.depth[r, c] = patch.depth[valid]
        return out

    def pruned(self, floor) -> "PreparedView":
        """A smaller copy that renders every subset containing ``floor`` as this view does.

        Compositing walks a tile's list front to back and a pixel stops where its
        transmittance would fall below 1e-4. A render that keeps every Gaussian of ``floor``
        (and maybe more) has, at every point of the list, at most the transmittance of
        ``floor`` alone, so wherever ``floor`` alone has stopped a pixel it has stopped it too.
        The copy keeps only the list entries that reach some pixel (alpha at least 1/255) not
        yet stopped under ``floor`` alone, and the Gaussians they name; every render, re-render
        and contribution list of a ``keep`` containing ``floor`` is bit for bit the same.

        Parameters
        ----------
        floor : (N,) bool
            Gaussians that every later render of this view keeps (with those of an earlier
            pruning: floors add up).

        Returns
        -------
        PreparedView
            Its :attr:`visible` are the Gaussians it holds; a ``keep`` that leaves out a
            Gaussian of the floor, or a removal of one, raises :class:`ClearsplatError`.
        """
        floor = _check_keep(floor, self.num_gaussians, "floor")
        floor_v = _kernels.take_mask(floor, self._index, self._num_threads)
        if self._floor is not None:
            floor_v |= self._floor
        h, w = self.camera.height, self.camera.width
        live = _kernels.live_entries(self._splats, self._offsets, self._lists, floor_v, w, h,
                                     self._num_threads)
        lists = self._lists[live]
        # Entries per tile: the running count of live entries at each tile's start.
        running = np.zeros(live.size + 1, dtype=np.int64)
        np.cumsum(live, out=running[1:])
        offsets = running[self._offsets]
        held = np.zeros(self.num_visible, dtype=bool)
        held[lists] = True
        # Held Gaussians keep their front-to-back order: lists stay ascending.
        new_id = np.cumsum(held, dtype=np.int64).astype(np.int32) - 1
        view = PreparedView(camera=self.camera, num_gaussians=self.num_gaussians,
                            splats=self._splats[held], rects=self._rects[held],
                            index=self._index[held], offsets=offsets,
                            lists=new_id[lists], num_threads=self._num_threads)
        view._floor = floor_v[held]
        return view

    def restrict(self, keep) -> "PreparedView":
        """Make this view, in place, the view of the subset scene
        ``scene.subset(np.flatnonzero(keep))``, without projecting again; returns it.

        Each Gaussian is projected on its own (its record does not depend on the others), the
        depth sort is stable with ties in Gaussian order, and tile lists run front to back: so
        dropping the Gaussians outside ``keep`` from the records and lists, and numbering the
        rest as the subset does, gives the arrays that :func:`prepare` of the subset scene
        computes, bit for bit. The arrays are reused (no new memory); renders made before
        are not affected.

        Parameters
        ----------
        keep : (N,) bool
            Gaussians of the subset.

        Returns
        -------
        PreparedView
            This view, now of ``keep.sum()`` Gaussians indexed as the subset scene.
        """
        keep = _check_keep(keep, self.num_gaussians, "keep")
        if keep is None:
            raise ClearsplatError("expected an (N,) bool mask", field="keep")
        if self._floor is not None:
            raise ClearsplatError("a pruned view holds only part of the visible Gaussians and "
                                  "cannot be restricted to a subset", field="keep")
        arrays = [np.ascontiguousarray(a) for a in (self._splats, self._rects, self._index,
                                                     self._offsets, self._lists)]
        arrays = [a if a.flags.writeable else a.copy() for a in arrays]
        splats, rects, index, offsets, lists = arrays
        num, pairs = _kernels.restrict_view(splats, rects, index, offsets, lists, keep)
        self._splats, self._rects, self._index = splats[:num], rects[:num], index[:num]
        self._offsets, self._lists = offsets, lists[:pairs]
        self.num_gaussians = int(np.count_nonzero(keep))
        self._by_index = None
        return self

    def subset(self, keep) -> "PreparedView":
        """A new view of the subset scene ``scene.subset(np.flatnonzero(keep))``, without
        projecting again (see :meth:`restrict`, which does the same in place).

        Parameters
        ----------
        keep : (N,) bool

        Returns
        -------
        PreparedView
        """
        view = PreparedView(camera=self.camera, num_gaussians=self.num_gaussians,
                            splats=self._splats.copy(), rects=self._rects.copy(),
                            index=self._index.copy(), offsets=self._offsets.copy(),
                            lists=self._lists.copy(), num_threads=self._num_threads)
        view._floor = self._floor
        view.restrict(keep)
        # Compact copies of the fronts the restriction left, so the new view holds no more.
        view._splats, view._rects = view._splats.copy(), view._rects.copy()
        view._index, view._lists = view._index.copy(), view._lists.copy()
        return view

    def contributions(self, mask, *, keep=None) -> Contributions:
        """Every ``(pixel, gaussian, alpha * T)`` the compositing adds where ``mask`` is True.

        Parameters
        ----------
        mask : (H, W) bool
        keep : (N,) bool, optional

        Returns
        -------
        Contributions, ordered by pixel, then front to back.
        """
        h, w = self.camera.height, self.camera.width
        mask = np.asarray(mask)
        if mask.dtype != np.bool_ or mask.shape != (h, w):
            raise ClearsplatError(f"expected a ({h}, {w}) bool mask, got {mask.dtype} "
                                  f"{mask.shape}", field="mask")
        pixel, ids, weight = _kernels.contributions(self._splats, self._offsets, self._lists,
                                                   self._keep(keep), mask, w, h,
                                                   self._num_threads)
        return Contributions(pixel, self._index[ids].astype(np.int64), weight)




def prepare_view(g: Gaussians, camera: Camera, keep, near: float, num_threads: int,
                 settings: RenderSettings | None = None) -> PreparedView:
    """A :class:`PreparedView` of checked inputs (``keep`` (N,) bool or None)."""
    s = RenderSettings() if settings is None else settings
    splats, rects, index = _kernels.project(
        g.means, g.scales, g.quats, g.opacities, sh_to_evaluate(g, s), keep,
        camera.world_to_camera, camera.K, camera.position, camera.width, camera.height, near,
        num_threads, eps2d=s.eps2d, antialiased=s.antialiased, radius_clip=s.radius_clip)
    rows, cols = -(-camera.height // TILE), -(-camera.width // TILE)
    offsets, lists = _kernels.bin_tiles(rects, cols, rows, num_threads)
    return PreparedView(camera=camera, num_gaussians=len(g), splats=splats, rects=rects,
                        index=index, offsets=offsets, lists=lists, num_threads=num_threads)

