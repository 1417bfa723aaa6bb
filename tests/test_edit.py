"""Reviewing the filter's decisions: candidate data in filter outputs and ``clearsplat edit``."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import clearsplat
from clearsplat.cli import main
from clearsplat.errors import ClearsplatError
from clearsplat.review import (
    CANDIDATES_FILE,
    REMOVED_FILE,
    CandidateSets,
    edit_command,
    edit_removed,
    load_filter_output,
    load_full_scene,
    read_candidates,
    write_candidates,
)


def run(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_error(err: str, *words) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("clearsplat: error: "), err
    for w in words:
        assert w in lines[0], (w, lines[0])


def tree(folder: Path) -> dict:
    """Every file under ``folder`` with its hash (to show that nothing changed)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from clearsplat.synth import make_world, reconstruct
    world = make_world("object", num_views=3, height=32, width=56)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    root = tmp_path_factory.mktemp("edit")
    scene.save(root / "scene")
    return root / "scene"


def _mask(shape, r0, c0, r1, c1):
    m = np.zeros(shape, bool)
    m[r0:r1, c0:c1] = True
    m[r0, c0] = False                   # not a plain box: the bits matter
    return m


@pytest.fixture(scope="module")
def crafted(scene_dir, tmp_path_factory):
    """A filter output with known candidates, written as ``clearsplat filter`` writes one.

    0 and 1 accepted, their expansions overlapping; 2 rejected by the individual test (no
    expansion) and overlapping 1; 3 passed the individual test but lost the joint test; 4 an
    empty region. Returns (folder, candidates, N).
    """
    from clearsplat.batch import write_filter_outputs
    from clearsplat.filter import Candidate, FilterConfig, FilterResult
    from clearsplat.io.output import output_folder

    scene = clearsplat.load_scene(scene_dir)
    n = len(scene)
    rng = np.random.default_rng(7)
    pool = rng.permutation(n)
    e0, e1, e3 = np.sort(pool[:300]), np.sort(pool[250:500]), np.sort(pool[600:700])
    g2 = np.sort(np.concatenate([pool[450:480], pool[800:840]]))
    shape = (32, 56)
    cands = [
        Candidate(0, 0, 1, _mask(shape, 2, 3, 9, 12), e0[::2].copy(), e0,
                  scores={"individual": 0.2}, accepted=True, reason="accepted (first range)"),
        Candidate(1, 1, 2, _mask(shape, 10, 20, 30, 55), e1[::3].copy(), e1,
                  scores={"individual": 0.3, "additional": 0.1, "joint": 0.05},
                  accepted=True, reason="accepted (second range, joint test)", round=2),
        Candidate(2, 2, 1, _mask(shape, 0, 0, 4, 5), g2, None,
                  scores={"individual": -0.01}, reason="rejected by individual test"),
        Candidate(3, 1, 2, _mask(shape, 20, 1, 31, 9), e3[::2].copy(), e3,
                  scores={"individual": 0.1, "additional": 0.02, "joint": -0.2},
                  reason="rejected by joint test"),
        Candidate(4, 0, 1, np.zeros(shape, bool), np.zeros(0, np.int64), None,
                  scores={"individual": 0.0}, reason="no Gaussians left"),
    ]
    keep = np.ones(n, bool)
    keep[e0] = keep[e1] = False
    result = FilterResult(keep, cands, [], {"total": 0.0}, FilterConfig())
    out = tmp_path_factory.mktemp("crafted") / "filtered"
    with output_folder(out, inputs=[scene_dir], command="filter") as tmp:
        write_filter_outputs(tmp, scene, result, source=str(scene_dir), located_at=out)
    return out, cands, n


def as_mask(n, *index_sets):
    m = np.zeros(n, bool)
    for s in index_sets:
        m[s] = True
    return m


def check_ply(folder: Path, scene_dir: Path, removed: np.ndarray) -> None:
    """gaussians.ply holds exactly the input's Gaussians that ``removed`` keeps, unchanged."""
    scene = clearsplat.load_scene(scene_dir)
    got = clearsplat.load_scene(folder)
    assert len(got) == int((~removed).sum())
    for name in ("means", "scales", "quats", "opacities", "sh"):
        assert np.array_equal(getattr(got.gaussians, name),
                              getattr(scene.gaussians, name)[~removed]), name
    assert np.array_equal(got.view_id, scene.view_id[~removed])
    assert np.array_equal(got.pixel_id, scene.pixel_id[~removed])


