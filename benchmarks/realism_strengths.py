"""How far each realism scenario of the stand-in backbone is from the plain one.

Prints, per scenario and family, how well the inputs are reproduced by their own view's
Gaussians and how well the clean-input reconstruction renders held-out test views (the
strengths aim at real models: about 25-32 dB and 17-25 dB), and with ``--pictures DIR`` writes
one small PNG per scenario: the input as the model saw it, its own Gaussians' render, a test
view render and the test view's truth.

    python benchmarks/realism_strengths.py --pictures docs/images
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from clearsplat.metrics import psnr
from clearsplat.render import render, render_batch
from clearsplat.synth import make_world
from clearsplat.synth.realism import SCENARIOS, realistic_reconstruction, reproduction_psnr


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", default="4,16")
    ap.add_argument("--resolution", default="256x448")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pictures", help="folder for one PNG per scenario (object family, 4 views)")
    args = ap.parse_args()
    h, w = (int(x) for x in args.resolution.split("x"))
    views = [int(v) for v in args.views.split(",")]
    print(f"{'scenario':<10}{'family':<8}{'views':>5}  {'inputs (own Gaussians) dB':>26}  "
          f"{'test views dB':>13}")
    for family in ("object", "street"):
        for nv in views:
            world = make_world(family, num_views=nv, seed=args.seed, height=h, width=w)
            for name in SCENARIOS:
                scene, _ = realistic_reconstruction(world, name, seed=args.seed, clean=True)
                own = reproduction_psnr(scene)
                test = [psnr(r.rgb, im) for r, im in
                        zip(render_batch(scene, world.test_cameras), world.test_images)]
                print(f"{name:<10}{family:<8}{nv:>5}  {own.mean():>10.2f} "
                      f"({own.min():5.2f}-{own.max():5.2f})    {np.mean(test):>13.2f}", flush=True)
                if args.pictures and family == "object" and nv == views[0]:
                    _picture(world, name, args.seed, args.pictures)


def _picture(world, name, seed, folder) -> None:
    from PIL import Image
    scene, _ = realistic_reconstruction(world, name, seed=seed)
    own = render(scene, scene.cameras[0], keep=scene.view_id == 0).rgb
    test = render(scene, world.test_cameras[0]).rgb
    panels = [scene.images[0], own, test, world.test_images[0]]
    strip = np.concatenate([np.clip(p, 0, 1) for p in panels], axis=1)
    img = Image.fromarray((strip * 255 + 0.5).astype(np.uint8))
    img = img.resize((img.width // 2, img.height // 2), Image.LANCZOS).quantize(colors=64)
    os.makedirs(folder, exist_ok=True)
    img.save(os.path.join(folder, f"realism-{name}.png"), optimize=True)


if __name__ == "__main__":
    main()
