"""The slow suite's accuracy guard (``make test-slow``): end-to-end ATE of ``gsjax run --preset cpu`` on the
synthetic scene (clean and noisy), the 7-Scenes sample (40 and 150 frames) and the Replica sample, CB-KNN off and
paper, each under a bound a little above today's value (the rows and bounds are ``experiments/tracking_table.py``'s,
which also regenerates the site's tracking table, docs/findings/accuracy.md, from these runs: set
``GSJAX_SLOW_WORK=DIR`` here and pass ``--work DIR --update-docs`` there)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))
import tracking_table

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return Path(os.environ["GSJAX_SLOW_WORK"]) if os.environ.get("GSJAX_SLOW_WORK") else tmp_path_factory.mktemp("slow")


@pytest.mark.parametrize("mode", tracking_table.MODES)
@pytest.mark.parametrize("row", tracking_table.ROWS, ids=[r.name for r in tracking_table.ROWS])
def test_tracking_stays_within_its_ate_bound(row, mode, work):
    if not tracking_table.available(row):
        pytest.skip(f"{row.needs} is not in the shared data")
    metrics = tracking_table.run_row(row, mode, work)
    assert metrics.frames == row.frames
    ate = metrics.trajectory.ate_rmse_c2w_cm
    bound = tracking_table.BOUNDS_CM[(row.name, mode)]
    assert np.isfinite(ate) and ate <= bound, f"{row.name} {mode}: ATE {ate:.3f} cm > bound {bound} cm"
    assert ate < 0.5 * metrics.constant_pose_ate_rmse_c2w_cm  # tracking, not standing still
    assert metrics.nonfinite_gaussians == 0 and not metrics.diverged_frames