# ------------------------------------------------------------------------------------------------
# the candidate data of a filter output
# ------------------------------------------------------------------------------------------------
def test_candidate_data_round_trips(crafted, scene_dir, tmp_path):
    out, cands, n = crafted
    sets = read_candidates(out / CANDIDATES_FILE, num_gaussians=n, count=len(cands))
    assert len(sets) == 5
    for k, c in enumerate(cands):
        assert np.array_equal(sets.own(k), c.gaussians)
        if c.expanded is None:
            assert sets.expansion(k) is None
            assert np.array_equal(sets.removal(k), c.gaussians)       # the fallback
        else:
            assert np.array_equal(sets.expansion(k), c.expanded)
            assert np.array_equal(sets.removal(k), c.expanded)
        assert np.array_equal(sets.pixels(k, c.pixels.shape), c.pixels)
    assert sets.gaussians.dtype == np.int32                         # compact
    # the same candidates give the same bytes
    write_candidates(tmp_path / "a.npz", cands, num_gaussians=n)
    write_candidates(tmp_path / "b.npz", CandidateSets.from_candidates(cands, num_gaussians=n),
                     num_gaussians=n)
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes() \
        == (out / CANDIDATES_FILE).read_bytes()
    # removed.ply and gaussians.ply together are the input, bit for bit
    full = load_full_scene(load_filter_output(out))
    scene = clearsplat.load_scene(scene_dir)
    for name in ("means", "scales", "quats", "opacities", "sh"):
        assert np.array_equal(getattr(full.gaussians, name), getattr(scene.gaussians, name))
    assert np.array_equal(full.view_id, scene.view_id)
    removed = np.load(out / "removed.npy")
    assert len(clearsplat.read_ply(out / REMOVED_FILE)[0]) == int(removed.sum())


def test_a_real_filter_output_holds_its_candidates(scene_dir, tmp_path, capsys):
    code, _, err = run(["filter", scene_dir, "--out", tmp_path / "f"], capsys)
    assert code == 0, err
    summary = json.loads((tmp_path / "f" / "summary.json").read_text())
    output = load_filter_output(tmp_path / "f")
    sets = output.sets
    assert len(sets) == len(summary["candidates"]) > 0
    union = np.zeros(len(output.removed), bool)
    for k, c in enumerate(summary["candidates"]):
        assert sets.own(k).size == c["gaussians"]
        e = sets.expansion(k)
        assert (None if e is None else e.size) == c["expanded_gaussians"]
        assert int(sets.pixels(k, (32, 56)).sum()) == c["pixels"]
        if c["accepted"]:
            union[sets.removal(k)] = True
    assert np.array_equal(union, output.removed)     # the filter's removal is their union
    # rejecting every accepted candidate gives the input back
    accepted = [c["index"] for c in summary["candidates"] if c["accepted"]]
    code, stdout, err = run(["edit", tmp_path / "f", "--reject",
                             ",".join(map(str, accepted)), "--out", tmp_path / "e"], capsys)
    assert code == 0, err
    assert f"restored {int(output.removed.sum()):,} and removed 0" in stdout
    assert not np.load(tmp_path / "e" / "removed.npy").any()
    check_ply(tmp_path / "e", scene_dir, np.zeros(len(union), bool))


