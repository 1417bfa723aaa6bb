"""Regenerate ``docs/benchmarks.md``: today's default, measured on this machine, one command.

Usage::

    python benchmarks/report.py --out docs/benchmarks.md                 # every section
    python benchmarks/report.py --out docs/benchmarks.md --only speed    # one section, merged
    python benchmarks/report.py --out page.md --quick                    # a tiny grid (tests)

Sections measured (each runs the commands printed above its tables, as subprocesses):

- ``quality``: the realism benchmark, ``clearsplat bench`` at 256x448, 4/8/16 views, both
  families, every scenario, seed 0, configs ``default`` and ``paper-local``, with its
  real-image check; summarised per scenario and view count with the helpers of
  ``benchmarks/realism_acceptance.py``.
- ``ablation``: ``clearsplat bench --ablation`` (``clearsplat.bench.ABLATIONS``) at 128x224,
  4 and 8 views, both families, scenarios ``plain`` and ``all``; one row per config.
- ``speed``: ``benchmarks/filter_speed.py`` (object 4/8/16 views at 256x448; street
  8/16/32/64/100 views at 128x224 and 64 views at 256x448), ``benchmarks/cli_speed.py``, ``benchmarks/render_speed.py``. Run it on a
  quiet machine: ``--wait-quiet S`` polls the 1-minute load average until it is below
  ``--max-load`` (0.5) for a minute, up to S seconds (600 by default); otherwise the section
  keeps its block of the existing page and the exit status is 3.

The sections that measure nothing (dense captures, the GPU, real datasets) are fixed text,
written on every run. Each section's block on the page lies between ``<!-- report:NAME -->``
and ``<!-- /report:NAME -->``; a run with ``--only`` replaces those blocks and keeps the
others of the existing page as they are. Text written by hand between a block's end and the
next block stays where it is on every run. Raw outputs go to ``--work`` (default
``out/report``); ``--reuse`` takes a step's output from there instead of running it again when
the same command wrote it (the command is stored beside it).
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import textwrap
import time
from collections import defaultdict
from dataclasses import dataclass, field

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HERE = os.path.join(ROOT, "benchmarks")
SECTIONS = ("scenarios", "quality", "ablation", "speed", "dense", "gpu", "datasets")
MEASURED = ("scenarios", "quality", "ablation", "speed")
MAX_LINES = 660   # the generated sections and the measurements written by hand between them
SCENARIOS = "plain,soft,depth,multi,exposure,pose,coarse,all"


def _acceptance_module():
    """``benchmarks/realism_acceptance.py`` as a module (its summary helpers)."""
    spec = importlib.util.spec_from_file_location(
        "realism_acceptance", os.path.join(HERE, "realism_acceptance.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


RA = _acceptance_module()


# --------------------------------------------------------------------------------------------
# The machine


def machine() -> dict:
    """Cores, CPU model, memory, Python and date of this machine, read from the system."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    mem = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal"):
                    mem = int(line.split()[1]) / 2**20
                    break
    except OSError:
        pass
    return {"cores": os.cpu_count(), "cpu": model, "memory_gib": mem,
            "python": platform.python_version(), "system": platform.system(),
            "arch": platform.machine()}


def machine_line(m: dict, when: str) -> str:
    mem = f", {m['memory_gib']:.0f} GiB" if m.get("memory_gib") else ""
    return (f"Machine: {m['cores']} cores, {m['cpu']} ({m['arch']}){mem}, {m['system']}, "
            f"Python {m['python']}, no GPU used; measured {when}.")


# --------------------------------------------------------------------------------------------
# Steps: commands run as subprocesses, their outputs kept in the work folder


@dataclass
class Step:
    """One command of a section. ``argv[0]`` is ``clearsplat`` or ``python``."""

    name: str
    argv: list
    result: str | None = None          # a file the command writes (relative to the work dir)
    stdout: str = ""
    seconds: float | None = None
    finished: str = ""
    reused: bool = False
    extra: dict = field(default_factory=dict)

    def shown(self, width: int = 92) -> str:
        """The command as typed, continued with backslashes past ``width`` columns."""
        lines, cur = [], ""
        for a in (shlex.quote(a) for a in self.argv):
            if cur and len(cur) + 1 + len(a) > width:
                lines.append(cur + " \\")
                cur = "    " + a
            else:
                cur = f"{cur} {a}" if cur else a
        return "\n".join(lines + [cur])


def _read(path: str) -> str:
    with open(path) as f:
        return f.read()


def _json(path: str):
    with open(path) as f:
        return json.load(f)


def _exe(argv: list) -> list:
    if argv[0] == "clearsplat":
        return [sys.executable, "-m", "clearsplat"] + argv[1:]
    if argv[0] == "python":
        return [sys.executable] + argv[1:]
    return argv


