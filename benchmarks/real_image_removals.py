"""What the real-image check removes beside the pasted object, by distance to it.

Usage::

    python benchmarks/real_image_removals.py
    python benchmarks/real_image_removals.py --config default+refine=depth

Runs :func:`clearsplat.synth.stereo.real_image_check` (the Middlebury pair with a real object
pasted into one view) with a config and prints its IoU and the other view's PSNR, then the pixels of the pasted view that
hold a removed Gaussian outside the paste, in bands of distance to it (the expansion's dilation
is 9 pixels), each with the median ratio of its removed Gaussians' camera depth to the clean
scene's depth at their pixel (below 1: in front of the surface that is there without the paste).
Counts only: the same on any machine.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import ndimage

from clearsplat.bench import parse_config
from clearsplat.synth.stereo import real_image_check

#: Upper ends of the distance bands, in pixels from the paste.
BANDS = (1.5, 9.5, np.inf)


def removals_beside(check: dict) -> list[dict]:
    """Per distance band, the removed pixels outside the paste and the median depth ratio of
    the removed Gaussians there (``count``, ``ratio``; ratio NaN for an empty band)."""
    scene, info = check["scene"], check["info"]
    view, mask = info["view"], info["mask"]
    extra = check["removed_pixels"] & ~mask
    distance = ndimage.distance_transform_edt(~mask)
    own = (scene.view_id == view) & check["result"].removed
    pid = scene.pixel_id[own]
    z = scene.cameras[view].to_camera(scene.gaussians.means[own])[:, 2]
    ratio = z / info["depths"][view].reshape(-1)[pid]
    at = extra.reshape(-1)[pid]
    d = distance.reshape(-1)[pid]
    out, low = [], 0.0
    for high in BANDS:
        band = (distance > low) & (distance <= high)
        sel = at & (d > low) & (d <= high)
        out.append({"from": low, "to": high, "count": int((extra & band).sum()),
                    "ratio": float(np.median(ratio[sel])) if sel.any() else float("nan")})
        low = high
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default="default", help="PRESET[+key=value...]")
    p.add_argument("--height", type=int, default=240, help="image rows of the pair")
    args = p.parse_args(argv)
    check = real_image_check(parse_config(args.config), height=args.height)
    mask = check["info"]["mask"]
    found = int((check["removed_pixels"] & mask).sum())
    print(f"real-image check, {args.config}: IoU {check['iou']:.3f}; {found:,} of "
          f"{int(mask.sum()):,} pasted pixels removed, "
          f"{int((check['removed_pixels'] & ~mask).sum()):,} others")
    print(f"the other view: PSNR {check['psnr_before']:.2f} dB unfiltered, "
          f"{check['psnr_after']:.2f} dB filtered, {check['psnr_clean']:.2f} dB for the "
          f"prediction without the paste")
    print(f"{'pixels from the paste':>22} {'removed':>8} {'depth / clean depth':>20}")
    for b in removals_beside(check):
        print(f"{b['from']:>10.1f} - {b['to']:<9.1f} {b['count']:>8,} {b['ratio']:>20.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
