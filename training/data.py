"""Training data: configurations spread over the joint limits, labelled by pytorch-kinematics FK."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from service.manifest import AffineNormalisation, JointSpec, TaskSpec
from service.pipeline.joint_space import JointLimits
from service.pipeline.targets import condition_features
from training.kinematics import ForwardKinematics


def sobol_configurations(joints: JointSpec, count: int, seed: int) -> torch.Tensor:
    """(count, n) float64 configurations: scrambled Sobol points scaled to the joint limits."""
    engine = torch.quasirandom.SobolEngine(joints.count, scramble=True, seed=seed)
    unit = engine.draw(count, dtype=torch.float64)  # (N, n) in [0, 1)
    lower = torch.tensor(joints.lower_rad, dtype=torch.float64)
    upper = torch.tensor(joints.upper_rad, dtype=torch.float64)
    return lower + unit * (upper - lower)


@torch.no_grad()
def end_effector_poses(
    fk: ForwardKinematics, q: torch.Tensor, chunk: int = 200_000
) -> tuple[np.ndarray, np.ndarray]:
    """Positions (N, 3) and rotations (N, 3, 3) of configurations q (N, n), in float64."""
    positions, rotations = [], []
    for start in range(0, q.shape[0], chunk):
        position, rotation, _ = fk(q[start : start + chunk])
        positions.append(position.numpy())
        rotations.append(rotation.numpy())
    return np.concatenate(positions), np.concatenate(rotations)


def joint_normalisation(joints: JointSpec) -> AffineNormalisation:
    """Maps the joint limits onto [-1, 1]."""
    limits = JointLimits.of(joints)
    return AffineNormalisation(
        offset=((limits.upper_rad + limits.lower_rad) / 2).tolist(),
        scale=((limits.upper_rad - limits.lower_rad) / 2).tolist(),
    )


def fit_condition_normalisation(features: np.ndarray) -> AffineNormalisation:
    """Maps each condition dimension's range in the training data onto [-1, 1]."""
    low, high = features.min(axis=0), features.max(axis=0)
    scale = np.where(high - low > 1e-12, (high - low) / 2, 1.0)
    return AffineNormalisation(offset=((high + low) / 2).tolist(), scale=scale.tolist())


@dataclass(frozen=True)
class FlowPairs:
    """Normalised training pairs: targets of the flow (q_1) and their conditions."""

    q_1: torch.Tensor  # (N, n) float32, joint limits at -1 and 1
    condition: torch.Tensor  # (N, c) float32, the fitted range at -1 and 1


def fresh_seed(seed: int, epoch: int) -> int:
    """The Sobol scramble seed of `epoch`'s fresh configurations in a run seeded `seed`."""
    return int(np.random.SeedSequence([seed, epoch]).generate_state(1)[0])


@dataclass(frozen=True)
class Labeller:
    """Draws configurations and labels them with FK, normalised by fixed normalisations.

    Built once from the initial data, so every later draw (fresh data each epoch) is
    normalised exactly as the data the normalisation was fitted on.
    """

    fk: ForwardKinematics
    joints: JointSpec
    task: TaskSpec
    joint_normalisation: AffineNormalisation
    condition_normalisation: AffineNormalisation

    def label(self, q: torch.Tensor) -> FlowPairs:
        """Normalised pairs of configurations q (N, n) float64."""
        return self.normalise(q, condition_features_of(self.fk, self.task, q))

    def normalise(self, q: torch.Tensor, features: np.ndarray) -> FlowPairs:
        """Pairs of configurations q (N, n) float64 and their raw condition features (N, c)."""
        return FlowPairs(
            q_1=torch.from_numpy(self.joint_normalisation.normalise(q.numpy()).astype(np.float32)),
            condition=torch.from_numpy(
                self.condition_normalisation.normalise(features).astype(np.float32)
            ),
        )

    def __call__(self, count: int, seed: int) -> FlowPairs:
        """`count` pairs from the Sobol points of scramble `seed`."""
        return self.label(sobol_configurations(self.joints, count, seed))


def condition_features_of(fk: ForwardKinematics, task: TaskSpec, q: torch.Tensor) -> np.ndarray:
    """Raw condition features (N, c) of configurations q (N, n) float64 for `task`."""
    position, rotation = end_effector_poses(fk, q)
    return condition_features(
        task, position[:, task.position_axes], rotation if task.orientation_rows else None
    )


@dataclass(frozen=True)
class FlowData:
    """Normalised training pairs, their normalisations, and how to label more of them."""

    q_1: torch.Tensor  # (N, n) float32 in [-1, 1]
    condition: torch.Tensor  # (N, c) float32 in [-1, 1]
    joint_normalisation: AffineNormalisation
    condition_normalisation: AffineNormalisation
    # Labels new configurations like these (training with fresh_data needs it).
    labeller: Labeller | None = None


def build_flow_data(
    fk: ForwardKinematics, joints: JointSpec, task: TaskSpec, count: int, seed: int
) -> FlowData:
    """`count` Sobol configurations (scramble `seed`) labelled by FK; normalisations fitted."""
    q = sobol_configurations(joints, count, seed)
    features = condition_features_of(fk, task, q)
    labeller = Labeller(
        fk=fk,
        joints=joints,
        task=task,
        joint_normalisation=joint_normalisation(joints),
        condition_normalisation=fit_condition_normalisation(features),
    )
    pairs = labeller.normalise(q, features)
    return FlowData(
        q_1=pairs.q_1,
        condition=pairs.condition,
        joint_normalisation=labeller.joint_normalisation,
        condition_normalisation=labeller.condition_normalisation,
        labeller=labeller,
    )