# ------------------------------------------------------------------------------------------------
# the rule
# ------------------------------------------------------------------------------------------------
def test_edit_removed_is_the_union_of_the_accepted():
    """From the union of the accepted sets, any edit gives the union of the new accepted sets
    (random sets, many overlaps, fallbacks included)."""
    from types import SimpleNamespace
    rng = np.random.default_rng(3)
    n, k = 200, 12
    for trial in range(30):
        cands = []
        for i in range(k):
            own = np.unique(rng.integers(0, n, rng.integers(0, 20)))
            expanded = (np.unique(np.concatenate([own, rng.integers(0, n, 15)]))
                        if rng.random() < 0.7 else None)
            cands.append(SimpleNamespace(view=i % 3, pixels=np.zeros((4, 4), bool),
                                         gaussians=own, expanded=expanded))
        sets = CandidateSets.from_candidates(cands, num_gaussians=n)
        accepted = rng.random(k) < 0.5
        removed = sets.covered(accepted) > 0
        ids = rng.permutation(k)
        reject, accept = ids[:rng.integers(0, 5)], ids[5:5 + rng.integers(0, 5)]
        new, verdicts = edit_removed(removed, sets, accepted, reject=reject, accept=accept)
        expect = accepted.copy()
        expect[reject], expect[accept] = False, True
        assert np.array_equal(verdicts, expect)
        union = np.zeros(n, bool)
        for i in np.flatnonzero(expect):
            union[cands[i].gaussians if cands[i].expanded is None else cands[i].expanded] = True
        assert np.array_equal(new, union), trial
    with pytest.raises(ClearsplatError) as e:
        edit_removed(removed, sets, accepted, reject=[1], accept=[1])
    assert e.value.field == "accept"
    with pytest.raises(ClearsplatError) as e:
        edit_removed(removed, sets, accepted, reject=[k])
    assert e.value.field == "reject"


# ------------------------------------------------------------------------------------------------
# clearsplat edit
# ------------------------------------------------------------------------------------------------
def test_reject_restores_what_no_other_accepted_candidate_removes(crafted, scene_dir, tmp_path,
                                                                   capsys):
    out, cands, n = crafted
    before = tree(out)
    e0, e1 = cands[0].expanded, cands[1].expanded
    code, stdout, err = run(["edit", out, "--reject", "1", "--out", tmp_path / "e"], capsys)
    assert code == 0, err
    removed = np.load(tmp_path / "e" / "removed.npy")
    assert np.array_equal(removed, as_mask(n, e0))
    restored = np.setdiff1d(e1, e0)                     # the overlap stays removed
    assert 0 < restored.size < e1.size
    assert f"restored {restored.size:,} and removed 0 " in stdout
    check_ply(tmp_path / "e", scene_dir, removed)
    summary = json.loads((tmp_path / "e" / "summary.json").read_text())
    assert summary["removed"] == int(removed.sum()) and summary["accepted"] == 1
    c = summary["candidates"][1]
    assert c["accepted"] is False and c["reason"] == "rejected in review"
    assert c["filter_reason"] == "accepted (second range, joint test)"
    assert summary["edits"] == [{"reject": [1], "accept": [], "restored": int(restored.size),
                                 "removed": 0, "gaussians_removed": int(removed.sum()),
                                 "source": f"../{out.parent.name}/filtered"}]
    assert tree(out) == before                          # the input is only read


def test_accept_removes_its_expanded_gaussians(crafted, scene_dir, tmp_path, capsys):
    out, cands, n = crafted
    old = np.load(out / "removed.npy")
    code, stdout, err = run(["edit", out, "--accept", "3", "--out", tmp_path / "a"], capsys)
    assert code == 0, err
    removed = np.load(tmp_path / "a" / "removed.npy")
    assert np.array_equal(removed, old | as_mask(n, cands[3].expanded))
    added = int((removed & ~old).sum())
    assert added == np.setdiff1d(cands[3].expanded, np.flatnonzero(old)).size > 0
    assert f"removed {added:,} Gaussians" in stdout
    check_ply(tmp_path / "a", scene_dir, removed)
    # a candidate the individual test rejected has no expansion: its own Gaussians go
    code, _, err = run(["edit", out, "--accept", "2", "--out", tmp_path / "b"], capsys)
    assert code == 0, err
    assert np.array_equal(np.load(tmp_path / "b" / "removed.npy"),
                          old | as_mask(n, cands[2].gaussians))
    # an empty candidate removes nothing
    code, stdout, err = run(["edit", out, "--accept", "4", "--out", tmp_path / "c"], capsys)
    assert code == 0 and "restored 0 and removed 0" in stdout
    assert np.array_equal(np.load(tmp_path / "c" / "removed.npy"), old)


