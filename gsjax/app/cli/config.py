"""``gsjax config``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from gsjax.app.cli import common
from gsjax.config.names import CBKNN_MODES, PRESETS


def add(sub) -> None:
    p = sub.add_parser(
        "config", parents=[common.COMMON],
        help="show a preset's config as config.json stores it (with --NAME VALUE overrides), or write the reference",
        description="Print the config a run would use: PRESET at --width px with the CB-KNN mode and the overrides "
        "(--tracking.iters 60 ...), as JSON, checked as gsjax run checks it. --reference writes the table of every "
        "field (unit, static or traced, bounds, default per preset, meaning) instead.")
    p.add_argument("--preset", choices=PRESETS, default="cpu", help="named preset (default cpu)")
    p.add_argument("--width", type=common.positive, default=None,
                   help="working image width (px) its pixel-sized fields scale to (default: the preset's own)")
    p.add_argument("--cbknn", choices=CBKNN_MODES, default="off", help="CB-KNN mode (default off)")
    p.add_argument("--reference", type=Path, metavar="FILE", default=None,
                   help="write the config reference (Markdown) to FILE ('-': standard output)")
    p.set_defaults(func=run, accepts_overrides=True)


def run(args) -> int:
    if args.reference is not None:
        if args.overrides:
            raise common.UserError("--reference documents every field; it takes no --NAME VALUE overrides")
        from gsjax.app.config_reference import config_reference
        from gsjax.io.atomic import atomic_write_text

        text = config_reference()
        if str(args.reference) == "-":
            sys.stdout.write(text)
        else:
            atomic_write_text(args.reference, text)
            print(f"wrote the config reference to {args.reference}")
        return 0
    from gsjax.config.text import config_to_dict

    print(json.dumps(config_to_dict(common.configure(args, args.width)), indent=2))
    return 0
