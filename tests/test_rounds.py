"""Later rounds: which regions they take on (``later_rounds``) and where R_i^-i changed."""

import numpy as np
import pytest

from clearsplat.features import get_extractor
from clearsplat.features.base import upsample_nearest
from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.filter.proposal import Region, ViewProposal
from clearsplat.filter.rounds import keep_changed_regions
from clearsplat.render import prepare
from clearsplat.synth import make_world, reconstruct


def _proposal(cells_list, grid, height, width):
    p = ViewProposal(view=0, similarity=np.zeros(grid, np.float32),
                     support=np.ones(grid, bool), ranges=np.zeros(grid, np.int8))
    for cells in cells_list:
        p.regions.append(Region(0, 1, cells, upsample_nearest(cells, height, width)))
    return p


def _cells(grid, *where):
    c = np.zeros(grid, bool)
    for r, k in where:
        c[r, k] = True
    return c


def test_keep_changed_regions_against_a_loop():
    rng = np.random.default_rng(0)
    grid, (h, w) = (6, 9), (96, 144)
    for _ in range(20):
        regions = [rng.random(grid) < 0.08 for _ in range(6)]
        regions = [c for c in regions if c.any()]
        changed = np.zeros((h, w), bool)
        for _ in range(rng.integers(0, 4)):
            changed[rng.integers(0, h), rng.integers(0, w)] = True
        p = _proposal(regions, grid, h, w)
        dropped = keep_changed_regions([p], [changed])
        # Slow reference: a region stays when a cell within one step (8 neighbours) of one
        # of its cells holds a changed pixel (cell (r, c) covers rows 16r..16r+15 here).
        expect = []
        for cells in regions:
            near = False
            for r, c in zip(*np.nonzero(cells)):
                for dr in (-1, 0, 1):
                    for dc in (-1, 0, 1):
                        rr, cc = r + dr, c + dc
                        if 0 <= rr < grid[0] and 0 <= cc < grid[1]:
                            near |= changed[16 * rr:16 * rr + 16, 16 * cc:16 * cc + 16].any()
            expect.append(near)
        assert [any(q.cells is c for q in p.regions) for c in regions] == expect
        assert dropped == len(regions) - sum(expect)


def test_keep_changed_regions_edge_cases():
    grid, (h, w) = (4, 4), (64, 64)
    regions = [_cells(grid, (0, 0)), _cells(grid, (3, 3))]
    p = _proposal(regions, grid, h, w)
    assert keep_changed_regions([p], [None]) == 0 and len(p.regions) == 2   # unknown: keep
    none = np.zeros((h, w), bool)
    assert keep_changed_regions([p], [none]) == 2 and p.regions == []       # nothing changed
    p = _proposal(regions, grid, h, w)
    one = none.copy()
    one[16, 16] = True          # cell (1, 1): next to (0, 0), two cells from (3, 3)
    keep_changed_regions([p], [one])
    assert [r.cells is regions[0] for r in p.regions] == [True]


@pytest.fixture(scope="module")
def street():
    w = make_world("street", num_views=8, seed=0, height=128, width=224)
    return reconstruct(w.cameras, w.images, w.depths, seed=0)


def test_changed_regions_are_a_subset_of_every_region(street):
    ex = get_extractor("local")
    exact = FilterConfig.preset("exact")
    assert exact == FilterConfig(neighbours=None, verify_views="centres")
    assert exact.later_rounds == "all"
    a = filter_distractors(street, config=exact, extractor=ex)
    b = filter_distractors(street, config=FilterConfig(later_rounds="changed"), extractor=ex)
    # The second round runs in both; "changed" takes on only what the first one changed.
    assert max(c.round for c in a.candidates) == 2 == max(c.round for c in b.candidates)
    second = lambda r: [c for c in r.candidates if c.round == 2]
    assert 0 < len(second(b)) < len(second(a))
    # Every candidate of the default's second round is one the exact second round has too.
    exact_regions = {(c.view, c.pixels.tobytes()) for c in second(a)}
    assert all((c.view, c.pixels.tobytes()) in exact_regions for c in second(b))


def test_second_round_regions_touch_what_the_first_round_changed(street):
    ex = get_extractor("local")
    first = filter_distractors(street, config=FilterConfig(rounds=1), extractor=ex)
    result = filter_distractors(street, config=FilterConfig(rounds=2, later_rounds="changed"),
                                extractor=ex)
    assert not (result.keep & ~first.keep).any()     # the first round's removals stay
    seen = 0
    for c in result.candidates:
        if c.round != 2:
            continue
        # Where R_i^-i changed: rendered directly, with and without the first round's removals.
        pv = prepare(street, street.cameras[c.view])
        own = street.view_id == c.view
        before, after = pv.render(keep=~own), pv.render(keep=~own & first.keep)
        changed = ((before.rgb != after.rgb).any(-1) | (before.alpha != after.alpha)
                   | (before.depth != after.depth))
        # Within one 16-pixel cell (and its neighbours) of the region.
        ys, xs = np.nonzero(c.pixels)
        y0, y1 = max(ys.min() // 16 - 1, 0) * 16, (ys.max() // 16 + 2) * 16
        x0, x1 = max(xs.min() // 16 - 1, 0) * 16, (xs.max() // 16 + 2) * 16
        assert changed[y0:y1, x0:x1].any()
        seen += 1
    assert seen > 0


def test_budget_and_backend_hand_on_give_the_same_later_round(street):
    ex = get_extractor("local")
    cfg = FilterConfig(later_rounds="changed")
    a = filter_distractors(street, config=cfg.replace(view_memory=None), extractor=ex)
    # Views prepared again (not handed on): the change is measured from the renders alone.
    b = filter_distractors(street, config=cfg.replace(prune_views=True), extractor=ex)
    assert np.array_equal(a.keep, b.keep)
    assert [c.record() for c in a.candidates] == [c.record() for c in b.candidates]
