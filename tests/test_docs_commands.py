"""Every ``gsjax`` command line written in the README and the docs parses as the command line parses it: its
command and flags exist, and its config overrides and ``--grid`` axes name fields that exist, under their current
names, with values they accept. The synopses (with ``[optional]`` parts or ``a|b`` choices) are left out; they are
``--help``'s job. Nothing runs."""

from __future__ import annotations

import argparse
import re
import shlex
import warnings
from pathlib import Path

import pytest

from gsjax.app.cli import build_parser
from gsjax.app.cli.common import parse_overrides
from gsjax.config.text import apply_overrides
from gsjax.slam.presets import preset

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
_BLOCK = re.compile(r"```(?:bash|sh|shell)\n(.*?)```", re.DOTALL)


def gsjax_argv(tokens: list[str]) -> list[str] | None:
    """The arguments after ``gsjax`` when ``tokens`` (one shell command) runs gsjax, else None."""
    while tokens and re.fullmatch(r"[A-Z_]+=\S*", tokens[0]):  # VAR=value before the command
        tokens = tokens[1:]
    if tokens[:1] and tokens[0].endswith("python") and tokens[1:3] == ["-m", "gsjax"]:
        tokens = tokens[2:]
    if tokens[:1] and (tokens[0] == "gsjax" or tokens[0].endswith("bin/gsjax")) and "--help" not in tokens:
        return tokens[1:]
    return None


def command_lines() -> list[tuple[str, list[str]]]:
    """(where, argv after ``gsjax``) of every gsjax command in the pages' shell blocks."""
    found = []
    for page in PAGES:
        for block in _BLOCK.findall(page.read_text(encoding="utf-8")):
            for line in block.replace("\\\n", " ").splitlines():
                if "[" in line or "|" in line:
                    continue
                tokens = shlex.split(line, comments=True)
                segments = [[]]
                for token in tokens:  # `cd /tmp && gsjax ...`: each command of the line
                    if token in ("&&", ";", "&"):
                        segments.append([])
                    else:
                        segments[-1].append(token)
                for segment in segments:
                    argv = gsjax_argv(segment)
                    if argv is not None:
                        found.append((f"{page.relative_to(ROOT)}: gsjax {' '.join(argv)}", argv))
    return found


COMMANDS = command_lines()


def test_the_pages_hold_commands_of_every_kind():
    kinds = {argv[0] for _, argv in COMMANDS}
    assert {"run", "sweep", "tune", "landscape", "report", "view", "synth", "eval", "config"} <= kinds, kinds


@pytest.mark.parametrize("where, argv", COMMANDS, ids=[where for where, _ in COMMANDS])
def test_a_documented_command_parses(where, argv):
    try:
        args, extra = build_parser().parse_known_args(argv)
    except (SystemExit, argparse.ArgumentError) as error:
        pytest.fail(f"{where}: the command line does not parse ({error})")
    assert not extra or getattr(args, "accepts_overrides", False), f"{where}: unknown arguments {extra}"
    config = preset(getattr(args, "preset", None) or "cpu")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a field under its old name is a FutureWarning: the docs use today's
        apply_overrides(config, parse_overrides(extra))
        for axis in getattr(args, "grid", None) or []:
            name, _, values = axis.partition("=")
            for value in values.split(","):
                apply_overrides(config, {name: value})
