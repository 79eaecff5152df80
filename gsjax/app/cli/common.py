"""What the commands share: the one-line user error, the parser class, the common flags, argument types, and
opening and configuring a run's sequence."""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

from gsjax.config.names import BAGS, CBKNN_MODES, DATASETS, PRESETS, SYNTHETIC


class UserError(Exception):
    """An error caused by the user's input; printed without a traceback."""


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``gsjax run: error: argument --x: ...``), like every other error."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def dataset_warnings(open_fn):
    """Call ``open_fn()``; print each distinct DatasetWarning it raised as one ``warning: ...`` line on stderr (other
    warnings as Python shows them) -> (its result, the DatasetWarning messages). Distinct: ``gsjax run`` lists a
    dataset twice (once to learn its image size)."""
    from gsjax.data import DatasetWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DatasetWarning)
        result = open_fn()
    messages = []
    for item in caught:
        if issubclass(item.category, DatasetWarning):
            if str(item.message) in messages:
                continue
            messages.append(str(item.message))
            print(f"warning: {item.message}", file=sys.stderr, flush=True)
        else:
            warnings.showwarning(item.message, item.category, item.filename, item.lineno)
    return result, messages


_PYTHON_SHOWWARNING = warnings.showwarning


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` for the command line: a FutureWarning (a deprecation, ...) as one ``warning:``
    line, the rest as Python shows them."""
    if issubclass(category, FutureWarning):
        print(f"warning: {message}", file=sys.stderr, flush=True)
    else:
        _PYTHON_SHOWWARNING(message, category, filename, lineno, file, line)


# Options every subcommand takes.
COMMON = argparse.ArgumentParser(add_help=False)
COMMON.add_argument("--debug", action="store_true", help="show the full traceback of an error")




def port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port number 0-65535, got {text!r}")
    return value


def add_sequence_flags(p) -> None:
    """The flags that choose the sequence, its camera and the config (shared by run, sweep and landscape)."""
    p.add_argument("--dataset", choices=DATASETS + BAGS + (SYNTHETIC,), required=True)
    p.add_argument("--path", type=Path, default=None,
                   help="dataset directory; for rosbag a ROS 1 .bag file or a ROS 2 bag folder, for realsense the "
                        "SDK's .db3 or .bag recording (not for synthetic)")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--preset", choices=PRESETS, default="cpu", help="configuration preset (default cpu)")
    p.add_argument("--cbknn", choices=CBKNN_MODES, default="off", help="CB-KNN mode (default off = SplaTAM)")
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--stride", type=int, default=1, help="use every N-th frame (faster motion)")
    p.add_argument("--downscale", type=int, default=None,
                   help="integer image reduction (default: to about 80 px wide for the cpu preset, else 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--intrinsics", type=pinhole, default=None, metavar="FX,FY,CX,CY",
                   help="the camera in pixels at the stored image size, overriding the dataset's own")
    p.add_argument("--depth-scale", type=depth_scale, default=None, metavar="S",
                   help="stored depth units per metre, overriding the dataset's (TUM 5000, 7-Scenes 1000)")
    p.add_argument("--synthetic-noise", action="store_true",
                   help="synthetic dataset only: Kinect-like sensor effects (depth noise, holes, colour noise, blur)")
    add_bag_flags(p)


def add_bag_flags(p) -> None:
    """The flags of a ROS bag (``--dataset rosbag``): its topics, the pairing tolerance, the ground truth."""
    bag = p.add_argument_group("ROS bags and RealSense recordings (--dataset rosbag, realsense)")
    bag.add_argument("--rgb-topic", default=None, help="colour topic (default: the bag's one colour image topic)")
    bag.add_argument("--depth-topic", default=None, help="depth topic (default: the bag's one depth image topic)")
    bag.add_argument("--camera-info-topic", default=None,
                     help="sensor_msgs/CameraInfo topic (default: the bag's one, or the one beside the depth topic)")
    bag.add_argument("--max-time-diff", type=seconds, default=0.02, metavar="S",
                     help="largest colour-depth (and frame-ground truth) stamp difference paired, s (default 0.02)")
    bag.add_argument("--groundtruth", type=Path, default=None, metavar="FILE",
                     help="ground truth as a TUM trajectory file (camera-to-world)")
    bag.add_argument("--gt-frames", type=frame_pair, default=None, metavar="PARENT,CHILD",
                     help="ground truth from the bag's /tf: the transform PARENT -> CHILD is the camera-to-world pose")


def seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number of seconds >= 0, got {text!r}")
    return value


def frame_pair(text: str) -> tuple[str, str]:
    parts = [part.strip() for part in text.split(",")]
    if len(parts) != 2 or not all(parts):
        raise argparse.ArgumentTypeError(f"expected two frame names PARENT,CHILD (e.g. world,camera), got {text!r}")
    return parts[0], parts[1]


def bag_options(args):
    """The :class:`gsjax.data.rosbag.BagOptions` of the command line; UserError for bag flags given for another
    dataset."""
    from gsjax.data import BagOptions

    given = {flag: value for flag, value in (("--rgb-topic", args.rgb_topic), ("--depth-topic", args.depth_topic),
                                             ("--camera-info-topic", args.camera_info_topic),
                                             ("--groundtruth", args.groundtruth), ("--gt-frames", args.gt_frames))
             if value is not None}
    if args.dataset not in BAGS:
        if given or args.max_time_diff != 0.02:
            flag = next(iter(given), "--max-time-diff")
            raise UserError(f"{flag} applies to --dataset {' or '.join(BAGS)} only")
        return None
    if args.groundtruth is not None and args.gt_frames is not None:
        raise UserError("give the ground truth with --groundtruth FILE or --gt-frames PARENT,CHILD, not both")
    topics = [flag for flag in ("--rgb-topic", "--depth-topic", "--camera-info-topic") if flag in given]
    if args.dataset == "realsense" and topics:
        raise UserError(f"{topics[0]} applies to --dataset rosbag; a RealSense recording's streams are found by "
                        "the SDK's own topic names")
    return BagOptions(args.rgb_topic, args.depth_topic, args.camera_info_topic, args.max_time_diff, args.groundtruth,
                      args.gt_frames)


def pinhole(text: str) -> tuple[float, float, float, float]:
    """``FX,FY,CX,CY`` -> four floats (fx, fy > 0); argparse reports the error naming --intrinsics."""
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4 or not all(map(math.isfinite, values)):
        raise argparse.ArgumentTypeError(f"expected FX,FY,CX,CY: four numbers in pixels, got {text!r}")
    if values[0] <= 0 or values[1] <= 0:
        raise argparse.ArgumentTypeError(f"the focal lengths FX and FY must be > 0, got {text!r}")
    return values


def depth_scale(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a number > 0 (stored depth units per metre), got {text!r}")
    return value


def parse_overrides(tokens: list[str]) -> dict[str, str]:
    """``--a.b value`` / ``--a.b=value`` pairs -> {"a.b": "value"}."""
    overrides, i = {}, 0
    while i < len(tokens):
        token = tokens[i]
        if not token.startswith("--") or "." not in token:
            raise UserError(f"unrecognised argument {token!r} (config overrides look like --tracking.iters 60)")
        if "=" in token:
            name, value = token[2:].split("=", 1)
            i += 1
        else:
            if i + 1 >= len(tokens):
                raise UserError(f"{token} needs a value")
            name, value = token[2:], tokens[i + 1]
            i += 2
        overrides[name] = value
    return overrides


def open_run_sequence(args):
    """The sequence to run on, with the downscale the preset implies."""
    from gsjax.slam.presets import working_downscale

    if args.stride < 1 or (args.max_frames is not None and args.max_frames < 1):
        raise UserError("--stride and --max-frames must be >= 1")
    if args.downscale is not None and args.downscale < 1:
        raise UserError(f"--downscale must be >= 1, got {args.downscale}")
    from gsjax.data import open_sequence

    bag = bag_options(args)
    if args.dataset == SYNTHETIC:
        for flag, value in (("--intrinsics", args.intrinsics), ("--depth-scale", args.depth_scale)):
            if value is not None:
                raise UserError(f"{flag} applies to datasets read from disk; the synthetic scene has its own camera")
        source = dict(sensor_noise=args.synthetic_noise, seed=args.seed)
    else:
        if args.synthetic_noise:
            raise UserError("--synthetic-noise applies to --dataset synthetic only")
        what = "FILE_OR_DIR" if args.dataset in BAGS else "DIR"
        if args.path is None:
            raise UserError(f"--dataset {args.dataset} needs --path {what}")
        if args.dataset in BAGS and not args.path.exists():
            raise UserError(f"--path {args.path}: no such bag file or folder")
        if args.dataset not in BAGS and not args.path.is_dir():
            raise UserError(f"--path {args.path}: no such directory")
        source = dict(path=args.path, intrinsics=args.intrinsics, depth_scale=args.depth_scale)
        if bag is not None:
            source["bag"] = bag
    native = open_sequence(args.dataset, max_frames=1, **source).intrinsics
    if args.intrinsics is not None and not (0 <= args.intrinsics[2] <= native.width
                                            and 0 <= args.intrinsics[3] <= native.height):
        raise UserError(f"--intrinsics: the principal point ({args.intrinsics[2]:g}, {args.intrinsics[3]:g}) lies "
                        f"outside the {native.width}x{native.height} images; give the values in pixels at the stored "
                        "image size")
    factor = args.downscale or working_downscale(args.preset, native.width)
    if args.dataset == SYNTHETIC and (native.width % factor or native.height % factor):
        raise UserError(f"--downscale {factor} must divide the synthetic {native.width}x{native.height} image")
    if factor > min(native.width, native.height):
        raise UserError(f"--downscale {factor} leaves no pixel of the {native.width}x{native.height} images")
    sequence = open_sequence(args.dataset, max_frames=args.max_frames, stride=args.stride, downscale=factor,
                             **source)
    return sequence, factor


def configure(args, width: int | None = None):
    """The preset at the working ``width`` with the CB-KNN mode, then the command line's overrides as given."""
    from gsjax.config.text import apply_overrides
    from gsjax.slam.presets import preset, with_cbknn_mode

    return apply_overrides(with_cbknn_mode(preset(args.preset, width), args.cbknn), args.overrides)


def describe_run(args, sequence, factor: int) -> dict:
    """What a run, sweep or landscape records about its input (config.json, metrics.json, sweep.json, ...)."""
    return dict(dataset=args.dataset, path=str(args.path) if args.path else None, preset=args.preset,
                cbknn=args.cbknn, downscale=factor, stride=args.stride, overrides=args.overrides,
                intrinsics=list(args.intrinsics) if args.intrinsics else None, depth_scale=args.depth_scale,
                sequence=sequence.name, **_bag_record(args))


def _bag_record(args) -> dict:
    """A bag's reading options as config.json records them (only for a bag: other runs' files stay as they were)."""
    if args.dataset not in BAGS:
        return {}
    return dict(bag=dict(rgb_topic=args.rgb_topic, depth_topic=args.depth_topic,
                         camera_info_topic=args.camera_info_topic, max_time_diff=args.max_time_diff,
                         groundtruth=str(args.groundtruth) if args.groundtruth else None,
                         gt_frames=list(args.gt_frames) if args.gt_frames else None))


def backends(text: str) -> list[str]:
    names = [x.strip() for x in text.split(",") if x.strip()]
    bad = [x for x in names if x not in ("xla", "pallas")]
    if not names or bad:
        raise argparse.ArgumentTypeError(f"{text!r}: a comma-separated list of xla, pallas")
    return names


def sizes(text: str) -> list[tuple[int, int]]:
    from gsjax.app.bench import parse_size

    try:
        return [parse_size(x.strip()) for x in text.split(",") if x.strip()]
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err).removeprefix("--sizes: ")) from None


def positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a positive integer")
    return value


def quiet_logs() -> None:
    import logging

    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    logging.getLogger("gsjax").setLevel(logging.INFO)
    for noisy in ("absl", "orbax", "jax"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