def test_edits_compose_and_keep_the_full_record(crafted, scene_dir, tmp_path, capsys):
    out, cands, n = crafted
    e3, g2 = cands[3].expanded, cands[2].gaussians
    assert run(["edit", out, "--reject", "0", "--accept", "2", "--out", tmp_path / "one"],
               capsys)[0] == 0
    assert run(["edit", tmp_path / "one", "--accept", "3", "--reject", "1",
                "--out", tmp_path / "two"], capsys)[0] == 0
    assert run(["edit", out, "--reject", "0,1", "--accept", "2,3", "--out",
                tmp_path / "together"], capsys)[0] == 0
    removed = np.load(tmp_path / "two" / "removed.npy")
    assert np.array_equal(removed, as_mask(n, g2, e3))
    assert np.array_equal(removed, np.load(tmp_path / "together" / "removed.npy"))
    check_ply(tmp_path / "two", scene_dir, removed)
    s = json.loads((tmp_path / "two" / "summary.json").read_text())
    assert [(e["reject"], e["accept"]) for e in s["edits"]] == [([0], [2]), ([1], [3])]
    mid = int(np.load(tmp_path / "one" / "removed.npy").sum())
    assert s["edits"][0]["gaussians_removed"] == mid
    assert s["edits"][1]["gaussians_removed"] == int(removed.sum())
    assert s["edits"][0]["restored"] - s["edits"][0]["removed"] + s["edits"][1]["restored"] \
        - s["edits"][1]["removed"] == int(np.load(out / "removed.npy").sum()) - int(removed.sum())
    assert s["edits"][1]["source"] == "one"
    assert [c["accepted"] for c in s["candidates"]] == [False, False, True, True, False]
    assert s["candidates"][0]["filter_reason"] == "accepted (first range)"
    assert s["candidates"][2]["filter_reason"] == "rejected by individual test"
    assert (s["removed"], s["accepted"]) == (int(removed.sum()), 2)
    marker = json.loads((tmp_path / "two" / ".clearsplat.json").read_text())
    assert marker["command"] == "edit"
    # and back: the filter's own files again, byte for byte
    assert run(["edit", tmp_path / "two", "--reject", "2,3", "--accept", "0,1",
                "--out", tmp_path / "back"], capsys)[0] == 0
    for name in ("removed.npy", "gaussians.ply", REMOVED_FILE, CANDIDATES_FILE):
        assert (tmp_path / "back" / name).read_bytes() == (out / name).read_bytes(), name
    assert len(json.loads((tmp_path / "back" / "summary.json").read_text())["edits"]) == 3


def test_edit_output_is_a_bundle_and_keeps_all_on_request(crafted, scene_dir, tmp_path,
                                                         capsys):
    out, _, n = crafted
    code, _, err = run(["edit", out, "--reject", "1", "--out", tmp_path / "deep" / "k",
                        "--keep-all"], capsys)
    assert code == 0, err
    removed = np.load(tmp_path / "deep" / "k" / "removed.npy")
    scene = clearsplat.load_scene(scene_dir)
    got = clearsplat.load_scene(tmp_path / "deep" / "k")            # images found again
    assert len(got) == n and got.images is not None
    assert (got.gaussians.opacities[removed] < 1e-6).all()
    assert np.array_equal(got.gaussians.opacities[~removed], scene.gaussians.opacities[~removed])
    # a keep-all folder edited again gives the original opacities back
    code, _, err = run(["edit", tmp_path / "deep" / "k", "--accept", "1",
                        "--out", tmp_path / "again"], capsys)
    assert code == 0, err
    assert np.array_equal(np.load(tmp_path / "again" / "removed.npy"),
                          np.load(out / "removed.npy"))
    assert (tmp_path / "again" / "gaussians.ply").read_bytes() == \
        (out / "gaussians.ply").read_bytes()
    # other commands read it: view's --filtered, render, export
    code, _, err = run(["export", tmp_path / "again", "--to", tmp_path / "x.splat"], capsys)
    assert code == 0, err
    assert edit_command(out, tmp_path / "e", reject=[3, 1], accept=[2]) == \
        f"clearsplat edit {out} --reject 1,3 --accept 2 --out {tmp_path / 'e'}"


