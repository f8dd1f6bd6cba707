"""wire: the models shared with the client name the pipeline's timed spans, in its order;
an answer's configurations leave the garbage collector's view and go back into requests.

`service/wire.py` spells out `TimedSpan` (the keys of `timings_ms`) so that it needs no
numpy; this checks it against the pipeline's own `TIMED_SPANS`. A parsed answer's
configurations are tuples of floats, which CPython's collector stops tracking once a
collection has seen them (checked with `gc.is_tracked`, not assumed), and a configuration
taken from an answer is accepted where a request asks for one, while strings still are not.
"""

from __future__ import annotations

import gc
import json
from typing import get_args

import pytest
from pydantic import ValidationError

from service import wire
from service.pipeline.types import TIMED_SPANS

COMPONENT = {
    "id": 0,
    "size": 2,
    "representative": [0.1, 0.2, 0.3],
    "configurations": [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]],
    "joint_min": [0.1, 0.2, 0.3],
    "joint_max": [0.4, 0.5, 0.6],
    "max_position_error": 1e-9,
    "max_orientation_error": 0.0,
    "distance_to_reference": None,
    "nearest_to_reference": None,
    "arc_length_rad": 1.0,
    "closed": False,
    "ends": ["joint_limit", "joint_limit"],
    "path": [[0.1, 0.2, 0.3], [0.2, 0.3, 0.4], [0.4, 0.5, 0.6]],
    "clearance_m": None,
    "safest_configuration": None,
    "safest_clearance_m": None,
}


def test_timed_spans_are_the_pipelines() -> None:
    assert get_args(wire.TimedSpan) == TIMED_SPANS


def test_an_answers_configurations_leave_the_collectors_view_once_seen() -> None:
    component = wire.ComponentOut.model_validate_json(json.dumps(COMPONENT))
    assert component.path is not None
    vectors = [component.representative, *component.configurations, *component.path]
    assert all(isinstance(v, tuple) for v in vectors)
    gc.collect()
    assert not any(gc.is_tracked(v) for v in vectors)
    # What a list would cost: it stays tracked after the same collection.
    as_list = list(component.representative)
    gc.collect()
    assert gc.is_tracked(as_list)


def test_a_configuration_from_an_answer_goes_back_into_a_request() -> None:
    component = wire.ComponentOut.model_validate_json(json.dumps(COMPONENT))
    goal = wire.GoalIn(configuration=component.configurations[1])
    assert goal.configuration is not None and list(goal.configuration) == [0.4, 0.5, 0.6]
    request = wire.SmmRequest(
        robot="planar3r",
        task="position",
        target=wire.TargetIn(position=[0.5, 0.0]),
        reference_configuration=component.representative,
    )
    assert request.reference_configuration is not None
    assert list(request.reference_configuration) == [0.1, 0.2, 0.3]
    for refused in (("0.4", 0.5, 0.6), "0.4 0.5 0.6"):
        with pytest.raises(ValidationError, match="configuration"):
            wire.GoalIn(configuration=refused)  # type: ignore[arg-type]
