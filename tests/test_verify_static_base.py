"""The individual test against a base without the other views' candidates
(``verify_base="static"``): its terms against full renders, and the filter with it."""

from types import SimpleNamespace

import numpy as np
import pytest

from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.filter.verify import Verifier, _static_base_terms, change_weighted_terms
from clearsplat.metrics import removal_stats
from clearsplat.render import prepare
from clearsplat.synth import distractor_truth, make_world, reconstruct


@pytest.fixture(scope="module")
def street():
    world = make_world("street", num_views=6, seed=0, height=64, width=112)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    return scene, distractor_truth(scene, world)


class _Views(list):
    def sees(self, j, gaussians):
        gaussians = np.asarray(gaussians)
        return bool(gaussians.any() if gaussians.dtype == bool else gaussians.size)


def _candidates(scene, truth, rng):
    """Per view, its distractor Gaussians split in two, plus a few static ones: candidates of
    both ranges, some touching each other."""
    out = []
    for i in range(scene.num_views):
        mine = np.flatnonzero(truth & (scene.view_id == i))
        halves = np.array_split(mine, 2) if mine.size else []
        static = np.flatnonzero(~truth & (scene.view_id == i))
        extra = rng.choice(static, 40, replace=False)
        for k, g in enumerate(list(halves) + [extra]):
            if g.size:
                out.append(SimpleNamespace(view=i, gaussians=np.sort(g), range=1 + k % 2))
    return out


@pytest.mark.parametrize("seed,incremental", [(0, True), (1, True), (2, False)])
def test_static_base_terms_match_full_renders(street, seed, incremental):
    # Each candidate's terms on view j: removing it from R_j^-j without the other views'
    # candidates (its own view's stay), scored over the whole image from two full renders.
    scene, truth = street
    rng = np.random.default_rng(seed)
    views = _Views(prepare(scene, cam) for cam in scene.cameras)
    own = [scene.view_id == i for i in range(scene.num_views)]
    excl = [v.render(keep=~o) for v, o in zip(views, own)]
    index = SimpleNamespace(members=[np.flatnonzero(scene.view_id == i)
                                     for i in range(scene.num_views)])
    state = SimpleNamespace(views=views, own=own, index=index)    # what it reads
    renders = SimpleNamespace(excl=excl)
    candidates = _candidates(scene, truth, rng)
    proposed = np.zeros(len(scene), bool)
    for c in candidates:
        proposed[c.gaussians] = True
    q = {r: [rng.random(e.alpha.shape) < 0.1 for e in excl] for r in (1, 2)}
    verifier = Verifier(views, scene.images, epsilon=0.002, incremental=incremental)
    differs = 0
    for j in range(scene.num_views):
        todo = [c for c in candidates if c.view != j]
        got = _static_base_terms(state, j, todo, proposed, q, verifier, renders)
        assert sorted(id(c) for c, _ in got) == sorted(id(c) for c in todo)
        for c, p in got:
            # R_j^-j without the candidates of every view but c's, then without c too.
            base_keep = ~own[j] & ~(proposed & (scene.view_id != c.view))
            cut = base_keep.copy()
            cut[c.gaussians] = False
            before, after = views[j].render(keep=base_keep), views[j].render(keep=cut)
            want = change_weighted_terms(before.rgb.reshape(-1, 3), after.rgb.reshape(-1, 3),
                                         scene.images[j].reshape(-1, 3), q[c.range][j].ravel(),
                                         0.002)
            np.testing.assert_allclose([p.num, p.den, p.err], [want.num, want.den, want.err],
                                       rtol=1e-9, atol=1e-12)
            # The same removal from R_j^-j as it is (the "exclude-own" base).
            keep = ~own[j]
            cut = keep.copy()
            cut[c.gaussians] = False
            plain = change_weighted_terms(excl[j].rgb.reshape(-1, 3),
                                          views[j].render(keep=cut).rgb.reshape(-1, 3),
                                          scene.images[j].reshape(-1, 3),
                                          q[c.range][j].ravel(), 0.002)
            differs += not np.isclose(plain.num, p.num)
    assert differs > 0      # the bases differ: the test tells them apart


@pytest.mark.parametrize("backend", ["native", "torch"])
def test_filter_with_the_static_base(street, backend):
    if backend == "torch":
        pytest.importorskip("torch")
    scene, truth = street
    config = FilterConfig(verify_base="static", backend=backend)
    result = filter_distractors(scene, config=config)
    stats = removal_stats(result.removed, truth)
    own = removal_stats(filter_distractors(
        scene, config=FilterConfig(verify_base="exclude-own", backend=backend)).removed, truth)
    assert stats["recall"] >= own["recall"] - 0.05 and stats["recall"] > 0.5
    assert stats["static_removed"] < 0.01
    for c in result.candidates:
        if c.gaussians.size:
            assert "individual" in c.scores