def test_edit_replaces_only_its_own_output(crafted, tmp_path, capsys):
    out, _, _ = crafted
    assert run(["edit", out, "--reject", "0", "--out", tmp_path / "e"], capsys)[0] == 0
    code, _, err = run(["edit", out, "--reject", "1", "--out", tmp_path / "e"], capsys)
    assert code == 2
    one_error(err, "--out", "--force")
    code, _, err = run(["edit", out, "--reject", "1", "--out", tmp_path / "e", "--force"],
                       capsys)
    assert code == 0, err
    assert json.loads((tmp_path / "e" / "summary.json").read_text())["edits"][0]["reject"] \
        == [1]
    code, _, err = run(["edit", out, "--reject", "1", "--out", out, "--force"], capsys)
    assert code == 2
    one_error(err, "--out", "input")


# ------------------------------------------------------------------------------------------------
# bad input: one line, exit code 2, nothing written
# ------------------------------------------------------------------------------------------------
def _refused(argv, capsys, tmp_path, *words):
    before = sorted(p.name for p in tmp_path.iterdir())
    code, stdout, err = run(argv, capsys)
    assert code == 2, (stdout, err)
    one_error(err, *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == before    # nothing written


def test_unknown_or_bad_ids(crafted, tmp_path, capsys):
    out, _, _ = crafted
    before = tree(out)
    new = tmp_path / "e"
    _refused(["edit", out, "--reject", "5", "--out", new], capsys, tmp_path,
             "summary.json", "--reject", "no candidate 5", "5 candidates (0 to 4)")
    _refused(["edit", out, "--accept", "1,99", "--out", new], capsys, tmp_path,
             "summary.json", "--accept", "no candidate 99")
    _refused(["edit", out, "--reject", "1", "--accept", "1", "--out", new], capsys, tmp_path,
             "--accept", "candidate 1")
    _refused(["edit", out, "--reject", "one", "--out", new], capsys, tmp_path,
             "--reject", "'one'")
    _refused(["edit", out, "--reject", "-1", "--out", new], capsys, tmp_path, "--reject")
    _refused(["edit", out, "--out", new], capsys, tmp_path, "nothing to edit")
    assert tree(out) == before


def test_not_a_filter_output(scene_dir, tmp_path, capsys):
    new = tmp_path / "e"
    _refused(["edit", scene_dir, "--reject", "0", "--out", new], capsys, tmp_path,
             "summary.json", "not found", "'clearsplat filter'")
    _refused(["edit", tmp_path / "nowhere", "--reject", "0", "--out", new], capsys, tmp_path,
             "nowhere", "not a folder")
    # a clearsplat output of another command
    assert run(["render", scene_dir, "--path", scene_dir / "cameras.json",
                "--out", tmp_path / "renders"], capsys)[0] == 0
    _refused(["edit", tmp_path / "renders", "--reject", "0", "--out", new], capsys, tmp_path,
             ".clearsplat.json", "command", "'clearsplat render'")


def test_output_without_candidate_data(crafted, tmp_path, capsys):
    out, _, _ = crafted
    old = tmp_path / "old"
    shutil.copytree(out, old)
    (old / CANDIDATES_FILE).unlink()            # as clearsplat wrote it before
    _refused(["edit", old, "--reject", "0", "--out", tmp_path / "e"], capsys, tmp_path,
             "candidates.npz", "candidates", "not found")
    shutil.copyfile(out / CANDIDATES_FILE, old / CANDIDATES_FILE)
    (old / REMOVED_FILE).unlink()
    _refused(["edit", old, "--reject", "0", "--out", tmp_path / "e"], capsys, tmp_path,
             "removed.ply", "not found")
    (old / CANDIDATES_FILE).write_bytes(b"not a zip")
    _refused(["edit", old, "--reject", "0", "--out", tmp_path / "e"], capsys, tmp_path,
             "candidates.npz", "candidates", "cannot read")
    # candidate data of another run
    shutil.copyfile(out / REMOVED_FILE, old / REMOVED_FILE)
    sets = read_candidates(out / CANDIDATES_FILE)
    fields = {f: getattr(sets, f) for f in CandidateSets.__dataclass_fields__}
    write_candidates(old / CANDIDATES_FILE, CandidateSets(**{**fields, "view": np.roll(sets.view, 1)}),
                     num_gaussians=sets.num_gaussians)
    _refused(["edit", old, "--reject", "0", "--out", tmp_path / "e"], capsys, tmp_path,
             "candidates.npz", "view", "different runs")
