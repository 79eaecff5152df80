"""The tracking table's rewrite of the site's accuracy page (experiments/tracking_table.py ``--update-docs``): it finds
the table under its heading on the real page and replaces only that table; no SLAM runs."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))
import tracking_table

REAL_UPDATE_DOCS = tracking_table.update_docs
NEW = "| sequence | frames |\n|---|---|\n| marker | 1 |\n"


def _table_under_heading(text: str) -> str:
    """The first table of the section under tracking_table.SECTION, as the page holds it."""
    section = text[text.index(tracking_table.SECTION):]
    lines = section.splitlines(keepends=True)
    first = next(i for i, line in enumerate(lines) if line.startswith("|"))
    table = []
    for line in lines[first:]:
        if not line.startswith("|"):
            break
        table.append(line)
    return "".join(table)


def test_the_accuracy_page_holds_the_table_under_its_heading():
    text = tracking_table.DOCS_PAGE.read_text()
    table = _table_under_heading(text)
    assert table.startswith("| sequence | frames | ATE RMSE off / paper |")
    # what markdown() writes has the same columns
    header = tracking_table.markdown({}).splitlines()[0]
    assert table.splitlines()[0] == header
    # putting the page's own table back changes nothing; another table replaces exactly that one
    assert tracking_table.replace_table(text, table) == text
    replaced = tracking_table.replace_table(text, NEW)
    assert replaced == text.replace(table, NEW, 1)
    assert replaced.count("| marker | 1 |") == 1


def test_replace_table_stays_in_its_section():
    text = "# Page\n\n| other | table |\n|---|---|\n\n## Measured tracking (cpu)\n\nSome words.\n\n" \
           "| a | b |\n|---|---|\n| 1 | 2 |\n\nMore.\n\n| second | table |\n|---|---|\n\n## Next\n"
    out = tracking_table.replace_table(text, NEW)
    assert "| other | table |" in out and "| second | table |" in out and "| 1 | 2 |" not in out
    assert out.index("| marker | 1 |") > out.index("Some words.")
    with pytest.raises(ValueError, match="no table"):
        tracking_table.replace_table("## Measured tracking\n\nwords\n\n## Next\n\n| a |\n", NEW)
    with pytest.raises(ValueError, match="no heading"):
        tracking_table.replace_table("## Other\n\n| a |\n", NEW)


@pytest.mark.parametrize("flag", ["--update-docs", "--update-readme"])
def test_both_flags_rewrite_the_page(flag, tmp_path, monkeypatch):
    page = tmp_path / "accuracy.md"
    page.write_text(tracking_table.DOCS_PAGE.read_text())
    fake = dict(ate_cm=0.123, constant_cm=4.56, psnr_db=30.0, s_per_frame=1.0, retried=0, diverged=0)
    monkeypatch.setattr(tracking_table, "run_row", lambda row, mode, work: None)
    monkeypatch.setattr(tracking_table, "summary", lambda metrics: fake)
    monkeypatch.setattr(tracking_table, "RESULTS", tmp_path / "results")
    monkeypatch.setattr(tracking_table, "update_docs", lambda table: REAL_UPDATE_DOCS(table, page))
    assert tracking_table.main(["--work", str(tmp_path / "work"), "--rows", "synthetic", flag]) == 0
    table = _table_under_heading(page.read_text())
    assert "| synthetic (`make demo`) | 30 | 0.12 / 0.12 cm | 4.56 cm | 30.0 / 30.0 dB | 1.0 / 1.0 |" in table
    assert len(table.splitlines()) == 3  # header, rule, the one row run
