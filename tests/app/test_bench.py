"""``gsjax bench``: the table and the JSON it writes (a tiny size, both backends), and its flags' errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gsjax.app.bench import COLUMNS, bench_map
from gsjax.app.cli import main


# Both backends: the Pallas path's interpreted renders (about 15 s to compile) in the slow suite; the default one
# benches XLA alone and checks the same JSON.
@pytest.mark.parametrize("backends", ["xla", pytest.param("xla,pallas", marks=pytest.mark.slow)])
def test_bench_measures_both_backends_and_writes_the_json(tmp_path, capsys, backends):
    out = tmp_path / "bench.json"
    status = main(["bench", "--backend", backends, "--sizes", "24x16", "--k", "16", "--repeats", "1",
                   "--out", str(out)])
    printed = capsys.readouterr().out
    assert status == 0, printed
    result = json.loads(out.read_text())
    assert result["device"]["platform"] == "cpu" and result["k"] == 16
    rows = result["rows"]
    expected = [("xla", "24x16"), ("pallas (interpret)", "24x16")][: len(backends.split(","))]
    assert [(r["backend"], r["size"]) for r in rows] == expected
    for row in rows:
        assert set(COLUMNS) <= set(row)
        for key in ("compile_s", "fwd_ms", "fwd_bwd_ms", "track_iter_ms", "ns_per_px_cand", "track_peak_mib"):
            assert np.isfinite(row[key]) and row[key] > 0, (key, row)
        assert row["gaussians"] > 100
    # the same map and settings on both backends: the same candidates, the same truncation (K = 16 truncates)
    for key in ("mean_list", "gaussians", "truncated_px"):
        assert all(row[key] == rows[0][key] for row in rows), key
    assert rows[0]["truncated_px"] > 0
    assert printed.count("pallas (interpret)") == len(rows) - 1 and f"wrote {out}" in printed


def test_bench_map_holds_the_requested_number_of_gaussians():
    g, w2c, intrinsics = bench_map(40, 30, gaussians=3000)
    assert g.capacity == 3000 and int(np.sum(np.asarray(g.active))) == 3000
    assert (intrinsics.width, intrinsics.height) == (40, 30)
    default, _, _ = bench_map(40, 30)
    assert 0.8 * 40 * 30 < int(np.sum(np.asarray(default.active))) < 2 * 40 * 30  # about one per pixel


@pytest.mark.parametrize("flags, named", [
    (["--sizes", "640by480"], "--sizes"),
    (["--sizes", "4x4"], "--sizes"),
    (["--backend", "cuda"], "--backend"),
    (["--gaussians", "-5"], "--gaussians"),
    (["--repeats", "0"], "--repeats"),
])
def test_a_bad_bench_flag_is_one_line_naming_it(flags, named, tmp_path, capsys):
    assert main(["bench", "--out", str(tmp_path / "b.json")] + flags) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gsjax bench: error: argument " + named), err
    assert not (tmp_path / "b.json").exists()
