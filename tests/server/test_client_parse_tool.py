"""The client's parse (`python -m tools.client_parse`): the list-typed twin of the wire
models reads the same answers to the same values (so the two parses measure the same
content), and a run reports a finite CPU per answer for each parser, the collector on and
off, on real answers of a bundled model."""

from __future__ import annotations

import math

from service.manifest import REPO_MODELS_DIR
from service.models.registry import load_model
from service.wire import SmmResponse
from tools import client_parse


def test_the_list_twin_reads_the_same_values_and_a_run_reports_each_parse() -> None:
    model = load_model(REPO_MODELS_DIR / "planar3r-position", threads=1)
    bodies = client_parse.answers_of(model, targets=2)
    for body in bodies:
        as_tuples = SmmResponse.model_validate_json(body)
        as_lists = client_parse.ListSmmResponse.model_validate_json(body)
        assert as_tuples.components, "a held-out target has components"
        path = as_lists.components[0].path
        assert path is not None and isinstance(path[0], list)
        assert as_lists.model_dump(mode="json") == as_tuples.model_dump(mode="json")
    figures = client_parse.measure(bodies, repeats=1)
    assert figures["answers"] == 2
    for name in client_parse.PARSERS:
        for collector in ("collector_on", "collector_off"):
            ms = figures[f"{name}_{collector}_ms"]
            assert math.isfinite(ms) and ms >= 0.0
