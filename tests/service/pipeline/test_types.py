"""types: Query.for_model checks a request against its model once and fills the model's
defaults; StageTimings reports every stage in pipeline order, then the total; chain_of
tells a serial chain the compiled kernels evaluate as the Protocol does."""

from __future__ import annotations

import numpy as np
import pytest

from service.errors import RequestFieldError
from service.manifest import CHAIN_FILE, KINEMATICS_FILE, MANIFEST_FILE, REPO_MODELS_DIR, Manifest
from service.models.chain import SerialChainKinematics
from service.models.sessions import OnnxKinematics, open_session
from service.pipeline.types import (
    STAGES,
    TIMED_SPANS,
    ChainKinematics,
    Query,
    StageTimings,
    chain_of,
)


def manifest_of(model_id: str) -> Manifest:
    return Manifest.model_validate_json((REPO_MODELS_DIR / model_id / MANIFEST_FILE).read_text())


PLANAR = manifest_of("planar3r-position")
POSE = manifest_of("iiwa14-pose")


def test_every_option_left_out_takes_the_model_default() -> None:
    query = Query.for_model(PLANAR, position_m=[0.5, 0.0])
    defaults = PLANAR.defaults
    assert query.position_m == [0.5, 0.0] and query.orientation_wxyz is None
    assert query.num_samples == defaults.num_samples
    assert query.tolerance_position_m == defaults.tolerance_position_m
    assert query.tolerance_orientation_rad == defaults.tolerance_orientation_rad
    assert query.seed == 0
    assert query.reference_rad is None and query.max_configurations_per_component is None


def test_given_options_are_kept_and_the_reference_becomes_an_array() -> None:
    query = Query.for_model(
        POSE,
        position_m=(0.4, 0.1, 0.6),
        orientation_wxyz=(0.0, 1.0, 0.0, 0.0),
        num_samples=17,
        seed=9,
        tolerance_position_m=1e-4,
        tolerance_orientation_rad=2e-4,
        reference_rad=[0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0],
        max_configurations_per_component=3,
    )
    assert (query.num_samples, query.seed) == (17, 9)
    assert (query.tolerance_position_m, query.tolerance_orientation_rad) == (1e-4, 2e-4)
    assert query.max_configurations_per_component == 3
    assert query.reference_rad is not None and query.reference_rad.dtype == np.float64
    np.testing.assert_array_equal(query.reference_rad, [0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])


@pytest.mark.parametrize(
    ("manifest", "options", "location", "message"),
    [
        (
            PLANAR,
            {"position_m": [0.5, 0.0, 0.1]},
            ("body", "target", "position"),
            "target.position must have 2 values (x, y) for the position task of this robot, got 3",
        ),
        (
            PLANAR,
            {"position_m": [0.5, 0.0], "orientation_wxyz": (1.0, 0.0, 0.0, 0.0)},
            ("body", "target", "orientation"),
            "target.orientation is not allowed for the position task",
        ),
        (
            POSE,
            {"position_m": [0.4, 0.1, 0.6]},
            ("body", "target", "orientation"),
            "target.orientation (a unit quaternion {w, x, y, z}) is required for the pose task",
        ),
        (
            PLANAR,
            {"position_m": [0.5, 0.0], "tolerance_orientation_rad": 0.01},
            ("body", "tolerance", "orientation"),
            "tolerance.orientation applies only to the pose and axis tasks",
        ),
        (
            PLANAR,
            {"position_m": [0.5, 0.0], "reference_rad": [0.0, 0.0]},
            ("body", "reference_configuration"),
            "reference_configuration must have 3 values (one per joint), got 2",
        ),
    ],
)
def test_a_request_the_model_cannot_take_names_its_field(
    manifest: Manifest, options: dict[str, object], location: tuple[str, ...], message: str
) -> None:
    with pytest.raises(RequestFieldError) as error:
        Query.for_model(manifest, **options)  # type: ignore[arg-type]
    assert error.value.location == location
    assert error.value.message.startswith(message)


def test_stage_timings_list_every_stage_in_order_then_the_total() -> None:
    assert STAGES == ("encode", "sample", "correct", "accept", "connect", "summarise")
    timings = StageTimings(
        stage_ms={
            "summarise": 6.0, "connect": 5.0, "encode": 1.0, "sample": 2.0, "correct": 3.0,
            "accept": 4.0,
        },
        total_ms=22.0,
    )  # fmt: skip
    spans = timings.as_dict()
    assert tuple(spans) == TIMED_SPANS == (*STAGES, "total")
    assert list(spans.values()) == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 22.0]


def test_chain_of_tells_a_serial_chain_as_the_protocol_does() -> None:
    """`chain_of` stands in for isinstance(k, ChainKinematics): the compiled kernels take
    the served chain.json kinematics, and kinematics.onnx goes through the network."""
    model_dir = REPO_MODELS_DIR / "iiwa14-pose"
    chain = SerialChainKinematics.from_file(model_dir / CHAIN_FILE)
    onnx = OnnxKinematics(open_session(model_dir / KINEMATICS_FILE, threads=1))
    assert chain_of(chain) is chain and isinstance(chain, ChainKinematics)
    assert chain_of(onnx) is None and not isinstance(onnx, ChainKinematics)
