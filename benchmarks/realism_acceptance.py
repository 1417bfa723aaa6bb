"""Acceptance summary of a ``clearsplat bench --realism ...`` run, from its results.json.

Per scenario, config and view count, means over the families (and seeds): distractor recall,
PSNR gain and its share of the gain of removing exactly the distractors (sum of gains over sum
of exact gains), share of the other Gaussians removed (mean / worst cell), and on the clean
twins the PSNR change and share removed (mean / worst cell). Then, per scenario and config,
the mean PSNR gain over every cell.

    python benchmarks/realism_acceptance.py bench-out/results.json
    python benchmarks/realism_acceptance.py a/results.json b/results.json \
        --check default --baseline prev-default

Several results files are read as one (runs of different configs on the same grid). With
``--check CONFIG`` it then states each acceptance point of the realism benchmark for that
config, with the figure that decides it and ``met`` or ``NOT met``:

- mean distractor recall at least 0.85 per scenario and view count;
- at 16 views at least 80 % of the exact-removal gain per scenario;
- other Gaussians removed at most 1 % per scenario and view count, 2 % in every cell;
- clean twins: mean PSNR change at least -0.05 dB and at most 0.5 % removed per scenario and
  view count, 1.5 % in every cell;
- with ``--baseline``: mean PSNR gain per scenario at least the baseline's, and on the plain
  scenario recall and gain at every view count and the real-image IoU no worse.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict


def _mean(xs) -> float:
    return sum(xs) / len(xs)


def _gain(r) -> float:
    return r["filtered"]["psnr"] - r["baseline"]["psnr"]


def _exact(r) -> float:
    return r["exact"]["psnr"] - r["baseline"]["psnr"]


def _clean(r) -> float:
    return r["clean_filtered"]["psnr"] - r["clean_baseline"]["psnr"]


def acceptance(cells: dict, real: dict, config: str, baseline: str | None = None) -> list:
    """``(point, figure, met)`` for each acceptance point of ``config`` (see the module)."""
    mine = {(s, v): rs for (s, c, v), rs in cells.items() if c == config}
    if not mine:
        raise SystemExit(f"no rows of config {config!r}")
    out = []

    def worst(label, items, bad, text, keep=max):
        key, value = keep(items, key=lambda kv: kv[1])
        out.append((label, f"{text(value)} ({key})", not bad(value)))

    per = [(f"{s} {v} views", rs) for (s, v), rs in sorted(mine.items())]
    worst("mean recall >= 0.85 per scenario and view count",
          [(k, _mean([r["recall"] for r in rs])) for k, rs in per],
          lambda x: x < 0.85, lambda x: f"lowest {x:.3f}", keep=min)
    sixteen = [(f"{s}", sum(map(_gain, rs)) / sum(map(_exact, rs)))
               for (s, v), rs in sorted(mine.items()) if v == 16]
    if sixteen:
        worst("16 views: >= 80 % of the exact-removal gain per scenario", sixteen,
              lambda x: x < 0.8, lambda x: f"lowest {100 * x:.0f} %", keep=min)
    worst("other removed <= 1 % per scenario and view count",
          [(k, _mean([100 * r["other_removed"] for r in rs])) for k, rs in per],
          lambda x: x > 1.0, lambda x: f"highest {x:.2f} %")
    every = [(f"{r.get('realism') or 'plain'} {r['family']} {r['views']} views", r)
             for rs in mine.values() for r in rs]
    worst("other removed <= 2 % in every cell",
          [(k, 100 * r["other_removed"]) for k, r in every],
          lambda x: x > 2.0, lambda x: f"highest {x:.2f} %")
    worst("clean: mean PSNR change >= -0.05 dB per scenario and view count",
          [(k, _mean([_clean(r) for r in rs])) for k, rs in per],
          lambda x: x < -0.05, lambda x: f"lowest {x:+.3f} dB", keep=min)
    worst("clean: removed <= 0.5 % per scenario and view count",
          [(k, _mean([100 * r["clean_removed"] for r in rs])) for k, rs in per],
          lambda x: x > 0.5, lambda x: f"highest {x:.2f} %")
    worst("clean: removed <= 1.5 % in every cell",
          [(k, 100 * r["clean_removed"]) for k, r in every],
          lambda x: x > 1.5, lambda x: f"highest {x:.2f} %")
    if baseline is None:
        return out
    base = {(s, v): rs for (s, c, v), rs in cells.items() if c == baseline}
    if not base:
        raise SystemExit(f"no rows of config {baseline!r}")
    scenarios = sorted({s for s, _ in mine})
    diffs = []
    for s in scenarios:
        a = [_gain(r) for (t, _), rs in mine.items() if t == s for r in rs]
        b = [_gain(r) for (t, _), rs in base.items() if t == s for r in rs]
        if a and b:
            diffs.append((s, _mean(a) - _mean(b)))
    worst(f"mean PSNR gain per scenario >= {baseline}'s", diffs,
          lambda x: x < 0, lambda x: f"smallest difference {x:+.2f} dB", keep=min)
    plain = []
    for (s, v), rs in sorted(mine.items()):
        if s == "plain" and (s, v) in base:
            plain.append((f"recall, {v} views", _mean([r["recall"] for r in rs])
                          - _mean([r["recall"] for r in base[(s, v)]])))
            plain.append((f"gain, {v} views", _mean([_gain(r) for r in rs])
                          - _mean([_gain(r) for r in base[(s, v)]])))
    if plain:
        worst(f"plain scenario: recall and gain no worse than {baseline}'s", plain,
              lambda x: x < 0, lambda x: f"smallest difference {x:+.3f}", keep=min)
    if config in real and baseline in real:
        d = real[config]["iou"] - real[baseline]["iou"]
        out.append((f"real-image IoU no worse than {baseline}'s",
                    f"{real[config]['iou']:.3f} against {real[baseline]['iou']:.3f}", d >= 0))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", nargs="+", help="results.json written by clearsplat bench")
    ap.add_argument("--check", metavar="CONFIG", help="state each acceptance point for it")
    ap.add_argument("--baseline", metavar="CONFIG",
                    help="with --check: the config whose gains and plain figures to keep")
    args = ap.parse_args()
    rows, real = [], {}
    for path in args.results:
        data = json.load(open(path))
        rows += data["rows"]
        for r in data.get("real_image_check") or []:
            real[r["config"]] = r
    cells = defaultdict(list)
    for r in rows:
        cells[(r.get("realism") or "plain", r["config"], r["views"])].append(r)
    order = list(dict.fromkeys(k[0] for k in cells))
    print("scenario  config         views  recall   gain of exact  other mean/max   clean dPSNR"
          "  clean rm mean/max")
    per_scenario = defaultdict(list)
    for scen in order:
        for key in sorted((k for k in cells if k[0] == scen), key=lambda k: (k[1], k[2])):
            rs = cells[key]
            gains = [_gain(r) for r in rs]
            exact = [_exact(r) for r in rs]
            other = [100 * r["other_removed"] for r in rs]
            clean = [_clean(r) for r in rs]
            crm = [100 * r["clean_removed"] for r in rs]
            recall = sum(r["recall"] for r in rs) / len(rs)
            per_scenario[(scen, key[1])].extend(gains)
            print(f"{scen:9s} {key[1]:14s} {key[2]:5d}  {recall:6.3f}  "
                  f"{sum(gains) / len(gains):+5.2f}  {100 * sum(gains) / sum(exact):5.0f}%  "
                  f"{sum(other) / len(other):5.2f}/{max(other):5.2f}%  "
                  f"{sum(clean) / len(clean):+10.3f}  "
                  f"{sum(crm) / len(crm):6.3f}/{max(crm):6.3f}%")
    print("\nMean PSNR gain over every cell of a scenario")
    for (scen, cfg), g in per_scenario.items():
        print(f"{scen:9s} {cfg:14s} {sum(g) / len(g):+5.2f} dB over {len(g)} cells")
    overall = defaultdict(list)
    for (_, cfg, views), rs in cells.items():
        overall[(cfg, views)].extend(rs)
    print("\nOver every scenario and family (worst cell in brackets)")
    print("config          views  cells  PSNR gain (of exact)  recall  other removed"
          "      clean dPSNR        clean removed")
    for (cfg, views) in sorted(overall):
        rs = overall[(cfg, views)]
        gains = [_gain(r) for r in rs]
        exact = [_exact(r) for r in rs]
        other = [100 * r["other_removed"] for r in rs]
        clean = [_clean(r) for r in rs]
        crm = [100 * r["clean_removed"] for r in rs]
        print(f"{cfg:15s} {views:5d}  {len(rs):5d}  {sum(gains) / len(gains):+5.2f} "
              f"({100 * sum(gains) / sum(exact):3.0f} %)       "
              f"{sum(r['recall'] for r in rs) / len(rs):6.3f}  "
              f"{sum(other) / len(other):.2f} % ({max(other):.2f} %)  "
              f"{sum(clean) / len(clean):+.3f} ({min(clean):+.3f})  "
              f"{sum(crm) / len(crm):.2f} % ({max(crm):.2f} %)")
    if args.check:
        print(f"\nAcceptance of {args.check}"
              + (f" (baseline {args.baseline})" if args.baseline else ""))
        for point, figure, met in acceptance(cells, real, args.check, args.baseline):
            print(f"  {'met    ' if met else 'NOT met'}  {point}: {figure}")


if __name__ == "__main__":
    main()