def run_step(step: Step, work: str, *, reuse: bool, log) -> Step:
    """Run ``step`` (or take its stored output with ``reuse``); fills stdout, seconds."""
    base = os.path.join(work, step.name)
    meta_path = base + ".json"
    if reuse and os.path.exists(meta_path):
        meta = _json(meta_path)
        if meta.get("argv") == step.argv and meta.get("rc") == 0 and (
                step.result is None or os.path.exists(os.path.join(ROOT, step.result))):
            step.stdout = _read(base + ".out")
            step.seconds, step.finished, step.reused = meta["seconds"], meta["finished"], True
            log(f"{step.name}: reused ({step.shown(10**6)})")
            return step
    if step.result:     # a stale output: the bench's own folder in the work dir, or the file
        result = os.path.abspath(os.path.join(ROOT, step.result))
        out_dir = os.path.dirname(result)
        if os.path.dirname(out_dir) == os.path.abspath(work) and os.path.isdir(out_dir) \
                and os.path.basename(out_dir) == step.name:
            shutil.rmtree(out_dir)
        elif os.path.isfile(result):
            os.remove(result)
    log(f"{step.name}: {step.shown(10**6)}")
    t0 = time.perf_counter()
    res = subprocess.run(_exe(step.argv), cwd=ROOT, capture_output=True, text=True,
                         check=False)
    step.seconds = time.perf_counter() - t0
    step.finished = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
    step.stdout = res.stdout
    with open(base + ".out", "w") as f:
        f.write(res.stdout)
    with open(base + ".err", "w") as f:
        f.write(res.stderr)
    with open(meta_path, "w") as f:
        json.dump({"argv": step.argv, "rc": res.returncode, "seconds": step.seconds,
                   "finished": step.finished}, f)
    if res.returncode != 0:
        raise SystemExit(f"{step.shown(10**6)} failed (exit {res.returncode}):\n{res.stderr[-3000:]}")
    return step


# --------------------------------------------------------------------------------------------
# The grids


@dataclass
class Grid:
    """What each measured section runs; :func:`grids` gives the full and the quick one."""

    quality: list
    ablation: list
    speed: list
    scenarios: list
    quick: bool = False


def grids(work: str, quick: bool) -> Grid:
    work = os.path.abspath(work)
    w = os.path.relpath(work, ROOT) if work.startswith(ROOT + os.sep) else work
    if quick:
        q = [Step("quality", ["clearsplat", "bench", "--realism", "plain", "--views", "4",
                              "--families", "object", "--seeds", "0",
                              "--resolution", "48x80", "--configs", "default,paper-local",
                              "--no-real-check", "--out", f"{w}/quality"],
                  result=f"{w}/quality/results.json")]
        a = [Step("ablation", ["clearsplat", "bench", "--config", "default=default",
                               "--config", "one-round=default+rounds=1", "--realism", "plain",
                               "--views", "4", "--families", "object", "--seeds", "0",
                               "--resolution", "48x80", "--no-real-check",
                               "--out", f"{w}/ablation"],
                  result=f"{w}/ablation/results.json")]
        s = [Step("speed-object", ["python", "benchmarks/filter_speed.py", "--views", "2",
                                   "--resolution", "48x80", "--repeats", "1",
                                   "--full-repeats", "0", "--json", f"{w}/speed-object.rows"],
                  result=f"{w}/speed-object.rows"),
             Step("speed-cli", ["python", "benchmarks/cli_speed.py", "--views", "2",
                                "--resolution", "48x80", "--repeats", "1"])]
        sc = [Step("scenarios", ["python", "benchmarks/realism_strengths.py", "--views", "2",
                                 "--resolution", "48x80"])]
        return Grid(q, a, s, sc, quick=True)
    q = [Step("quality", ["clearsplat", "bench", "--realism", SCENARIOS, "--views", "4,8,16",
                          "--families", "object,street", "--seeds", "0",
                          "--resolution", "256x448", "--configs", "default,paper-local",
                          "--out", f"{w}/quality"],
              result=f"{w}/quality/results.json")]
    a = [Step("ablation", ["clearsplat", "bench", "--ablation", "--realism", "plain,all",
                           "--views", "4,8", "--families", "object,street", "--seeds", "0",
                           "--resolution", "128x224", "--out", f"{w}/ablation"],
              result=f"{w}/ablation/results.json")]
    s = [Step("speed-object", ["python", "benchmarks/filter_speed.py", "--views", "4,8,16",
                               "--resolution", "256x448", "--family", "object",
                               "--repeats", "3", "--full-repeats", "0",
                               "--json", f"{w}/speed-object.rows"],
              result=f"{w}/speed-object.rows"),
         Step("speed-street", ["python", "benchmarks/filter_speed.py",
                               "--views", "8,16,32,64,100",
                               "--resolution", "128x224", "--family", "street",
                               "--repeats", "3", "--full-repeats", "0",
                               "--json", f"{w}/speed-street.rows"],
              result=f"{w}/speed-street.rows"),
         Step("speed-dense", ["python", "benchmarks/filter_speed.py", "--views", "64",
                              "--resolution", "256x448", "--family", "street",
                              "--repeats", "1", "--full-repeats", "0",
                              "--json", f"{w}/speed-dense.rows"],
              result=f"{w}/speed-dense.rows"),
         Step("speed-cli", ["python", "benchmarks/cli_speed.py", "--repeats", "5"]),
         Step("speed-render", ["python", "benchmarks/render_speed.py", "--repeats", "5"])]
    sc = [Step("scenarios", ["python", "benchmarks/realism_strengths.py", "--views", "4,16",
                             "--resolution", "256x448"])]
    return Grid(q, a, s, sc)


