"""``clearsplat import``: a model's PLY export -> a scene bundle with the view association."""

from __future__ import annotations

import json

from ._common import Bar, warn


def add_parser(sub) -> None:
    from ..io.importers import EXPORT_FORMATS, MODEL_FORMATS

    p = sub.add_parser(
        "import", help="turn a model's PLY export into a scene bundle",
        description="Read the PLY a feed-forward model's export function wrote, recover each "
                    "Gaussian's input view and pixel from the vertex order and the image grid "
                    "(da3, worldmirror, longlrm and voxel-fused anysplat exports: from where "
                    "each vertex projects, or from how it reproduces the input images), bring "
                    "it into the cameras' world, and write a bundle `clearsplat filter` takes, "
                    "in the file's vertex order. Defaults follow each model's upstream export "
                    "(docs/backbones.md).")
    formats = list(EXPORT_FORMATS) + list(MODEL_FORMATS)
    p.add_argument("format", choices=formats, metavar="FORMAT",
                   help=f"which model wrote the file: {', '.join(formats)}; worldmirror: "
                        "HunyuanWorld-Mirror v1 and WorldMirror 2.0 alike, told apart by the "
                        "file's vertex order (voxel order, pixel order or neither); longlrm: "
                        "pruned or not, told apart the same way; volsplat: refused (its "
                        "export keeps no scale)")
    p.add_argument("ply", help="the exported .ply")
    p.add_argument("--cameras", required=True,
                   help="cameras.json, transforms.json, a COLMAP model folder or WorldMirror's "
                        "camera_params.json: the model's context views")
    p.add_argument("--images", required=True,
                   help="folder with the images the model saw (matched by name, else sorted)")
    p.add_argument("--out", required=True, help="bundle folder to write")
    p.add_argument("--views", help="comma-separated camera indices or image names of the "
                                   "context views, in the model's order (default: all)")
    p.add_argument("--trim", type=int, help="border cells the export dropped per side "
                                            "(default: the format's, e.g. 8 for depthsplat)")
    p.add_argument("--spp", type=int, help="Gaussians per pixel (default 1)")
    p.add_argument("--opacity-cut", type=float,
                   help="the export dropped opacities <= this (yonosplat: 0.01; 0: none)")
    p.add_argument("--order", choices=["vhws", "hwsv"],
                   help="vertex order: vhws = view slowest (model order), hwsv = view fastest")
    p.add_argument("--grid", help="per-view grid ROWSxCOLS of a latent-grid model (resplat)")
    p.add_argument("--align", choices=["auto", "none", "scale", "scale-shift"], default="auto",
                   help="fit the file-to-world scale (and shift) to the pixel rays "
                        "(auto: only for the viewer frame of pixelsplat/mvsplat)")
    p.add_argument("--no-voxels", dest="voxelized", action="store_false", default=None,
                   help="anysplat: the model ran with voxelize: false (per-pixel order); by "
                        "default its voxels' views are recovered from the images")
    p.add_argument("--half-pixel", dest="half_pixel", action="store_true", default=None,
                   help="move principal points by +0.5 px (VGGT pixel convention; anysplat's "
                        "default)")
    p.add_argument("--no-half-pixel", dest="half_pixel", action="store_false")
    p.add_argument("--allow-misaligned", action="store_true",
                   help="write the bundle even when fewer than half of the Gaussians project "
                        "near their pixel, or (recovered associations) are seen by their view "
                        "(by default such an import is refused: its association is wrong, "
                        "docs/backbones.md)")
    p.add_argument("--force", action="store_true",
                   help="replace an --out folder that an earlier clearsplat run wrote")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import ClearsplatError
    from ..io import save_scene
    from ..io.importers import MIN_NEAR_SHARE, MIN_SEEN_SHARE, import_export, load_views
    from ..io.output import check_output_folder, output_folder

    inputs = [args.ply, args.cameras, args.images]
    check_output_folder(args.out, inputs=inputs, force=args.force)
    grid = None
    if args.grid:
        try:
            grid = tuple(int(x) for x in args.grid.lower().split("x"))
        except ValueError:
            grid = ()
        if len(grid) != 2 or min(grid) < 1:
            raise ClearsplatError(f"expected ROWSxCOLS, two positive numbers, got "
                                  f"{args.grid!r}", field="--grid")
    views = [v for v in args.views.split(",") if v.strip()] if args.views else None
    cameras, images, names = load_views(args.cameras, args.images, views=views)
    scene, report = import_export(
        args.ply, args.format, cameras, images, trim=args.trim, spp=args.spp,
        opacity_cut=args.opacity_cut, order=args.order, grid=grid, align=args.align,
        voxelized=args.voxelized, half_pixel=args.half_pixel,
        allow_misaligned=args.allow_misaligned, progress=Bar())
    print(f"{args.format}: {report.summary()}")
    for note in report.notes:
        print(f"  note: {note}")
    seen = 1.0 - report.ambiguous / max(report.num_vertices, 1)
    if report.association:               # the pixel of a recovered vertex is where it projects
        if seen < MIN_SEEN_SHARE:
            warn(f"kept with --allow-misaligned: only {100 * seen:.1f} % of the Gaussians got "
                 "a view unambiguously: the association is wrong for the others")
    elif report.num_vertices and scene.is_pixel_aligned and report.near_pixel < MIN_NEAR_SHARE:
        warn(f"kept with --allow-misaligned: only {100 * report.near_pixel:.1f} % of the "
             f"Gaussians project within {report.near_px:.3g} px of their pixel: the "
             "association is wrong where they do not")
    elif report.num_vertices and scene.is_pixel_aligned and report.inside_pixel < 0.9:
        warn(f"only {100 * report.inside_pixel:.1f} % of the Gaussians project into their "
             "pixel: the cameras, their order (--views), the images' size or the format's "
             "options do not match the export")
    with output_folder(args.out, inputs=inputs, force=args.force, command="import") as tmp:
        save_scene(scene, tmp)
        with open(tmp / "import.json", "w") as f:
            json.dump(dict(report.as_dict(), images=names, source=args.ply), f, indent=1)
    print(f"wrote {args.out} ({scene.num_views} views); next: clearsplat filter {args.out} "
          "--out FILTERED")
    return 0
