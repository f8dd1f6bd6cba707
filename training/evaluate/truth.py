"""Exact ground truth per target, from the references: every exact configuration of the
SMM within the limits, and (iiwa14, panda) the component of each and each component's
size."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from service.pipeline.types import SmmModel
from training.evaluate.references import axis, iiwa14, panda
from training.evaluate.references.iiwa14 import MIN_SHARE, PositionSmm
from training.evaluate.references.planar3r import closed_form_smm, expected_component_count

# Recall of exact components is reported per size bucket: small pieces are expected
# to be missed more often at a fixed number of samples. Size is the arc length of a
# 1-D component and the share of the fibre of a 4-D one.
ARC_BUCKETS_RAD = (0.0, 0.5, 2.0, np.inf)
SHARE_BUCKETS = (0.0, MIN_SHARE, 0.1, np.inf)


@dataclass(frozen=True)
class Truth:
    points: np.ndarray  # (P, n) exact configurations within the limits
    count: int  # number of feasible components (4-D: those of at least MIN_SHARE)
    # Component of each point, each component's size and the size buckets (not planar3r).
    point_component: np.ndarray | None = None  # (P,)
    size: np.ndarray | None = None  # (C,) arc length in rad (1-D) or share of the fibre (4-D)
    size_edges: tuple[float, ...] = ARC_BUCKETS_RAD
    # Joints that decide membership: the 4-D fibre is q1..q6's fibre times any q7.
    membership_joints: int = 7  # the first this many joints
    # Where given, the exact component of a configuration is that of its nearest label
    # point (the 4-D reference's every node, denser than `points`), else of `points`.
    label_points: np.ndarray | None = None  # (L, membership_joints)
    label_component: np.ndarray | None = None  # (L,)
    # Joints compared on the circle when labelling (the UR5's: each turns a full circle).
    periodic: np.ndarray | None = None  # (membership_joints,)

    def labelling(self) -> tuple[np.ndarray, np.ndarray]:
        """The points (on the membership joints) and components that label configurations."""
        if self.label_points is not None and self.label_component is not None:
            return self.label_points, self.label_component
        assert self.point_component is not None
        return self.points[:, : self.membership_joints], self.point_component


class _Arc(Protocol):
    """A component of a 1-D pose SMM, as each reference gives it."""

    @property
    def q_rad(self) -> np.ndarray: ...  # (k, 7) ordered along the arc

    @property
    def arc_length_rad(self) -> float: ...


@dataclass(frozen=True)
class _Reference:
    pose_smm: Callable[[np.ndarray, np.ndarray], Sequence[_Arc]]
    position_smm: Callable[[np.ndarray, int], PositionSmm]


# The exact references of the 7-joint arms, by robot name.
REFERENCES = {
    "iiwa14": _Reference(iiwa14.pose_smm, lambda p, seed: iiwa14.position_smm(p, seed=seed)),
    "panda": _Reference(panda.pose_smm, lambda p, seed: panda.position_smm(p, seed=seed)),
}


# The axis task's references (training/evaluate/references/axis.py), by robot: position,
# target axis, tool axis, limits -> the exact SMM (r = 1 for the UR5, 2 for the iiwa14).
AXIS_REFERENCES: dict[str, Callable[..., axis.AxisSmm]] = {
    "ur5": lambda p, a, u, lower, upper: axis.ur5_axis_smm(p, a, u),
    "iiwa14": axis.iiwa14_axis_smm,
}

# The evaluation package each reference imports when it runs (training/evaluate/packages.py).
REFERENCE_PACKAGES: dict[str, str] = {"panda": "eaik", "ur5": "eaik"}


def ground_truth(model: SmmModel, q_target: np.ndarray, seed: int) -> Truth:
    """The exact SMM of the target made by q_target (n,); `seed` drives the 4-D grid only."""
    fk = model.kinematics(q_target[None])
    position, rotation = fk.position_m[0], fk.rotation[0]
    robot = model.manifest.robot
    if robot == "planar3r":
        components = closed_form_smm(position[:2], phi_step_rad=0.002)
        count = expected_component_count(float(np.linalg.norm(position[:2])))
        return Truth(points=np.concatenate(components), count=count)
    task = model.manifest.task
    if task.tool_axis is not None:
        return _axis_truth(model, position, rotation @ np.asarray(task.tool_axis))
    if robot not in REFERENCES:
        known = ", ".join(sorted([*REFERENCES, "planar3r"]))
        raise ValueError(f"no exact reference for robot {robot!r}; references: {known}")
    reference = REFERENCES[robot]
    if model.manifest.task.orientation:
        exact = reference.pose_smm(position, rotation)
        return Truth(
            points=np.concatenate([c.q_rad for c in exact]),
            count=len(exact),
            point_component=np.concatenate([np.full(len(c.q_rad), i) for i, c in enumerate(exact)]),
            size=np.array([c.arc_length_rad for c in exact]),
        )
    fibre = reference.position_smm(position, seed)
    if fibre.count == 0:
        # At the edge of the workspace (arm straight) the fibre is thinner than the grid
        # and no node lands on it: the generating configuration stands for it.
        return Truth(
            points=q_target[None], count=1, point_component=np.zeros(1, int), size=np.ones(1),
            size_edges=SHARE_BUCKETS, membership_joints=6,
        )  # fmt: skip
    return Truth(
        points=fibre.q_rad, count=fibre.count, point_component=fibre.component,
        size=fibre.share, size_edges=SHARE_BUCKETS, membership_joints=6,
        label_points=fibre.node_q6_rad, label_component=fibre.node_component,
    )  # fmt: skip


def _axis_truth(model: SmmModel, position_m: np.ndarray, axis_direction: np.ndarray) -> Truth:
    """The axis task's exact SMM: 1-D components sized by arc length, 2-D by share (those
    of at least MIN_SHARE counted, as for the 4-D fibre)."""
    manifest = model.manifest
    robot = manifest.robot
    if robot not in AXIS_REFERENCES:
        known = ", ".join(sorted(AXIS_REFERENCES))
        raise ValueError(f"no exact axis-task reference for robot {robot!r}; references: {known}")
    assert manifest.task.tool_axis is not None
    exact = AXIS_REFERENCES[robot](
        position_m, axis_direction, np.asarray(manifest.task.tool_axis),
        np.asarray(manifest.joints.lower_rad), np.asarray(manifest.joints.upper_rad),
    )  # fmt: skip
    n = manifest.joints.count
    periodic = np.asarray(manifest.joints.periodic, bool)
    if manifest.redundancy == 1:
        return Truth(
            points=exact.q_rad, count=exact.count, point_component=exact.component,
            size=exact.size, membership_joints=n, periodic=periodic,
        )  # fmt: skip
    return Truth(
        points=exact.q_rad, count=int((exact.size >= MIN_SHARE).sum()),
        point_component=exact.component, size=exact.size, size_edges=SHARE_BUCKETS,
        membership_joints=n, periodic=periodic,
    )  # fmt: skip