def grid_words(step: Step) -> str:
    """The grid of a ``clearsplat bench`` step, in words, read from its own arguments."""
    a = step.argv

    def arg(flag, default=""):
        return a[a.index(flag) + 1] if flag in a else default
    scen = arg("--realism", "plain").split(",")
    scen_text = "every scenario" if len(scen) == 8 else "scenario" + \
        ("s " if len(scen) > 1 else " ") + ", ".join(f"`{s}`" for s in scen)
    fams = arg("--families", "object,street").replace(",", " and ")
    return (f"{arg('--resolution', '256x448')}, {arg('--views').replace(',', '/')} views, "
            f"{fams}, {scen_text}, seed {arg('--seeds', '0')}")


# --------------------------------------------------------------------------------------------
# Tables


def wrap(lines: list) -> str:
    """The lines of a section as text, prose wrapped at 96 columns (not tables, code or
    headings)."""
    out, fenced = [], False
    for line in lines:
        if line.startswith("```"):
            fenced = not fenced
        if fenced or line.startswith(("```", "|", "#", "- ")) or len(line) <= 96:
            out.append(line)
        else:
            out.append(textwrap.fill(line, 96, break_long_words=False, break_on_hyphens=False))
    return "\n".join(out)


def _pct(x):
    return f"{100 * x:.2f} %"


def quality_tables(data: dict) -> list[str]:
    """Per scenario, view count and config (means over the families; worst cell after the
    slash), then over every scenario; as ``realism_acceptance.py`` summarises them."""
    cells = defaultdict(list)
    for r in data["rows"]:
        cells[(r.get("realism") or "plain", r["config"], r["views"])].append(r)
    configs = list(dict.fromkeys(r["config"] for r in data["rows"]))
    order = list(dict.fromkeys(r.get("realism") or "plain" for r in data["rows"]))
    views = sorted({r["views"] for r in data["rows"]})
    out = ["| scenario | views | config | recall | PSNR gain (of exact) | other removed mean / max "
           "| clean PSNR change | clean removed mean / max |",
           "|---|---|---|---|---|---|---|---|"]
    for scen in order:
        for v in views:
            for cfg in configs:
                rs = cells.get((scen, cfg, v))
                if not rs:
                    continue
                out.append(_row(rs, [f"`{scen}`", str(v), f"`{cfg}`"], slash=True))
    over = ["| config | views | cells | recall | PSNR gain (of exact) | other removed (worst) "
            "| clean PSNR change (worst) | clean removed (worst) |",
            "|---|---|---|---|---|---|---|---|"]
    for cfg in configs:
        for v in views:
            rs = [r for (s, c, vv), x in cells.items() if c == cfg and vv == v for r in x]
            over.append(_row(rs, [f"`{cfg}`", str(v), str(len(rs))], slash=False))
    return out, over


def _row(rs: list, head: list, *, slash: bool) -> str:
    gains = [RA._gain(r) for r in rs]
    exact = sum(RA._exact(r) for r in rs)
    other = [r["other_removed"] for r in rs]
    clean = [RA._clean(r) for r in rs]
    crm = [r["clean_removed"] for r in rs]
    share = f"{100 * sum(gains) / exact:.0f} %" if exact > 0 else "n/a"
    mean = sum(gains) / len(gains)
    recall = sum(r["recall"] for r in rs) / len(rs)
    if slash:
        o = f"{100 * sum(other) / len(other):.2f} / {100 * max(other):.2f} %"
        c = f"{sum(clean) / len(clean):+.3f}"
        cr = f"{100 * sum(crm) / len(crm):.3f} / {100 * max(crm):.3f} %"
    else:
        o = f"{100 * sum(other) / len(other):.2f} % ({100 * max(other):.2f} %)"
        c = f"{sum(clean) / len(clean):+.3f} ({min(clean):+.3f})"
        cr = f"{100 * sum(crm) / len(crm):.2f} % ({100 * max(crm):.2f} %)"
    return "| " + " | ".join(head + [f"{recall:.3f}", f"{mean:+.2f} ({share})", o, c, cr]) + " |"


