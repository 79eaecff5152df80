"""``gsjax landscape``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

from gsjax.app.cli import common


def add(sub) -> None:
    p = sub.add_parser(
        "landscape",
        help="frame T's tracking loss and its jax.grad along pose perturbations, CB-KNN off vs paper, with basins",
        description="Build the map from frames 0..T-1 (SLAM, or --map-from gt), then evaluate frame T's tracking "
        "loss (exactly the tracker's) under left perturbations of the reference pose (frame T's ground truth, else "
        "its tracked pose) along each axis (tx ty tz in cm, rx ry rz in degrees), with jax.grad at every grid point, "
        "for CB-KNN off and paper (--modes); and the basins: how far off the tracker still returns to within 0.5 cm / "
        "0.5 deg of the reference (basin) and of its own fixed point, where it ends when started at the reference "
        "(basin_fixed). --grid2d: also over the plane of the two --axes, steps x steps points (steps^2 tracker runs "
        "per mode). Writes landscape.json and landscape.png (and landscape2d.png).",
        parents=[common.COMMON],
    )
    common.add_sequence_flags(p)
    p.add_argument("--frame", type=int, required=True, help="the frame T whose tracking loss is studied (>= 1)")
    p.add_argument("--axes", default="tx,ry", help="comma-separated axes among tx,ty,tz,rx,ry,rz (default tx,ry)")
    p.add_argument("--extent-cm", type=float, default=4.0, help="translation grid half-width (cm, default 4)")
    p.add_argument("--extent-deg", type=float, default=4.0, help="rotation grid half-width (degrees, default 4)")
    p.add_argument("--steps", type=int, default=21, help="grid points per axis (default 21)")
    p.add_argument("--map-from", choices=("slam", "gt"), default="slam",
                   help="build the map by SLAM (default) or at the ground-truth poses")
    p.add_argument("--modes", default="off,paper",
                   help="comma-separated tracking modes to compare, among off, paper (CB-KNN), blur (image-space "
                        "smoothing, 1.5 px) and pyramid (coarse to fine, 2 blur levels) (default off,paper)")
    p.add_argument("--grid2d", action="store_true",
                   help="also the 2-D grid over the two --axes: steps^2 tracker runs per mode; landscape2d.png")
    p.add_argument("--batch", type=int, default=None,
                   help="tracker runs vmapped at a time (memory; default 1 on a CPU, where one at a time is "
                        "faster, 64 elsewhere)")
    p.add_argument("--overwrite", action="store_true", help="replace a previous landscape in --out")
    p.add_argument("--chunk", type=int, default=8, help="frames per jitted scan chunk while mapping (default 8)")
    p.set_defaults(func=run, accepts_overrides=True)


def run(args) -> int:
    from gsjax.app.landscape import LandscapeOptions, run_landscape
    from gsjax.app.run_folder.layout import check_run_dir
    from gsjax.io.run_folder import LANDSCAPE_FILES

    common.quiet_logs()
    common.configure(args)  # bad overrides are reported before any data is read
    options = LandscapeOptions(out=args.out, frame=args.frame, axes=tuple(a.strip() for a in args.axes.split(",")),
                               extent_cm=args.extent_cm, extent_deg=args.extent_deg, steps=args.steps,
                               map_from=args.map_from, seed=args.seed, chunk=args.chunk, overwrite=args.overwrite,
                               modes=tuple(m.strip() for m in args.modes.split(",")), grid2d=args.grid2d,
                               batch=args.batch)
    check_run_dir(args.out, overwrite=args.overwrite, outputs=LANDSCAPE_FILES)
    if args.max_frames is None:
        args.max_frames = args.frame + 1  # frames past T are not read
    (sequence, factor), _ = common.dataset_warnings(lambda: common.open_run_sequence(args))
    describe = common.describe_run(args, sequence, factor)
    document = run_landscape(sequence, common.configure(args, sequence.intrinsics.width), options, describe=describe)
    for axis, entry in document["axes"].items():
        print(f"{axis}: basin " + ", ".join(f"{mode} {entry[mode]['basin']:g} {entry['unit']} (to its fixed point "
                                            f"{entry[mode]['basin_fixed']:g})" for mode in options.modes))
    if options.grid2d:
        plane = document["grid2d"]
        print(f"{' x '.join(plane['axes'])}: basin radius " + ", ".join(
            f"{mode} {plane[mode]['basin']:.2f} (to its fixed point {plane[mode]['basin_fixed']:.2f})"
            for mode in options.modes) + " of the extent")
    print(f"outputs in {args.out.resolve()}: landscape.json landscape.png" + " landscape2d.png" * options.grid2d)
    return 0
