"""Check that the filter's output has not changed: removed Gaussians and summaries, bit for bit.

Usage::

    python benchmarks/filter_identity.py --save ref/      # record today's outputs
    python benchmarks/filter_identity.py --check ref/     # after a change: compare
    python benchmarks/filter_identity.py --check ref/ --set view_memory=0.5   # an option
    python benchmarks/filter_identity.py --check ref/ --ignore expanded_gaussians

Runs ``filter_distractors`` on the stand-in scenes (object and street, 4, 8 and 16 views, at
128x224 and 256x448; the default, ``paper-local`` and non-incremental configurations; with
``--dense`` also the default at 24 views (object) and 32 views (street), 128x224, where each
camera renders only its neighbourhood) and stores, per case, the removed Gaussians and the
summary without its timings. ``--check``
prints one line per case and exits 1 if any differs. Speed work must keep every case equal.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

CONFIGS = ("default", "paper-local", "full-rerender")


#: ``--dense`` cases: bounded neighbourhoods (``neighbours="auto"``), the default only.
DENSE_CASES = (("object", 24, 128, 224), ("street", 32, 128, 224))


def _cases(quick: bool):
    sizes = ((128, 224),) if quick else ((128, 224), (256, 448))
    for family in ("object", "street"):
        for h, w in sizes:
            for views in (4, 8, 16):
                yield family, views, h, w


def _config(name: str, overrides=()):
    from clearsplat.bench import parse_value
    from clearsplat.filter import FilterConfig
    if name == "default":
        cfg = FilterConfig()
    elif name == "paper-local":
        cfg = FilterConfig.preset("paper-local")
    else:
        cfg = FilterConfig(incremental=False)
    for item in overrides:   # KEY=VALUE, read as `clearsplat bench --config` reads it
        key, _, value = item.partition("=")
        cfg = cfg.replace(**{key: parse_value(value)})
    return cfg


def _run(family: str, views: int, h: int, w: int, configs, overrides=()) -> dict:
    import numpy as np

    from clearsplat.features import get_extractor
    from clearsplat.filter import filter_distractors
    from clearsplat.synth import make_world, reconstruct

    world = make_world(family, num_views=views, seed=0, height=h, width=w)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    extractor = get_extractor("local")
    out = {}
    for name in configs:
        r = filter_distractors(scene, config=_config(name, overrides), extractor=extractor)
        s = r.summary()
        s.pop("timings")
        s["config"].pop("incremental")
        for item in overrides:   # options that must not change the output are not compared
            s["config"].pop(item.partition("=")[0], None)
        out[name] = {"removed": np.flatnonzero(r.removed).tolist(), "summary": s}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", metavar="DIR")
    g.add_argument("--check", metavar="DIR")
    p.add_argument("--quick", action="store_true", help="128x224 only")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a FilterConfig field for every configuration (an option that must not "
                        "change the output), VALUE as in `clearsplat bench --config`")
    p.add_argument("--ignore", action="append", default=[], metavar="FIELD",
                   help="a field of the candidates' records not to compare (a record that "
                        "changed on purpose, e.g. expanded_gaussians); removals always are")
    p.add_argument("--no-full", action="store_true",
                   help="skip the non-incremental configuration (slow at 16 views)")
    p.add_argument("--dense", action="store_true",
                   help="also the default at 24 and 32 views (128x224)")
    args = p.parse_args(argv)
    folder = args.save or args.check
    os.makedirs(folder, exist_ok=True)
    configs = [c for c in CONFIGS if not (args.no_full and c == "full-rerender")]
    bad = 0
    cases = [(c, configs) for c in _cases(args.quick)]
    cases += [(c, ["default"]) for c in DENSE_CASES] if args.dense else []
    for (family, views, h, w), case_configs in cases:
        name = f"{family}-{views}v-{h}x{w}"
        path = os.path.join(folder, name + ".json")
        got = _run(family, views, h, w, case_configs, tuple(args.set))
        if args.save:
            with open(path, "w") as f:
                json.dump(got, f)
            print(f"saved {name}: " + ", ".join(f"{c} removes {len(got[c]['removed'])}"
                                                for c in case_configs))
            continue
        with open(path) as f:
            want = json.load(f)
        for c in case_configs:
            if c not in want:
                print(f"{name} {c}: no reference")
                continue
            # Options added since the reference was saved (performance settings that do not
            # change the output) or removed since are not compared: only those both configs have.
            got_config, want_config = got[c]["summary"]["config"], want[c]["summary"]["config"]
            for key in set(got_config) ^ set(want_config):
                got_config.pop(key, None)
                want_config.pop(key, None)
            for item in args.set:   # the options set here are not compared on either side
                want[c]["summary"]["config"].pop(item.partition("=")[0], None)
            # Likewise fields added to the candidates' records (the round that found them).
            known = set().union(*(r.keys() for r in want[c]["summary"]["candidates"]))
            for record in got[c]["summary"]["candidates"]:
                for key in set(record) - known if known else ():
                    record.pop(key)
            for s in (got[c]["summary"], want[c]["summary"]):
                for record in s["candidates"]:
                    for key in args.ignore:
                        record.pop(key, None)
            same = (got[c]["removed"] == want[c]["removed"]
                    and got[c]["summary"] == want[c]["summary"])
            bad += not same
            print(f"{name} {c}: {'identical' if same else 'DIFFERENT'} "
                  f"({len(got[c]['removed'])} removed)")
    if args.check:
        print("all identical" if not bad else f"{bad} cases differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
