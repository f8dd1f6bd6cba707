"""The catalogue of bad inputs (docs/bad-inputs.md), as requests and the answers they must get.

Each entry: the request, the status it must get, the field its message must name and
an excerpt of what the message must say is allowed. Shared by the in-process test
(tests/service/api/test_bad_inputs.py) and the real-server one (tests/server).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from tests.support import bodies
from tests.support.bundled import served_robots_message

PLANAR = bodies.PLANAR
POSE: dict[str, Any] = {**bodies.POSE, "num_samples": 50}
JSON = {"content-type": "application/json"}
BOX: dict[str, Any] = {"shape": "box", "dimensions": [0.2, 0.2, 0.2], "position": [0.5, 0.5, 0.5]}


@dataclass(frozen=True)
class BadInput:
    id: str
    status: int
    field_name: str  # the message names this field
    allowed: str  # and says this about what is allowed
    body: dict[str, Any] | None = None
    raw: bytes | None = None  # sent as is instead of `body`
    headers: dict[str, str] = field(default_factory=lambda: dict(JSON))
    method: str = "POST"

    def content(self) -> bytes:
        return self.raw if self.raw is not None else json.dumps(self.body).encode()


def planar(**changes: Any) -> dict[str, Any]:
    return {**PLANAR, **changes}


def pose(**changes: Any) -> dict[str, Any]:
    return {**POSE, **changes}


def pose_orientation(**quaternion: Any) -> dict[str, Any]:
    return pose(target={"position": [0.5, 0.1, 0.6], "orientation": quaternion})


def raw_planar(position: str) -> bytes:
    prefix = '{"robot": "planar3r", "task": "position", "target": {"position": '
    return (prefix + position + "}}").encode()


def catalogue(max_num_samples: int, max_body_bytes: int) -> list[BadInput]:
    """Every catalogued bad input, for a server with these limits."""
    return [
        # Non-finite numbers (JSON has none, but Python's parser reads NaN, Infinity, 1e999).
        BadInput(
            "nan-position",
            422,
            "target.position[0]",
            "a finite number",
            raw=raw_planar("[NaN, 0.0]"),
        ),
        BadInput(
            "infinite-position",
            422,
            "target.position[1]",
            "a finite number",
            raw=raw_planar("[0.5, -Infinity]"),
        ),
        BadInput(
            "overflowing-number",
            422,
            "target.position[0]",
            "a finite number",
            raw=raw_planar("[1e999, 0.0]"),
        ),
        BadInput(
            "nan-quaternion",
            422,
            "target.orientation.x",
            "a finite number",
            raw=b'{"robot": "iiwa14", "task": "pose", "target": {"position": [0.5, 0.1, 0.6], '
            b'"orientation": {"w": 0.0, "x": NaN, "y": 0.0, "z": 0.0}}}',
        ),
        BadInput(
            "nan-reference",
            422,
            "reference_configuration[1]",
            "a finite number",
            raw=b'{"robot": "planar3r", "task": "position", "target": {"position": [0.5, 0.0]}, '
            b'"reference_configuration": [0.0, NaN, 0.0]}',
        ),
        # Wrong lengths.
        BadInput(
            "position-too-long",
            422,
            "target.position",
            "2 values (x, y)",
            planar(target={"position": [0.5, 0.0, 0.1]}),
        ),
        BadInput(
            "position-too-short",
            422,
            "target.position",
            "2 values (x, y)",
            planar(target={"position": [0.5]}),
        ),
        BadInput(
            "position-empty",
            422,
            "target.position",
            "a list of 1 to 3 values",
            planar(target={"position": []}),
        ),
        BadInput(
            "position-over-three",
            422,
            "target.position",
            "a list of 1 to 3 values",
            planar(target={"position": [0.1] * 4}),
        ),
        BadInput(
            "pose-position-too-short",
            422,
            "target.position",
            "3 values (x, y, z)",
            pose(target={**POSE["target"], "position": [0.5, 0.1]}),
        ),
        BadInput(
            "reference-wrong-length",
            422,
            "reference_configuration",
            "3 values (one per joint)",
            planar(reference_configuration=[0.0, 0.1]),
        ),
        # Missing and unknown fields.
        BadInput(
            "missing-target",
            422,
            "target",
            "required: position",
            {"robot": "planar3r", "task": "position"},
        ),
        BadInput(
            "missing-robot",
            422,
            "robot",
            "a string",
            {"task": "position", "target": {"position": [0.5, 0.0]}},
        ),
        BadInput(
            "missing-position", 422, "target.position", "a list of 1 to 3 values", planar(target={})
        ),
        BadInput(
            "missing-quaternion-component",
            422,
            "target.orientation.z",
            "a finite number",
            pose_orientation(w=1.0, x=0.0, y=0.0),
        ),
        BadInput(
            "unknown-top-level-field",
            422,
            "num_sample",
            "only the fields robot, task, target, num_samples",
            planar(num_sample=10),
        ),
        BadInput(
            "unknown-tolerance-field",
            422,
            "tolerance.positon",
            "only the fields position, orientation",
            planar(tolerance={"positon": 1e-3}),
        ),
        BadInput(
            "unknown-target-field",
            422,
            "target.orientaton",
            "only the fields position, orientation, axis",
            pose(target={"position": [0.5, 0.1, 0.6], "orientaton": POSE["target"]["orientation"]}),
        ),
        BadInput(
            "unknown-quaternion-field",
            422,
            "target.orientation.q",
            "only the fields w, x, y, z",
            pose_orientation(w=1.0, x=0.0, y=0.0, z=0.0, q=0.0),
        ),
        # Orientation against the task.
        BadInput(
            "orientation-on-position-task",
            422,
            "target.orientation",
            "use task 'pose'",
            planar(
                target={
                    "position": [0.5, 0.0],
                    "orientation": {"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0},
                }
            ),
        ),
        BadInput(
            "axis-on-pose-task",
            422,
            "target.axis",
            "use task 'axis'",
            pose(target={**POSE["target"], "axis": [0.0, 0.0, 1.0]}),
        ),
        BadInput(
            "axis-missing-on-axis-task",
            422,
            "target.axis",
            "a unit vector [x, y, z], base frame",
            {"robot": "ur5", "task": "axis", "target": {"position": [0.4, 0.1, 0.3]}},
        ),
        BadInput(
            "zero-axis",
            422,
            "target.axis",
            "must be a unit vector (norm within 0.01 of 1, normalised then)",
            {
                "robot": "ur5",
                "task": "axis",
                "target": {"position": [0.4, 0.1, 0.3], "axis": [0.0, 0.0, 0.0]},
            },
        ),
        BadInput(
            "orientation-missing-on-pose-task",
            422,
            "target.orientation",
            "a unit quaternion {w, x, y, z}",
            pose(target={"position": [0.5, 0.1, 0.6]}),
        ),
        BadInput(
            "zero-quaternion",
            422,
            "target.orientation",
            "norm within 0.01 of 1",
            pose_orientation(w=0.0, x=0.0, y=0.0, z=0.0),
        ),
        BadInput(
            "far-from-unit-quaternion",
            422,
            "target.orientation",
            "norm within 0.01 of 1",
            pose_orientation(w=0.0, x=2.0, y=0.0, z=0.0),
        ),
        BadInput(
            "slightly-off-unit-quaternion",
            422,
            "target.orientation",
            "norm within 0.01 of 1",
            pose_orientation(w=0.0, x=1.02, y=0.0, z=0.0),
        ),
        BadInput(
            "orientation-tolerance-on-position-task",
            422,
            "tolerance.orientation",
            "only to the pose and axis tasks",
            planar(tolerance={"orientation": 1e-3}),
        ),
        # Numbers out of range.
        BadInput(
            "num-samples-zero",
            422,
            "num_samples",
            f"an integer >= 1 and <= {max_num_samples}",
            planar(num_samples=0),
        ),
        BadInput(
            "num-samples-negative",
            422,
            "num_samples",
            f"an integer >= 1 and <= {max_num_samples}",
            planar(num_samples=-5),
        ),
        BadInput(
            "num-samples-over-limit",
            413,
            "num_samples",
            f"at most {max_num_samples}",
            planar(num_samples=max_num_samples + 1),
        ),
        BadInput(
            "num-samples-fractional", 422, "num_samples", "an integer", planar(num_samples=2.5)
        ),
        BadInput(
            "position-tolerance-zero",
            422,
            "tolerance.position",
            "a finite number > 0 and <= 0.1",
            planar(tolerance={"position": 0.0}),
        ),
        BadInput(
            "position-tolerance-too-loose",
            422,
            "tolerance.position",
            "a finite number > 0 and <= 0.1",
            planar(tolerance={"position": 1.0}),
        ),
        BadInput(
            "orientation-tolerance-too-loose",
            422,
            "tolerance.orientation",
            "a finite number > 0 and <= 3.14",
            pose(tolerance={"orientation": 4.0}),
        ),
        BadInput(
            "seed-negative",
            422,
            "seed",
            "an integer >= 0 and <= 9223372036854775807",
            planar(seed=-1),
        ),
        BadInput(
            "seed-too-large",
            422,
            "seed",
            "an integer >= 0 and <= 9223372036854775807",
            planar(seed=2**64),
        ),
        BadInput(
            "max-configurations-zero",
            422,
            "max_configurations_per_component",
            "an integer >= 1",
            planar(max_configurations_per_component=0),
        ),
        BadInput(
            "include-paths-not-boolean",
            422,
            "include_paths",
            "true or false",
            planar(include_paths="yes"),
        ),
        # Wrong types (no coercion: "0.5" and true are not numbers).
        BadInput(
            "string-number",
            422,
            "target.position[0]",
            "a finite number",
            planar(target={"position": ["0.5", 0.0]}),
        ),
        BadInput(
            "boolean-number",
            422,
            "target.position[1]",
            "a finite number",
            planar(target={"position": [0.5, True]}),
        ),
        BadInput("robot-not-a-string", 422, "robot", "a string", planar(robot=3)),
        BadInput(
            "target-not-an-object",
            422,
            "target",
            "an object with fields position, orientation, axis",
            planar(target=[0.5, 0.0]),
        ),
        # The scene.
        BadInput(
            "obstacle-unknown-shape",
            422,
            "obstacles[0].shape",
            "one of 'box', 'sphere', 'cylinder', 'capsule'",
            pose(obstacles=[{**BOX, "shape": "cone"}]),
        ),
        BadInput(
            "obstacle-wrong-dimensions",
            422,
            "obstacles[1].dimensions",
            "[x, y, z]: 3 values in metres, each above 0 and at most 100",
            pose(obstacles=[BOX, {**BOX, "dimensions": [0.2, 0.2]}]),
        ),
        BadInput(
            "obstacle-negative-dimension",
            422,
            "obstacles[0].dimensions",
            "each above 0",
            pose(obstacles=[{**BOX, "dimensions": [0.2, -0.2, 0.2]}]),
        ),
        BadInput(
            "obstacle-non-unit-quaternion",
            422,
            "obstacles[0].orientation",
            "norm within 0.01 of 1",
            pose(obstacles=[{**BOX, "orientation": {"w": 2.0, "x": 0.0, "y": 0.0, "z": 0.0}}]),
        ),
        BadInput(
            "obstacle-short-position",
            422,
            "obstacles[0].position",
            "a list of 3 to 3 values",
            pose(obstacles=[{**BOX, "position": [0.5, 0.5]}]),
        ),
        BadInput(
            "too-many-obstacles",
            422,
            "obstacles",
            "at most 64 items",
            pose(obstacles=[BOX] * 65),
        ),
        BadInput(
            "obstacles-without-geometry",
            422,
            "obstacles",
            "collision_geometry true",
            planar(obstacles=[BOX]),
        ),
        BadInput(
            "margin-too-large",
            422,
            "collision.margin_m",
            "a finite number >= 0 and <= 0.5",
            pose(collision={"margin_m": 0.6}),
        ),
        BadInput(
            "collision-unknown-field",
            422,
            "collision.margin",
            "only the fields self, margin_m",
            pose(collision={"margin": 0.1}),
        ),
        # Unknown model (a path-like name is just an unknown name: no field becomes a path).
        BadInput("unknown-robot", 404, "robot", served_robots_message(), planar(robot="ur10")),
        BadInput("unknown-task", 404, "task", "served tasks: position", planar(task="pose")),
        BadInput(
            "path-like-robot",
            404,
            "robot",
            served_robots_message(),
            planar(robot="../models/planar3r-position"),
        ),
        # The body as a whole.
        BadInput(
            "not-json",
            422,
            "body",
            "an object with fields robot, task, target",
            raw=b'{"robot": planar3r}',
        ),
        BadInput(
            "json-array-body",
            422,
            "body",
            "an object with fields robot, task, target",
            raw=b"[1, 2]",
        ),
        BadInput("empty-body", 422, "body", "an object with fields robot, task, target", raw=b""),
        BadInput(
            "integer-too-long-to-parse",
            400,
            "body",
            "4300 digits",
            raw=raw_planar("[1" + "0" * 5000 + ", 0]"),
        ),
        BadInput(
            "wrong-content-type",
            415,
            "content-type",
            "application/json",
            raw=json.dumps(PLANAR).encode(),
            headers={"content-type": "text/plain"},
        ),
        BadInput(
            "form-content-type",
            415,
            "content-type",
            "application/json",
            raw=b"robot=planar3r",
            headers={"content-type": "application/x-www-form-urlencoded"},
        ),
        BadInput(
            "missing-content-type",
            415,
            "content-type",
            "application/json",
            raw=json.dumps(PLANAR).encode(),
            headers={},
        ),
        BadInput(
            "oversized-body",
            413,
            "body",
            f"at most {max_body_bytes} bytes",
            planar(reference_configuration=[0.0] * (max_body_bytes // 4)),
        ),
    ]


def messages(answer: dict[str, Any]) -> list[str]:
    """The message(s) of an error answer: 422 lists errors, every other status one detail."""
    detail = answer["detail"]
    return [e["msg"] for e in detail] if isinstance(detail, list) else [detail]


def check_answer(bad: BadInput, status: int, answer: dict[str, Any]) -> None:
    assert status == bad.status, answer
    texts = messages(answer)
    assert any(bad.field_name in text and bad.allowed in text for text in texts), texts