def real_table(real: list | None) -> list[str]:
    if not real:
        return []
    out = ["| config | IoU | recall | precision | other-view PSNR | + filter | no paste "
           "| other removed |", "|---|---|---|---|---|---|---|---|"]
    for r in real:
        out.append(f"| `{r['config']}` | {r['iou']:.3f} | {r['recall']:.3f} | "
                   f"{r['precision']:.3f} | {r['psnr_before']:.2f} | {r['psnr_after']:.2f} | "
                   f"{r['psnr_clean']:.2f} | {_pct(r['other_removed'])} |")
    return out


def ablation_rows(data: dict, specs: dict) -> list[str]:
    """One row per config over every cell of the ablation grid, with the real-image check."""
    real = {r["config"]: r for r in data.get("real_image_check") or []}
    configs = list(dict.fromkeys(r["config"] for r in data["rows"]))
    out = ["| config | spec | PSNR gain (of exact) | recall | other removed (worst) "
           "| clean PSNR change (worst) | clean removed (worst) | real-image IoU "
           "| real other removed |", "|---|---|---|---|---|---|---|---|---|"]
    for cfg in configs:
        rs = [r for r in data["rows"] if r["config"] == cfg]
        gains = [RA._gain(r) for r in rs]
        exact = sum(RA._exact(r) for r in rs)
        share = f"{100 * sum(gains) / exact:.0f} %" if exact > 0 else "n/a"
        other = [r["other_removed"] for r in rs]
        clean = [RA._clean(r) for r in rs]
        crm = [r["clean_removed"] for r in rs]
        rr = real.get(cfg)
        out.append(
            f"| `{cfg}` | `{specs.get(cfg, cfg)}` | {sum(gains) / len(gains):+.2f} ({share}) | "
            f"{sum(r['recall'] for r in rs) / len(rs):.3f} | "
            f"{100 * sum(other) / len(other):.2f} % ({100 * max(other):.2f} %) | "
            f"{sum(clean) / len(clean):+.3f} ({min(clean):+.3f}) | "
            f"{100 * sum(crm) / len(crm):.2f} % ({100 * max(crm):.2f} %) | "
            + (f"{rr['iou']:.3f} | {_pct(rr['other_removed'])} |" if rr else "n/a | n/a |"))
    return out


def acceptance_lines(data: dict, config: str = "default") -> list[str]:
    cells = defaultdict(list)
    for r in data["rows"]:
        cells[(r.get("realism") or "plain", r["config"], r["views"])].append(r)
    real = {r["config"]: r for r in data.get("real_image_check") or []}
    return [f"{'met    ' if met else 'NOT met'}  {point}: {figure}"
            for point, figure, met in RA.acceptance(cells, real, config)]


def _runs_line(step: Step) -> str:
    m = re.search(r"(\d+) runs in (\d+) s", step.stdout)
    runs = f"{m.group(1)} runs in {m.group(2)} s of the bench" if m else "the bench"
    return f"{runs}, {step.seconds:.0f} s in all"


# --------------------------------------------------------------------------------------------
# Sections


def section_scenarios(steps: list, mach: dict, work: str) -> str:
    st = steps[0]
    scen = SCENARIOS.split(",")
    lines = [
        "## Realism scenarios", "",
        "`clearsplat.synth.realism` gives the stand-in backbone the artifacts of real "
        "feed-forward predictions, each a scenario of `clearsplat bench --realism` "
        "(`docs/method.md`, \"Real backbones\"). Their strengths aim where real models are: "
        "*inputs* is the PSNR of each input image against the render of its own view's "
        "Gaussians (mean, and range over views), *test views* the PSNR of the clean-input "
        "reconstruction on held-out views (seed 0).", "",
        "```bash", st.shown(), "```", "",
        machine_line(mach, st.finished) + f" {st.seconds:.0f} s in all.", "",
        *_code(st.stdout), "",
        "Each picture (made by the same script with `--pictures docs/images`): view 0 as the "
        "model saw it (with its distractors), the render of view 0's own Gaussians, a test-view "
        "render of the whole cluttered prediction, and that test view's truth (object family, "
        "4 views, seed 0).", "",
        "| scenario | |", "|---|---|",
        *[f"| `{s}` | ![{s}](images/realism-{s}.png) |" for s in scen], ""]
    return wrap(lines)


