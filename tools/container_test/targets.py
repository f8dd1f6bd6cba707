"""A request per bundled model, made from a known configuration, and how to check its
answer by a forward kinematics independent of the image: the references of
training/evaluate/references/ (the planar 3R's closed form, the iiwa14's DH table, the
Panda's and the UR5's URDFs read in float64), none of which the service computes with."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from tools.container_test import ROOT
from training.evaluate.references.iiwa14 import LIMITS_RAD as IIWA14_LIMITS_RAD
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.evaluate.references.planar3r import planar3r_position
from training.evaluate.references.rotations import rotation_angle_rad
from training.evaluate.references.urdf_chain import read_chain

# Slack on the tolerance when an answer is checked with the independent FK: the URDF is
# read in float32 by the export, so it agrees with the exact DH table to ~3e-8 m only.
FK_SLACK = 1e-7


@dataclass(frozen=True)
class Target:
    """A request for one bundled model and how to check its answer independently."""

    body: dict[str, Any]
    q_source: np.ndarray  # the configuration the target was made from
    check: Callable[[np.ndarray], dict[str, float]]  # (B, n) -> largest errors
    within_limits: Callable[[np.ndarray], np.ndarray]  # (B, n) -> (B,)
    distance: Callable[[np.ndarray, np.ndarray], np.ndarray]  # (B, n), (n,) -> (B,) rad


def planar3r_target() -> Target:
    q_source = np.array([0.4, 1.1, -0.7])
    goal = planar3r_position(q_source[None])[0]
    body = {
        "robot": "planar3r",
        "task": "position",
        "target": {"position": goal.tolist()},
        "tolerance": {"position": 1e-6},
        "reference_configuration": q_source.tolist(),
        "seed": 7,
    }
    return Target(
        body=body,
        q_source=q_source,
        check=lambda q: {
            "position": float(np.linalg.norm(planar3r_position(q) - goal, axis=1).max())
        },
        within_limits=lambda q: np.all(np.abs(q) <= np.pi, axis=-1),
        # Every joint is continuous: differences wrap to (-pi, pi].
        distance=lambda q, r: np.linalg.norm(np.angle(np.exp(1j * (q - r))), axis=-1),
    )


def spatial_target(
    robot: str,
    task: str,
    q_source: np.ndarray,  # (n,)
    pose: Callable[[np.ndarray], np.ndarray],  # (B, n) -> (B, 4, 4), the independent FK
    lower_rad: np.ndarray,  # (n,)
    upper_rad: np.ndarray,  # (n,)
    periodic: bool = False,  # every joint turns a full circle: distances wrap
) -> Target:
    """A spatial arm's target made from q_source, checked by its independent FK `pose`
    (the axis task's tool axis: the end effector's z, as both bundled axis models have)."""
    goal = pose(q_source[None])[0]  # (4, 4)
    target: dict[str, Any] = {"position": goal[:3, 3].tolist()}
    tolerance = {"position": 1e-6}
    if task == "pose":
        x, y, z, w = Rotation.from_matrix(goal[:3, :3]).as_quat()
        target["orientation"] = {"w": w, "x": x, "y": y, "z": z}
        tolerance["orientation"] = 1e-6
    if task == "axis":
        target["axis"] = goal[:3, 2].tolist()
        tolerance["orientation"] = 1e-6

    def check(q: np.ndarray) -> dict[str, float]:
        reached = pose(q)  # (B, 4, 4)
        errors = {"position": float(np.linalg.norm(reached[:, :3, 3] - goal[:3, 3], axis=1).max())}
        if task == "pose":
            goal_rotation = np.broadcast_to(goal[:3, :3], reached[:, :3, :3].shape)
            errors["orientation"] = float(
                rotation_angle_rad(reached[:, :3, :3], goal_rotation).max()
            )
        if task == "axis":
            tool = reached[:, :3, 2]  # (B, 3)
            sine = np.linalg.norm(np.cross(tool, goal[:3, 2]), axis=1)
            errors["orientation"] = float(np.arctan2(sine, tool @ goal[:3, 2]).max())
        return errors

    body = {
        "robot": robot,
        "task": task,
        "target": target,
        "tolerance": tolerance,
        "reference_configuration": q_source.tolist(),
        "seed": 7,
    }
    return Target(
        body=body,
        q_source=q_source,
        check=check,
        within_limits=lambda q: np.all(
            (q >= lower_rad - 1e-12) & (q <= upper_rad + 1e-12), axis=-1
        ),
        distance=(
            (lambda q, r: np.linalg.norm(np.angle(np.exp(1j * (q - r))), axis=-1))
            if periodic
            else (lambda q, r: np.linalg.norm(q - r, axis=-1))  # limited joints: no wrap
        ),
    )


def iiwa14_target(task: str) -> Target:
    """The iiwa14 checked by the paper's DH table (references.iiwa14)."""
    q_source = np.array([0.3, 0.6, 0.0, -1.2, 0.0, 0.9, 0.0])
    return spatial_target(
        "iiwa14", task, q_source, iiwa14_pose, -IIWA14_LIMITS_RAD, IIWA14_LIMITS_RAD
    )


