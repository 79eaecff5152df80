"""``gsjax synth``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

from pathlib import Path

from gsjax.app.cli import common

FORMATS = ("tum", "rosbag", "realsense")


def add(sub) -> None:
    p = sub.add_parser("synth", help="render a synthetic RGB-D sequence and write it in the TUM RGB-D layout or as a "
                       "ROS bag", parents=[common.COMMON])
    p.add_argument("--out", type=Path, required=True, help="output directory (must not exist or be empty)")
    p.add_argument("--frames", type=int, default=60, help="number of frames (default 60)")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--noise", action="store_true", help="add Kinect-like sensor noise, holes and blur")
    p.add_argument("--format", choices=FORMATS, default="tum",
                   help="tum: the TUM RGB-D folder layout (default); rosbag: OUT/synthetic.bag (ROS 1) or the ROS 2 "
                        "bag folder OUT/synthetic, with the ground truth on /tf and in OUT/groundtruth.txt; realsense: "
                        "OUT/synthetic.db3 recorded by the RealSense SDK (needs pyrealsense2; recorded in real time) "
                        "and OUT/groundtruth.txt at its frames' stamps")
    bag = p.add_argument_group("--format rosbag")
    bag.add_argument("--ros", type=int, choices=(1, 2), default=1, help="ROS 1 .bag or ROS 2 bag folder (default 1)")
    bag.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3",
                     help="ROS 2 storage (default sqlite3)")
    bag.add_argument("--compressed", action="store_true",
                     help="PNG CompressedImage colour and compressedDepth depth instead of raw rgb8 / 16UC1")
    bag.add_argument("--depth-scale", type=common.depth_scale, default=1000.0, metavar="S",
                     help="16UC1 depth units per metre (default 1000: millimetres, ROS's convention)")
    p.set_defaults(func=run)


def run(args) -> int:
    from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence

    if args.frames < 1:
        raise common.UserError(f"--frames must be >= 1, got {args.frames}")
    if args.out.exists() and (not args.out.is_dir() or any(args.out.iterdir())):
        raise common.UserError(f"--out {args.out} already exists and is not an empty directory; refusing to overwrite")
    if args.format != "rosbag" and (args.ros != 1 or args.storage != "sqlite3" or args.compressed
                                 or args.depth_scale != 1000.0):
        raise common.UserError("--ros, --storage, --compressed and --depth-scale apply to --format rosbag only")
    if args.format == "rosbag" and args.ros == 1 and args.storage != "sqlite3":
        raise common.UserError("--storage chooses a ROS 2 bag's storage; a ROS 1 bag is one .bag file (--ros 2)")
    config = SyntheticConfig(num_frames=args.frames, seed=args.seed)
    if args.noise:
        config = config.with_sensor_noise()
    sequence = synthetic_sequence(config)
    if args.format == "tum":
        from gsjax.data.tum import write_tum

        write_tum(sequence, args.out)
        print(f"wrote {args.frames} frames ({config.width}x{config.height}) in the TUM layout to {args.out}")
        return 0
    from gsjax.data.bag_write import write_rosbag
    from gsjax.io.trajectory import write_tum_trajectory

    args.out.mkdir(parents=True, exist_ok=True)
    if args.format == "realsense":
        from gsjax.data.realsense_write import write_realsense

        try:
            stamps = write_realsense(sequence, args.out / "synthetic.db3")
        except ImportError as error:
            raise common.UserError(str(error)) from None
        _, c2w, valid = sequence.gt_trajectory()
        write_tum_trajectory(args.out / "groundtruth.txt", stamps[valid], c2w[valid])
        print(f"wrote {args.frames} frames ({config.width}x{config.height}) as a RealSense recording to "
              f"{args.out / 'synthetic.db3'} (run it with --dataset realsense --path {args.out / 'synthetic.db3'} "
              f"--groundtruth {args.out / 'groundtruth.txt'})")
        return 0
    bag = write_rosbag(sequence, args.out / ("synthetic.bag" if args.ros == 1 else "synthetic"), ros=args.ros,
                       storage=args.storage, compressed=args.compressed, depth_scale=args.depth_scale)
    times, c2w, valid = sequence.gt_trajectory()
    write_tum_trajectory(args.out / "groundtruth.txt", times[valid], c2w[valid])
    print(f"wrote {args.frames} frames ({config.width}x{config.height}) as a ROS {args.ros} bag to {bag} (run it with "
          f"--dataset rosbag --path {bag} --gt-frames world,camera, or --groundtruth {args.out / 'groundtruth.txt'})")
    return 0