def section_quality(steps: list, mach: dict, work: str) -> str:
    st = steps[0]
    data = _json(os.path.join(ROOT, st.result))
    per, over = quality_tables(data)
    res = st.result
    full = "--resolution" in st.argv and st.argv[st.argv.index("--resolution") + 1] == "256x448"
    lines = [
        "## Quality: acceptance at the benchmark's resolution" if full else "## Quality", "",
        "The realism benchmark: clearsplat's synthetic worlds (analytic ground truth) "
        "reconstructed by the stand-in backbone with the artifacts of real feed-forward models "
        "(`plain` none; `soft` opacities; `depth` bias; `multi` three Gaussians per pixel; "
        "`exposure`; `pose` error; `coarse` 2x2 grid without `pixel_id`; `all`: soft, depth, "
        "exposure and pose together; `clearsplat.synth.realism`). Grid: "
        f"{grid_words(st)}; configs `default` (today's) and `paper-local` (the paper's "
        "procedure with the weight-free features).", "",
        "```bash", st.shown(),
        f"python benchmarks/realism_acceptance.py {res} --check default", "```", "",
        machine_line(mach, st.finished) + f" One process, cells one after another "
        f"({_runs_line(st)}).", "",
        "Per scenario, view count and config, means over the two families, worst cell after "
        "the slash. *gain*: test-view PSNR over the unfiltered prediction, with its share of "
        "the gain of removing exactly the distractor Gaussians (sum over sum); *other*: share "
        "of the other Gaussians removed; *clean*: the filter on each scene's clutter-free twin.",
        "", *per, "",
        "Over every scenario and family (worst cell in brackets):", "", *over, "",
        "The acceptance points of `benchmarks/realism_acceptance.py --check default`:", "",
        "```", *acceptance_lines(data), "```", ""]
    real = data.get("real_image_check")
    lines += ["### Real-image check", ""]
    if real:
        lines += [
            "The same command's real-image check: scikit-image's Middlebury Motorcycle stereo "
            "pair (two views, ground-truth disparity, 240x368) reconstructed pixel-aligned, a "
            "real object (the cat of `skimage.data.chelsea()`) pasted into one view. *IoU*, "
            "*recall*, *precision*: the removed pixels against the pasted mask; PSNR of the "
            "other view's render before and after filtering and without the paste; *other "
            "removed*: share of the other Gaussians removed.", "", *real_table(real), ""]
    else:
        lines += ["Not run in this grid (`--no-real-check`).", ""]
    return wrap(lines)


def section_ablation(steps: list, mach: dict, work: str) -> str:
    from clearsplat.bench import ABLATIONS
    st = steps[0]
    data = _json(os.path.join(ROOT, st.result))
    rows = ablation_rows(data, ABLATIONS)
    n_cells = len({(r.get("realism"), r["family"], r["views"]) for r in data["rows"]})
    lines = [
        "## Ablation", "",
        "Each option in which today's default differs from the paper, set to the paper's value "
        "alone; the paper's procedure (`paper-local`) and with its individual test changed "
        "(`paper+excl-own`); the paper's own ablations on the default; options that are off by "
        "default switched on. The configs are `clearsplat.bench.ABLATIONS`; `docs/method.md` "
        "names what each option answers. Grid: " + grid_words(st) + ".", "",
        "```bash", st.shown(), "```", "",
        machine_line(mach, st.finished) + f" One process ({_runs_line(st)}).", "",
        f"Means over the {n_cells} cells of the grid, worst cell in brackets; *of exact*: sum "
        "of the gains over the sum of the gains of removing exactly the distractors; the last "
        "two columns are the real-image check (two views).", "", *rows, ""]
    return wrap(lines)


def _code(text: str) -> list[str]:
    return ["```", *text.rstrip("\n").splitlines(), "```"]


def _step_lines(st: Step, mach: dict, after: str = "") -> list[str]:
    """A measuring step on the page: its command, the machine and its output."""
    return ["```bash", st.shown(), "```", "", machine_line(mach, st.finished) + after, "",
            *_code(st.stdout), ""]