def panda_target(task: str) -> Target:
    """The Panda checked by the float64 URDF chain of the references (not
    pytorch-kinematics, not the served chain.json kernel)."""
    chain = read_chain(ROOT / "models" / "robots" / "panda.urdf", "panda_hand_tcp", "panda_link0")
    q_source = np.array([0.3, -0.4, 0.2, -2.0, 0.1, 1.8, 0.5])
    return spatial_target("panda", task, q_source, chain.pose, chain.lower, chain.upper)


def ur5_target() -> Target:
    """The UR5's axis task checked by example-robot-data's URDF read in float64; every
    UR5 joint turns a full circle (its limits span 2 pi or more)."""
    chain = read_chain(ROOT / "models" / "robots" / "ur5.urdf", "tool0", "base_link")
    q_source = np.array([0.3, -1.2, 1.6, -1.97, -1.57, 0.0])
    return spatial_target(
        "ur5", "axis", q_source, chain.pose, chain.lower, chain.upper, periodic=True
    )


# Every bundled model needs an entry here: a model without an independent check fails.
TARGETS: dict[str, Callable[[], Target]] = {
    "planar3r-position": planar3r_target,
    "iiwa14-pose": lambda: iiwa14_target("pose"),
    "iiwa14-position": lambda: iiwa14_target("position"),
    "panda-pose": lambda: panda_target("pose"),
    "panda-position": lambda: panda_target("position"),
    "iiwa14-axis": lambda: iiwa14_target("axis"),
    "ur5-axis": ur5_target,
}


# How close (joint-space norm, rad) some answer must come to the source configuration.
# The 4-D position SMM is sampled sparsely at 1000 samples: a looser bound.
NEAREST_BOUND_RAD = {
    "planar3r-position": 0.3,
    "iiwa14-pose": 0.3,
    "iiwa14-position": 1.5,
    "panda-pose": 0.3,
    "panda-position": 1.5,
    "iiwa14-axis": 0.8,  # 2-D: between the 1-D and 4-D bounds
    "ur5-axis": 0.3,
}


def bundled_models() -> list[str]:
    return sorted(p.parent.name for p in (ROOT / "models").glob("*/manifest.json"))


def check_answer(model_id: str, target: Target, answer: dict[str, Any]) -> str:
    """Raise unless every configuration of `answer` is exact and within the limits."""
    assert answer["status"] == "ok", f"status {answer['status']}"
    configurations = [q for c in answer["components"] for q in c["configurations"]]
    q = np.array(configurations, dtype=float).reshape(len(configurations), -1)
    counts = answer["counts"]
    assert len(q) == counts["accepted"] > 0, f"{len(q)} configurations, counts {counts}"
    assert sum(c["size"] for c in answer["components"]) == counts["accepted"]
    errors = target.check(q)
    for kind, error in errors.items():
        bound = target.body["tolerance"][kind] + FK_SLACK
        assert error <= bound, f"{kind} error {error:.3g} > {bound:.3g} by the independent FK"
    assert np.all(target.within_limits(q)), "a configuration outside the joint limits"
    nearest = float(target.distance(q, target.q_source).min())
    assert nearest <= NEAREST_BOUND_RAD[model_id], f"nearest answer {nearest:.3f} rad away"
    worst = ", ".join(f"max {k} error {v:.1e}" for k, v in errors.items())
    return (
        f"{len(answer['components'])} components, {len(q)} configurations, {worst}, "
        f"nearest to the source {nearest:.3f} rad"
    )
