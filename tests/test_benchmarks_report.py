"""benchmarks/report.py: the generator of docs/benchmarks.md, on stored rows and a tiny grid."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import subprocess
import sys

import pytest

from clearsplat import FilterConfig
from clearsplat.bench import ABLATIONS, parse_config

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(ROOT, "benchmarks", "report.py")


@pytest.fixture(scope="module")
def report():
    spec = importlib.util.spec_from_file_location("report", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["report"] = mod          # its dataclasses look their module up there
    try:
        spec.loader.exec_module(mod)
        yield mod
    finally:
        sys.modules.pop("report", None)


def _quality(psnr):
    return {"psnr": psnr, "ssim": 0.9, "lpips": None}


def _row(scenario, config, family, views, k):
    return {"realism": scenario, "config": config, "family": family, "views": views,
            "seed": 0, "baseline": _quality(20.0), "filtered": _quality(24.0 + 0.01 * k),
            "exact": _quality(25.0), "reference": _quality(26.0),
            "clean_baseline": _quality(26.0), "clean_filtered": _quality(26.0 - 0.001 * k),
            "recall": 0.9, "other_removed": 0.003 + 1e-4 * k, "clean_removed": 0.001}


def _real(config):
    return {"config": config, "iou": 0.9, "recall": 0.95, "precision": 0.9,
            "psnr_before": 18.6, "psnr_after": 21.3, "psnr_clean": 21.0, "other_removed": 0.007}


def _store(work, name, data, report):
    """A step's outputs as ``run_step`` leaves them, so that ``--reuse`` takes them."""
    step = next(s for s in getattr(report.grids(work, False), name))
    path = os.path.join(report.ROOT, step.result)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        json.dump(data, f)
    with open(os.path.join(work, name + ".out"), "w") as f:
        f.write("48 runs in 1234 s; wrote results.json\n")
    with open(os.path.join(work, name + ".json"), "w") as f:
        json.dump({"argv": step.argv, "rc": 0, "seconds": 1240.0,
                   "finished": "2026-01-01 12:00"}, f)


def test_every_departure_of_the_default_has_an_ablation_row():
    default, paper = FilterConfig(), FilterConfig.preset("paper-local")
    differ = {f.name for f in dataclasses.fields(FilterConfig)
              if getattr(default, f.name) != getattr(paper, f.name)}
    assert differ          # the default departs from the paper somewhere
    alone = {}
    for label, spec in ABLATIONS.items():
        cfg = parse_config(spec)      # every entry names options that exist today
        changed = {f.name for f in dataclasses.fields(FilterConfig)
                   if getattr(cfg, f.name) != getattr(default, f.name)}
        if spec.startswith("default+") and len(changed) <= 2:
            for name in changed:
                if getattr(cfg, name) == getattr(paper, name):
                    alone.setdefault(name, label)
    assert differ <= set(alone), f"no ablation row for {sorted(differ - set(alone))}"


def test_full_grid_page_from_stored_rows_stays_short_and_merges(tmp_path, report):
    work = str(tmp_path / "work")
    os.makedirs(work)
    scen = report.SCENARIOS.split(",")
    rows = [_row(s, c, f, v, k) for k, (s, c, f, v) in enumerate(
        (s, c, f, v) for s in scen for f in ("object", "street") for v in (4, 8, 16)
        for c in ("default", "paper-local"))]
    _store(work, "quality", {"rows": rows, "real_image_check": [_real("default"),
                                                                _real("paper-local")]}, report)
    ab = [_row(s, c, f, v, k) for k, (s, c, f, v) in enumerate(
        (s, c, f, v) for s in ("plain", "all") for f in ("object", "street") for v in (4, 8)
        for c in ABLATIONS)]
    _store(work, "ablation", {"rows": ab, "real_image_check": [_real(c) for c in ABLATIONS]},
           report)
    page = tmp_path / "benchmarks.md"
    page.write_text("# Old page\n\nhistory that goes\n")
    assert report.main(["--out", str(page), "--work", work, "--reuse",
                        "--only", "quality,ablation"]) == 0
    text = page.read_text()
    assert text.count("\n") <= report.MAX_LINES
    assert "history that goes" not in text
    for name in report.SECTIONS:
        assert text.count(f"<!-- report:{name} -->") == 1
        assert text.count(f"<!-- /report:{name} -->") == 1
    # Every scenario, view count and config has its row; every ablation config its row.
    for s in scen:
        for v in (4, 8, 16):
            assert f"| `{s}` | {v} | `default` |" in text
    for label, spec in ABLATIONS.items():
        assert f"| `{label}` | `{spec}` |" in text
    assert "met      mean recall" in text
    assert "clearsplat bench --realism plain,soft,depth,multi,exposure,pose,coarse,all" in text
    assert "Machine: " in text and "2026-01-01 12:00" in text
    blocks = report.parse_blocks(text)
    assert "Not generated yet" in blocks["speed"] and "--only speed" in blocks["speed"]

    # A speed block merged in later keeps the other blocks as they are.
    quality = report.parse_blocks(text)["quality"]
    steps = [report.Step("speed-cli", ["python", "benchmarks/cli_speed.py"],
                         stdout="clearsplat filter, whole process\n  wall s: median 3.00\n",
                         seconds=30.0, finished="2026-01-02 08:00")]
    block = report.section_speed(steps, report.machine(), work, "0.12")
    strengths = report.Step("scenarios", ["python", "benchmarks/realism_strengths.py"],
                            stdout="scenario  family  views\n" + "plain object 4 34.59\n" * 32,
                            seconds=100.0, finished="2026-01-02 07:00")
    scen = report.section_scenarios([strengths], report.machine(), work)
    # Text written by hand after a block stays after it, also when the block is replaced.
    note = "### By hand\n\nA measurement the report does not run.\n"
    text = text.replace("<!-- /report:speed -->\n", "<!-- /report:speed -->\n\n" + note, 1)
    merged = report.assemble({"speed": block, "scenarios": scen}, text)
    after = report.parse_blocks(merged)
    assert merged.count(note) == 1
    assert merged.index("<!-- /report:speed -->") < merged.index(note) < merged.index(
        "<!-- report:dense -->")
    assert report.assemble({}, merged) == merged        # idempotent: nothing added twice
    assert after["quality"] == quality and after["ablation"] == blocks["ablation"]
    assert "wall s: median 3.00" in after["speed"] and "Not generated yet" not in merged
    assert "images/realism-all.png" in after["scenarios"]
    assert merged.count("\n") <= report.MAX_LINES