def section_speed(steps: list, mach: dict, work: str, load: str) -> str:
    by = {s.name: s for s in steps}
    lines = [
        "## Speed", "",
        "Today's default on the CPU. Each script prints its machine and the 1-minute load "
        f"average at its end; before the section the load was {load}.", ""]
    if "speed-object" in by or "speed-street" in by or "speed-dense" in by:
        lines += [
            "### Filter", "",
            "Stand-in scenes (one pixel-aligned Gaussian per pixel), each view count in a fresh "
            "process (its peak resident memory is its own); *total s*: median of the runs, "
            "*min-max* their range, *first* the first (a fresh process, as one "
            "`clearsplat filter` call); *CPU s*: process CPU time; *prepared*/*derived*: "
            "camera preparations, and those a second round took from the first; *where the "
            "time goes*: medians of the steps.", ""]
        for name in ("speed-object", "speed-street", "speed-dense"):
            if name in by:
                lines += _step_lines(by[name], mach, f" {by[name].seconds:.0f} s in all.")
    for name, heading, text in _SPEED_TEXT:
        if name in by:
            lines += [heading, "", text, "", *_step_lines(by[name], mach)]
    return wrap(lines)


#: The speed section's other steps: (step, heading, what it measures).
_SPEED_TEXT = (
    ("speed-cli", "### `clearsplat filter`, whole process",
     "A saved 16-view object bundle at 128x192 (393,216 Gaussians), filtered by the command in "
     "a fresh process each time (imports, loading, filtering, writing)."),
    ("speed-render", "### Rendering",
     "The CPU rasterizer: 8 views of pixel-aligned Gaussians at 256x448 (917,504 Gaussians) "
     "rendered from each input camera; medians over cameras and repeats."),
)


STATIC = {
    "dense": """## Dense captures

From 24 views on, the default bounds each camera's renders to its seven most co-visible views
and those it verifies, and picks verification views by the field of view shared both ways
(`neighbours="auto"`, `verify_views="auto"`); below 24 views, and in `exact`, every view. Each
view is compared with its reveal reference (per pixel, the 0.75 quantile of the depths of its
seven most co-visible views within 30 degrees, each rendered on its own), which outvotes the
other views' passers-by; the `video` preset also leaves the frame on each side out
(`leave_out=1`). Measurements: `docs/method.md`, "Dense captures",
"`reveal_reference="quantile"`" and
"Video"; speed: the street rows of "Speed" above.
""",
    "gpu": """## On a GPU

Measured on 2026-11-29 on a GPU machine we had for a short time: one NVIDIA H200 (143,771 MiB,
driver 580.159.04), 16 host cores, Python 3.12.3, PyTorch 2.11.0+cu130, clearsplat 0.12.0 built
there as a wheel; object scenes at 256x448 (street at 32 views), today's default config and
`fast` preset. That machine is not at hand, so this page's command does not regenerate these
figures.

| views | torch backend on the H200, total s | its verification s | GPU peak GB | native CPU filter, the same 16 cores: total s / verification s | same decisions |
|---|---|---|---|---|---|
| 4 | 2.04 | 1.05 | 0.97 | 0.84 / 0.28 | yes |
| 8 | 10.45 | 4.18 | 1.76 | 3.61 / 1.19 | no: 36 Gaussians differ (17,282 removed against 17,248) |
| 16 | 32.05 | 10.00 | 4.37 | 10.90 / 2.94 | no |
| 32 (street) | 49.24 | 18.29 | 5.65 | not measured / 5.71 | no |
| 8, `fast` | 5.54 | 2.79 | 1.48 | 1.59 / 0.56 | yes |
| 16, `fast` | 11.07 | 4.49 | 2.37 | 3.21 / 0.91 | yes |

Commands: `python benchmarks/filter_speed.py --device cuda --set backend=torch --views 4,8,16
--repeats 2 --full-repeats 1` (medians of 2 GPU runs after an untimed one), the same with
`--preset fast --views 8,16 --repeats 1` and `--views 32 --family street --repeats 1` (its
native column: the verification of its own native run); native: `python
benchmarks/filter_speed.py --views 4,8,16 --repeats 2 --full-repeats 1` and `--preset fast
--views 8,16 --repeats 1 --full-repeats 0`. `bash benchmarks/gpu_check.sh OUTDIR` runs all of
it, the street last (in 500 s it did not reach the street's end). The paper reports
3.24 s (DepthSplat, 8 views) and 3.86 s (ReSplat, 16 views) on an RTX 4090. The native filter on
those 16 cores is no faster than on the 2-core VM ("Speed" above: 0.79 / 3.63 / 10.27 s): its
refinement and the verification's serial NumPy work do not spread over cores.

**Why the GPU is slower than the CPU.** `python benchmarks/gpu_profile.py --views 4` (same
machine): of 2.70 s under the profiler the GPU is busy 0.47 s (17 %), with 199,167 torch ops,
80,291 kernel launches and 5,389 stream synchronisations; of its 0.47 s, compositing's scans
(`cumsum`) take 34 % and gathers 27 %: the backend expands every (Gaussian, pixel) fragment of a
tile, where a rasterizer kernel stops each pixel at its transmittance limit. It is bound by
launches, host round trips and fragment expansion: fused compositing kernels are needed, not a
faster card.

**Decisions.** The backend's renders agree with the native ones to float32 rounding, and at 8
views that rounding flips a few decisions (on CPU tensors too): about a third of each view's
patches differ by less than 1e-5 of their depth in the support condition (`python
benchmarks/support_rounding.py`). At 4 views (`python benchmarks/gpu_decisions.py --views 4,8
--set backend=torch`) and on a dense street (`python benchmarks/gpu_decisions.py --views 24
--family street --resolution 128x224 --set backend=torch --set verify_base=static`: 22,413
removed, 18.2 s against 4.5 s natively) the GPU made the native decisions exactly. The CUDA
tests (`python -m pytest tests/test_torch_backend.py -k cuda`) passed there: 10 passed.

**gsplat** (`--set device=cuda`, the default on CUDA) was not measured (no gsplat on that
machine); `tests/test_gsplat.py` checks its path with a fake gsplat.
""",
    "datasets": """## Real datasets: RobustNeRF and NeRF On-the-go

No figures exist: the datasets cannot be downloaded here. The workflow is in place and tested
on miniature copies of both layouts (`tests/test_datasets.py`):

```bash
clearsplat prepare data/robustnerf/statue data/on-the-go/patio --out prep/ --views 4,8,16
# the backbone writes prep/<dataset>/<scene>-<N>v-c<K>/gaussians.ply into each bundle, then
clearsplat batch 'prep/*/*' --out filtered/
clearsplat eval 'prep/*/*' --filtered filtered/ --label DepthSplat
```

- **Layouts** (`clearsplat.io.datasets`): RobustNeRF, `images/` (or `--images`) and COLMAP
  `sparse/0`, training images named `clutter`, test images `extra`; On-the-go,
  `transforms.json` and `split.json` (`clutter` / `extra`, indices into the images sorted by
  name), with `sparse/0` for co-visibility.
- **View configurations** (`clearsplat prepare`): four per scene and input count. Each starts
  from the (training, test) pair sharing the most COLMAP points that no earlier configuration
  started from, then adds input views and test views alternately, each the one that most
  increases the points seen by both sets (ties: most points shared with the other set, then
  the lower index), up to `--test-views` (3) test views. The paper does not give the exact
  procedure; this is our reading.
- **Scores** (`clearsplat eval`): the prediction and its filtered output rendered at the test
  cameras (CPU rasterizer, black background); PSNR and SSIM, LPIPS (AlexNet) only where the
  `lpips` package and its weights are installed, otherwise `n/a`; means over a scene's
  configurations, then over scenes, as in the paper's main table.
""",
}


