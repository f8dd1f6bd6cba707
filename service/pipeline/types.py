"""Small typed containers passed between the pipeline stages, and the two model interfaces."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


class VelocityField(Protocol):
    """The learned velocity v(q_t, t, condition) in normalised joint coordinates."""

    def __call__(
        self,
        q_t: NDArray[np.float32],  # (B, n)
        t: NDArray[np.float32],  # (B, 1)
        condition: NDArray[np.float32],  # (B, c)
    ) -> NDArray[np.float32]:  # (B, n)
        ...


@dataclass(frozen=True)
class KinematicsResult:
    """Forward kinematics and geometric Jacobian (base frame, linear rows first)."""

    position_m: FloatArray  # (B, 3)
    rotation: FloatArray  # (B, 3, 3)
    jacobian: FloatArray  # (B, 6, n)


class Kinematics(Protocol):
    def __call__(self, q_rad: FloatArray) -> KinematicsResult:  # q_rad (B, n), float64
        ...


@dataclass(frozen=True)
class Correction:
    """Stage 3 output: configurations after DLS and their remaining task errors."""

    q_rad: FloatArray  # (N, n); periodic joints wrapped to (-pi, pi]
    position_error_m: FloatArray  # (N,) inf where the sample was not finite
    orientation_error_rad: FloatArray  # (N,) zeros for a position task


@dataclass(frozen=True)
class Acceptance:
    """Stage 4 output: which samples are valid solutions, and why the others are not."""

    within_tolerance: BoolArray  # (N,)
    within_limits: BoolArray  # (N,)

    @property
    def accepted(self) -> BoolArray:
        return self.within_tolerance & self.within_limits


@dataclass(frozen=True)
class Component:
    """One connected component of the accepted configurations (an SMM piece)."""

    q_rad: FloatArray  # (k, n) every member
    position_error_m: FloatArray  # (k,)
    orientation_error_rad: FloatArray  # (k,)


@dataclass(frozen=True)
class Counts:
    """Where every sample went: sampled = accepted + rejected_tolerance + rejected_joint_limits."""

    sampled: int
    accepted: int
    rejected_tolerance: int  # not within tolerance after correction (or not finite)
    rejected_joint_limits: int  # within tolerance but outside the joint limits

    @classmethod
    def of(cls, acceptance: Acceptance) -> Counts:
        tolerance = acceptance.within_tolerance
        return cls(
            sampled=len(tolerance),
            accepted=int(acceptance.accepted.sum()),
            rejected_tolerance=int((~tolerance).sum()),
            rejected_joint_limits=int((tolerance & ~acceptance.within_limits).sum()),
        )


@dataclass(frozen=True)
class StageTimings:
    encode_ms: float
    sample_ms: float
    correct_ms: float
    accept_ms: float
    cluster_ms: float
    total_ms: float
