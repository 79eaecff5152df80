"""The tutorials (docs/tutorials/*.py, Jupytext percent scripts) run at a tiny size (GSJAX_TUTORIAL_TINY), so a
change to the API they use fails here, not only when the site is built (where they run at full size)."""

from __future__ import annotations

import runpy
from pathlib import Path

import matplotlib
import pytest

TUTORIALS = sorted((Path(__file__).resolve().parents[1] / "docs" / "tutorials").glob("*.py"))


def test_every_tutorial_is_in_the_site():
    nav = (Path(__file__).resolve().parents[1] / "mkdocs.yml").read_text()
    assert TUTORIALS and all(f"tutorials/{path.name}" in nav for path in TUTORIALS)


@pytest.mark.parametrize("path", TUTORIALS, ids=lambda p: p.stem)
def test_a_tutorial_runs_at_a_tiny_size(path, monkeypatch, capsys):
    monkeypatch.setenv("GSJAX_TUTORIAL_TINY", "1")
    # slam.run as written, through the program `gsjax run` exports for the same config (the suite's tiny one): the
    # same bits as the direct call (tests/app/test_programs.py), without compiling it a second time.
    from gsjax import slam
    from gsjax.app.runtime.cache import exported_call
    from gsjax.slam import driver

    direct = driver.run
    monkeypatch.setattr(slam, "run", lambda *args, call=None, **kwargs: direct(*args, call=call or exported_call(),
                                                                              **kwargs))
    matplotlib.use("Agg")  # plt.show() draws nothing
    import matplotlib.pyplot as plt

    try:
        runpy.run_path(str(path), run_name="__main__")
        assert plt.get_fignums()  # each tutorial shows at least one figure
    finally:
        plt.close("all")
    capsys.readouterr()
