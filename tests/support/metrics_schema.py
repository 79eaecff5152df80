"""Check a run's ``metrics.json`` against the JSON Schema generated from :class:`RunMetrics`."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import jsonschema

from gsjax.app.metrics_reference import metrics_schema


@functools.cache
def _validator() -> jsonschema.Draft202012Validator:
    schema = metrics_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def assert_valid_metrics(path: str | Path) -> dict:
    """The ``metrics.json`` at ``path`` as a dict; fails listing every place it departs from the schema."""
    value = json.loads(Path(path).read_text(encoding="utf-8"))
    errors = [f"{'/'.join(map(str, e.absolute_path)) or '(top)'}: {e.message}" for e in _validator().iter_errors(value)]
    assert not errors, f"{path} does not follow metrics.schema.json:\n" + "\n".join(errors)
    return value