PREAMBLE = """# Benchmarks

Today's default, measured by one command; this page is generated, do not edit it by hand:

```bash
python benchmarks/report.py --out docs/benchmarks.md            # every section
python benchmarks/report.py --out docs/benchmarks.md --only speed   # on a quiet machine
```

Each section names the commands that reproduce its tables and the machine they ran on
(`benchmarks/report.py` documents the grids). LPIPS and DINOv3 figures are absent: their
weights cannot be had offline. Durations given outside the Speed section are how long a run
took, not speed figures. How each departure from the paper was chosen is in `docs/method.md`;
what changed between versions, in `CHANGELOG.md`.
"""


def begin(name):
    return f"<!-- report:{name} -->"


def end(name):
    return f"<!-- /report:{name} -->"


def parse_blocks(page: str) -> dict:
    """The generated blocks of an existing page, by section name."""
    out = {}
    for name in SECTIONS:
        m = re.search(re.escape(begin(name)) + r"\n(.*?)" + re.escape(end(name)), page, re.S)
        if m:
            out[name] = m.group(1)
    return out


def parse_notes(page: str) -> dict:
    """The hand-written text of an existing page after each generated block, by section name:
    what lies between the block's end and the next block's beginning (or the page's end)."""
    out = {}
    for name in SECTIONS:
        m = re.search(re.escape(end(name)) + r"\n(.*?)(?=<!-- report:|\Z)", page, re.S)
        if m and m.group(1).strip():
            out[name] = m.group(1).strip("\n")
    return out


PAGE_ORDER = ("scenarios", "quality", "ablation", "speed", "dense", "gpu", "datasets")


