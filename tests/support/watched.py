"""A served model whose flow reports each call first: tests that slow or count targets."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.deadline import Deadline
from service.pipeline.types import VelocityField


def watched(model: ServedModel, on_call: Callable[[np.ndarray], None]) -> ServedModel:
    """`model`, its flow networks calling `on_call(condition)` ((c,), the rows' condition)
    before each evaluation."""

    def watching(network: VelocityField) -> VelocityField:
        def velocity(q_t: np.ndarray, t: np.ndarray, condition: np.ndarray) -> np.ndarray:
            on_call(condition[0])
            return network(q_t, t, condition)

        return velocity

    networks = {name: watching(network) for name, network in model.networks.items()}
    return dataclasses.replace(model, networks=networks)


def slow_on(model: ServedModel, position_m: list[float], deadline: Deadline) -> ServedModel:
    """`model`, its flow sleeping past `deadline` when asked about the target at
    `position_m` (a batch stopped by the deadline at that target's sampling)."""
    slow = condition_of(model, position_m)

    def sleep_past_the_deadline(condition: np.ndarray) -> None:
        if condition.tobytes() == slow:
            time.sleep(max(0.0, deadline.remaining_s()) + 0.01)

    return watched(model, sleep_past_the_deadline)


def condition_of(model: ServedModel, position_m: list[float]) -> bytes:
    """The bytes of the flow's condition for a position target, as `on_call` sees it."""
    normalise = model.manifest.condition.normalisation.normalise
    return normalise(np.array([position_m]))[0].astype(np.float32).tobytes()
