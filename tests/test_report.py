"""Report helpers: what the verdict picture paints."""

from __future__ import annotations

import numpy as np

from clearsplat import Scene
from clearsplat.render import render
from clearsplat.report import outline, removed_pixels
from clearsplat.synth import make_world, reconstruct


def test_removed_pixels_without_pixel_alignment_is_where_the_render_changes():
    world = make_world("object", num_views=2, height=16, width=24)
    aligned = reconstruct(world.cameras, world.images, world.depths, seed=0)
    loose = Scene(aligned.gaussians, aligned.view_id, None, aligned.cameras, aligned.images)
    removed = np.zeros(len(loose), bool)
    removed[(loose.view_id == 0) & (aligned.pixel_id % 24 < 6)] = True     # a left strip
    before = render(loose, loose.cameras[0])
    after = render(loose, loose.cameras[0], keep=~removed)
    mask = removed_pixels(loose, removed, 0, before, after, epsilon=0.01)
    assert np.array_equal(mask, np.abs(before.rgb - after.rgb).sum(-1) > 0.01)
    assert mask[:, :4].mean() > 0.5 and not mask[:, 12:].any()
    # Pixel-aligned: exactly the pixels of the view's removed Gaussians.
    exact = removed_pixels(aligned, removed, 0)
    assert exact[:, :6].all() and not exact[:, 6:].any()
    assert not removed_pixels(aligned, removed, 1).any()


def test_outline_is_the_border_of_the_mask():
    mask = np.zeros((7, 7), bool)
    mask[1:6, 1:6] = True
    ring = outline(mask)
    assert ring.sum() == 16 and not ring[2:5, 2:5].any() and (ring <= mask).all()
    edge = np.zeros((4, 4), bool)
    edge[:, :2] = True                          # touching the image border
    assert outline(edge)[:, 1].all() and not outline(edge)[1:3, 0].any()
