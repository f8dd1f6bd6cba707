"""The two exported networks behind the pipeline's Protocols, run with onnxruntime.

flow.onnx:       (q_t (B, n) f32, t (B, 1) f32, condition (B, c) f32) -> velocity (B, n) f32
kinematics.onnx: q (B, n) f64 -> position (B, 3), rotation (B, 3, 3), jacobian (B, 6, n), f64
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort

from service.pipeline.arrays import Float32Array, FloatArray
from service.pipeline.types import KinematicsResult

FLOW_INPUTS = ("q_t", "t", "condition")
FLOW_OUTPUT = "velocity"
KINEMATICS_INPUT = "q"
KINEMATICS_OUTPUTS = ("position", "rotation", "jacobian")


def session_options(threads: int) -> ort.SessionOptions:
    """`threads` intra-op threads (0: onnxruntime's default, all cores), one inter-op.

    The intra-op workers do not spin between calls: a spinning worker keeps its core busy
    for a while after every network evaluation, which on a small machine steals that
    core from the numpy stages of the same request (correction, connect) and from the
    other request in flight.
    """
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.add_session_config_entry("session.inter_op.allow_spinning", "0")
    return options


def open_session(path: Path, threads: int) -> ort.InferenceSession:
    options = session_options(threads)
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


class OnnxVelocityField:
    def __init__(self, session: ort.InferenceSession) -> None:
        self._session = session

    def __call__(
        self,
        q_t: Float32Array,  # (B, n)
        t: Float32Array,  # (B, 1)
        condition: Float32Array,  # (B, c)
    ) -> Float32Array:  # (B, n)
        feeds = dict(zip(FLOW_INPUTS, (q_t, t, condition), strict=True))
        (velocity,) = self._session.run([FLOW_OUTPUT], feeds)
        return np.asarray(velocity, dtype=np.float32)


class OnnxKinematics:
    def __init__(self, session: ort.InferenceSession) -> None:
        self._session = session

    def __call__(self, q_rad: FloatArray) -> KinematicsResult:  # q_rad (B, n)
        position, rotation, jacobian = self._session.run(
            list(KINEMATICS_OUTPUTS), {KINEMATICS_INPUT: np.ascontiguousarray(q_rad, np.float64)}
        )
        return KinematicsResult(position_m=position, rotation=rotation, jacobian=jacobian)