def test_speed_waits_for_a_quiet_machine(report):
    def run(loads):
        t = [0.0]
        it = iter(loads)

        def sleep(s):
            t[0] += s
        return report.wait_quiet(120, 0.5, lambda s: None, load=lambda: next(it),
                                 clock=lambda: t[0], sleep=sleep)
    quiet, text = run([2.0, 0.3] + [0.3] * 20)
    assert quiet and "below 0.5" in text
    quiet, text = run([0.3, 0.3, 0.9] + [2.0] * 20)       # a spike restarts the minute
    assert not quiet and "lowest 0.30" in text


def test_a_step_replaces_its_own_output_only(tmp_path, report):
    work = tmp_path / "work"
    (work / "quality").mkdir(parents=True)
    (work / "quality" / "results.json").write_text("{}")
    (work / "quality.out").write_text("kept")
    rows = work / "speed-object.rows"
    rows.write_text("stale")
    script = f"open({str(rows)!r}, 'w').write('new')"
    step = report.Step("speed-object", ["python", "-c", script], result=str(rows))
    report.run_step(step, str(work), reuse=False, log=lambda s: None)
    assert rows.read_text() == "new"
    assert (work / "quality" / "results.json").exists() and (work / "quality.out").exists()
    # --reuse takes the stored output of the same command and runs nothing.
    rows.write_text("stored")
    again = report.run_step(report.Step("speed-object", ["python", "-c", script],
                                        result=str(rows)), str(work), reuse=True,
                            log=lambda s: None)
    assert again.reused and rows.read_text() == "stored"


def test_only_rejects_an_unknown_section(tmp_path, report):
    with pytest.raises(SystemExit):
        report.main(["--out", str(tmp_path / "p.md"), "--only", "qualty"])


def test_quick_run_writes_a_page(tmp_path):
    page = tmp_path / "page.md"
    res = subprocess.run([sys.executable, SCRIPT, "--out", str(page), "--work",
                          str(tmp_path / "work"), "--quick", "--only", "quality,ablation"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    text = page.read_text()
    assert "| `plain` | 4 | `default` |" in text and "| `plain` | 4 | `paper-local` |" in text
    assert "| `one-round` | `default+rounds=1` |" in text
    assert "48x80, 4 views, object, scenario `plain`, seed 0" in text
    assert text.count("\n") <= 600


def test_filter_versus_runs_both_interpreters_pair_by_pair(capsys):
    # This checkout against itself on a tiny capture: one row per case, a ratio per pair and
    # the same removals on both sides.
    from scripts import load_script

    versus = load_script("benchmarks/filter_versus.py")
    assert versus.main(["--other", sys.executable, "--views", "3", "--family", "object",
                        "--resolution", "48x64", "--pairs", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("filter time, A: ") and "against B: " in lines[0]
    row = lines[-1].split()
    assert row[:2] == ["object", "3"] and row[-1] == "True"
    assert len(row) == 2 + 2 + 2 + 1 + 1 and 0.1 < float(row[-2]) < 10
