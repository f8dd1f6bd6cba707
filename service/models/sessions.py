"""The two exported networks behind the pipeline's Protocols, run with onnxruntime.

flow.onnx:       (q_t (B, n) f32, t (B, 1) f32, condition (B, c) f32) -> velocity (B, n) f32
kinematics.onnx: q (B, n) f64 -> position (B, 3), rotation (B, 3, 3), jacobian (B, 6, n), f64
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort

from service.pipeline.arrays import Float32Array, FloatArray
from service.pipeline.rows import ANSWERING, InFlight
from service.pipeline.types import KinematicsResult

FLOW_INPUTS = ("q_t", "t", "condition")
FLOW_OUTPUT = "velocity"
KINEMATICS_INPUT = "q"
KINEMATICS_OUTPUTS = ("position", "rotation", "jacobian")


def session_options(threads: int) -> ort.SessionOptions:
    """`threads` intra-op threads (0: onnxruntime's default, all cores), one inter-op.

    The intra-op workers spin while a call runs and stop when it returns
    (`session.force_spinning_stop`). Within a call a worker that sleeps must be woken for
    each of the network's operators (about forty), which on a 2-core Intel Xeon cost more
    than the second thread saved up to about 500 rows (`python -m tools.onnx_threads`);
    between calls a spinning worker would keep its core busy for a while, stealing it from
    the numpy and compiled stages of the same request (correction, connect) and from the
    other request in flight, so it sleeps there.
    """
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "1")
    options.add_session_config_entry("session.force_spinning_stop", "1")
    options.add_session_config_entry("session.inter_op.allow_spinning", "0")
    return options


def open_session(model: Path | bytes, threads: int) -> ort.InferenceSession:
    """The model at a path, or given as its bytes, on `threads` intra-op threads."""
    source = str(model) if isinstance(model, Path) else model
    return ort.InferenceSession(
        source, session_options(threads), providers=["CPUExecutionProvider"]
    )


# A flow call of at least this many rows runs on the session's threads, a smaller one on
# one thread: handing a small call's work to a second thread costs more than it saves.
# Measured on a 2-core Intel Xeon with the workers spinning within a call (`python -m
# tools.onnx_threads`): the 512-wide int8 networks (iiwa14, Panda) run as fast or faster
# on one thread up to about 320 rows (iiwa14 pose at 128 rows 0.38 against 0.50 ms, at 256
# 0.79 against 0.77-0.89) and faster on two from about 384 (1.23 against 1.08; at 500
# rows 1.67 against 1.42, at 1000 3.60 against 1.95); the 256-wide planar 3R network
# crosses over about the same place, and is drawn in rounds of 128. A row's velocity is
# the same to the bit on either (tests/service/models/test_sessions.py).
PARALLEL_MIN_ROWS = 384


# How many flow calls run at this moment: a call that starts while another runs takes one
# thread, since the cores are already shared (two requests at once, a batch's workers).
FLOW_CALLS = InFlight()


class OnnxVelocityField:
    """The flow network, on `parallel` (the session with the process's threads) for a call
    of at least `parallel_min_rows` rows made while no other runs, else on `serial` (one
    thread; the same session when `parallel` has one)."""

    def __init__(
        self,
        parallel: ort.InferenceSession,
        serial: ort.InferenceSession | None = None,
        parallel_min_rows: int = PARALLEL_MIN_ROWS,
    ) -> None:
        self._parallel = parallel
        self._serial = parallel if serial is None else serial
        self._parallel_min_rows = parallel_min_rows

    @classmethod
    def open(cls, path: Path, threads: int, serial: bool = True) -> OnnxVelocityField:
        """The network at `path` with `threads` intra-op threads for large calls (0: every
        core), and, with `serial`, a one-thread session beside it unless `threads` is 1
        (without, every call runs on the first session)."""
        parallel = open_session(path, threads)
        one = open_session(path, 1) if serial and threads != 1 else None
        return cls(parallel, one)

    def session_for(self, rows: int, others_in_flight: int) -> ort.InferenceSession:
        """The session a call of `rows` rows runs on while `others_in_flight` others run."""
        if rows >= self._parallel_min_rows and others_in_flight == 0 and ANSWERING.alone:
            return self._parallel
        return self._serial

    def __call__(
        self,
        q_t: Float32Array,  # (B, n)
        t: Float32Array,  # (B, 1)
        condition: Float32Array,  # (B, c)
    ) -> Float32Array:  # (B, n)
        feeds = dict(zip(FLOW_INPUTS, (q_t, t, condition), strict=True))
        with FLOW_CALLS.entered() as others:
            session = self.session_for(len(q_t), others)
            (velocity,) = session.run([FLOW_OUTPUT], feeds)
        return np.asarray(velocity, dtype=np.float32)


class OnnxKinematics:
    def __init__(self, session: ort.InferenceSession) -> None:
        self._session = session

    def __call__(self, q_rad: FloatArray) -> KinematicsResult:  # q_rad (B, n)
        position, rotation, jacobian = self._session.run(
            list(KINEMATICS_OUTPUTS), {KINEMATICS_INPUT: np.ascontiguousarray(q_rad, np.float64)}
        )
        return KinematicsResult(position_m=position, rotation=rotation, jacobian=jacobian)
