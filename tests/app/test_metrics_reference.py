"""The ``metrics.json`` reference (``docs/reference/metrics.md`` and ``metrics.schema.json``) is generated from
:class:`RunMetrics`; the schema accepts what runs write (tests/report, tests/app/test_finish) and rejects what they
do not."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from gsjax.app.metrics_reference import RECORDS, metrics_reference, metrics_schema
from gsjax.eval.run_metrics import RunMetrics
from tests.support.metrics_schema import _validator

DOCS = Path(__file__).resolve().parents[2] / "docs" / "reference"


def test_the_committed_reference_is_the_generated_one():
    assert (DOCS / "metrics.md").read_text(encoding="utf-8") == metrics_reference(), "run `make metrics-reference`"
    assert json.loads((DOCS / "metrics.schema.json").read_text(encoding="utf-8")) == metrics_schema(), \
        "run `make metrics-reference`"


def test_every_field_of_every_record_is_in_the_schema_and_the_page():
    schema, page = metrics_schema(), metrics_reference()
    for cls in RECORDS:
        record = schema if cls is RunMetrics else schema["$defs"][cls.__name__]
        names = [f.name for f in dataclasses.fields(cls)]
        assert list(record["properties"]) == names and record["required"] == names
        assert all(record["properties"][n]["description"] for n in names)
        assert all(f"| `{n}` |" in page for n in names)


def minimal_metrics() -> dict:
    return RunMetrics(frames=2, per_frame={name: [0.0, None] for name in metrics_schema()["properties"]["per_frame"]
                                           ["properties"]}).to_json()


@pytest.mark.parametrize("change, where", [
    (lambda m: m.update(frames="2"), "frames"),
    (lambda m: m.update(unknown=1), "(top)"),
    (lambda m: m.pop("warnings"), "(top)"),
    (lambda m: m["render"].update(frames=[0.5]), "render/frames/0"),
    (lambda m: m["per_frame"].update(gamma=["x", 0.0]), "per_frame/gamma/0"),
    (lambda m: m.update(checkpoints={"count": 1}), "checkpoints"),
])
def test_the_schema_rejects_what_a_run_does_not_write(change, where):
    metrics = minimal_metrics()
    assert not list(_validator().iter_errors(metrics))
    change(metrics)
    errors = list(_validator().iter_errors(metrics))
    assert errors and any(("/".join(map(str, e.absolute_path)) or "(top)") == where for e in errors)
