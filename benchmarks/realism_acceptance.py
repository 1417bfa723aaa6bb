"""Acceptance summary of a ``clearsplat bench --realism ...`` run, from its results.json.

Per scenario, config and view count, means over the families (and seeds): distractor recall,
PSNR gain and its share of the gain of removing exactly the distractors (sum of gains over sum
of exact gains), share of the other Gaussians removed (mean / worst cell), and on the clean
twins the PSNR change and share removed (mean / worst cell). Then, per scenario and config,
the mean PSNR gain over every cell.

    python benchmarks/realism_acceptance.py bench-out/results.json
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", help="results.json written by clearsplat bench")
    rows = json.load(open(ap.parse_args().results))["rows"]
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
            gains = [r["filtered"]["psnr"] - r["baseline"]["psnr"] for r in rs]
            exact = [r["exact"]["psnr"] - r["baseline"]["psnr"] for r in rs]
            other = [100 * r["other_removed"] for r in rs]
            clean = [r["clean_filtered"]["psnr"] - r["clean_baseline"]["psnr"] for r in rs]
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
        gains = [r["filtered"]["psnr"] - r["baseline"]["psnr"] for r in rs]
        exact = [r["exact"]["psnr"] - r["baseline"]["psnr"] for r in rs]
        other = [100 * r["other_removed"] for r in rs]
        clean = [r["clean_filtered"]["psnr"] - r["clean_baseline"]["psnr"] for r in rs]
        crm = [100 * r["clean_removed"] for r in rs]
        print(f"{cfg:15s} {views:5d}  {len(rs):5d}  {sum(gains) / len(gains):+5.2f} "
              f"({100 * sum(gains) / sum(exact):3.0f} %)       "
              f"{sum(r['recall'] for r in rs) / len(rs):6.3f}  "
              f"{sum(other) / len(other):.2f} % ({max(other):.2f} %)  "
              f"{sum(clean) / len(clean):+.3f} ({min(clean):+.3f})  "
              f"{sum(crm) / len(crm):.2f} % ({max(crm):.2f} %)")


if __name__ == "__main__":
    main()
