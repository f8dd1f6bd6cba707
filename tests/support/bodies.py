"""Valid POST /smm bodies, one per served model, shared by the tests."""

from __future__ import annotations

from typing import Any

PLANAR: dict[str, Any] = {
    "robot": "planar3r",
    "task": "position",
    "target": {"position": [1.2, 0.4]},
}
POSE: dict[str, Any] = {
    "robot": "iiwa14",
    "task": "pose",
    "target": {
        "position": [0.5, 0.1, 0.6],
        "orientation": {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0},
    },
}
POSITION: dict[str, Any] = {
    "robot": "iiwa14",
    "task": "position",
    "target": {"position": [0.5, 0.0, 0.6]},
}