def assemble(blocks: dict, old: str = "") -> str:
    """The page from new ``blocks`` and, for the sections not among them, ``old``'s; the
    hand-written text that ``old`` has after a block (:func:`parse_notes`) stays after it."""
    kept, notes = parse_blocks(old), parse_notes(old)
    parts = [PREAMBLE]
    for name in PAGE_ORDER:
        body = blocks.get(name, kept.get(name))
        if body is None:
            body = (f"## {name.capitalize()}\n\nNot generated yet: `python benchmarks/report.py "
                    f"--out docs/benchmarks.md --only {name}`.\n")
        parts.append(f"{begin(name)}\n{body.rstrip()}\n{end(name)}\n")
        if name in notes:
            parts.append(notes[name].rstrip() + "\n")
    return "\n".join(parts)


def load_average() -> float:
    return os.getloadavg()[0]


def wait_quiet(limit_s: float, max_load: float, log, quiet_s: float = 60.0,
               poll_s: float = 10.0, *, load=None, clock=time.monotonic,
               sleep=time.sleep) -> tuple[bool, str]:
    """Wait until the 1-minute load stays below ``max_load`` for ``quiet_s``, at most
    ``limit_s`` seconds. Returns (quiet, the loads seen, in words)."""
    load = load or load_average
    t0 = clock()
    since = None
    seen = []
    while True:
        la = load()
        seen.append(la)
        now = clock()
        if la < max_load:
            since = now if since is None else since
            if now - since >= quiet_s:
                return True, f"{la:.2f} (below {max_load} for {quiet_s:.0f} s)"
        else:
            since = None
        if now - t0 >= limit_s:
            return False, f"{la:.2f} after {limit_s:.0f} s of waiting (lowest {min(seen):.2f})"
        log(f"load {la:.2f}; waiting for below {max_load}")
        sleep(poll_s)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "benchmarks.md"))
    ap.add_argument("--only", help="comma-separated sections to regenerate: "
                                   + ", ".join(MEASURED) + " (default: all); the others keep "
                                   "their blocks of the existing page. The fixed-text "
                                   "sections (" + ", ".join(STATIC) + ") are written on every "
                                   "run; name one of them alone to measure nothing")
    ap.add_argument("--work", default=os.path.join(ROOT, "out", "report"),
                    help="folder for the raw outputs (default: out/report)")
    ap.add_argument("--reuse", action="store_true",
                    help="take a step's output from --work when the same command wrote it")
    ap.add_argument("--quick", action="store_true",
                    help="a tiny grid (48x80, 2-4 views, no real-image check or rendering "
                         "speed): checks the generator, measures nothing worth keeping")
    ap.add_argument("--wait-quiet", type=float, default=600, metavar="S",
                    help="before the speed section wait up to S seconds (default %(default)s; "
                         "0: do not wait) for the 1-minute load to stay below --max-load for a "
                         "minute; otherwise the speed section keeps its block and the exit "
                         "status is 3")
    ap.add_argument("--max-load", type=float, default=0.5)
    ap.add_argument("--max-lines", type=int, default=MAX_LINES)
    args = ap.parse_args(argv)
    only = [s.strip() for s in args.only.split(",")] if args.only else list(MEASURED)
    for s in only:
        if s not in MEASURED and s not in STATIC:
            ap.error(f"--only: unknown section {s!r}; one of "
                     f"{', '.join(MEASURED + tuple(STATIC))}")
    os.makedirs(args.work, exist_ok=True)

    def log(s):
        print("report: " + s, file=sys.stderr, flush=True)

    g = grids(args.work, args.quick)
    mach = machine()
    blocks = {name: STATIC[name] for name in STATIC}
    make = {"scenarios": section_scenarios, "quality": section_quality,
            "ablation": section_ablation}
    for name in ("scenarios", "quality", "ablation"):
        if name in only:
            steps = [run_step(s, args.work, reuse=args.reuse, log=log)
                     for s in getattr(g, name)]
            blocks[name] = make[name](steps, mach, args.work)
    status = 0
    if "speed" in only:
        quiet, load = True, f"{load_average():.2f}"
        if args.wait_quiet:
            quiet, load = wait_quiet(args.wait_quiet, args.max_load, log)
        if quiet:
            steps = [run_step(s, args.work, reuse=args.reuse, log=log) for s in g.speed]
            blocks["speed"] = section_speed(steps, mach, args.work, load)
        else:
            log(f"the machine never got quiet (load {load}): the speed section keeps its "
                "block of the existing page")
            status = 3
    old = _read(args.out) if os.path.exists(args.out) else ""
    page = assemble(blocks, old)
    n = page.count("\n")
    if n > args.max_lines:
        raise SystemExit(f"report: the page would have {n} lines (at most {args.max_lines})")
    with open(args.out, "w") as f:
        f.write(page)
    log(f"wrote {args.out} ({n} lines)")
    return status


if __name__ == "__main__":
    sys.exit(main())
