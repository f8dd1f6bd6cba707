"""A tiny planar training run for the training tests: its config, its data, weight equality."""

from __future__ import annotations

import torch

from service.manifest import REPO_MODELS_DIR
from training.config import TrainConfig, preset
from training.data import FlowData, build_flow_data
from training.kinematics import ForwardKinematics, joint_spec, load_chain
from training.robots import robot_spec

TINY = TrainConfig(
    **{
        **preset("planar3r", "position").as_dict(),
        "samples": 600,
        "epochs": 3,
        "batch_size": 128,
        "hidden_width": 16,
        "hidden_layers": 2,
    }  # type: ignore[arg-type]
)


def tiny_planar_data() -> FlowData:
    """TINY.samples labelled planar 3R position pairs (data seed 1)."""
    robot = robot_spec("planar3r")
    chain = load_chain(REPO_MODELS_DIR / robot.urdf, robot.end_effector_link, robot.base_link)
    return build_flow_data(
        ForwardKinematics(chain), joint_spec(chain), robot.task("position"), TINY.samples, 1
    )


def weights_equal(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    """Every parameter and buffer of `a` equals `b`'s bit for bit."""
    pairs = zip(a.state_dict().values(), b.state_dict().values(), strict=True)
    return all(torch.equal(x, y) for x, y in pairs)
