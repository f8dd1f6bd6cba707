"""A served model whose flow reports each call first: tests that slow or count targets."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from service.models.registry import ServedModel
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


def condition_of(model: ServedModel, position_m: list[float]) -> bytes:
    """The bytes of the flow's condition for a position target, as `on_call` sees it."""
    normalise = model.manifest.condition.normalisation.normalise
    return normalise(np.array([position_m]))[0].astype(np.float32).tobytes()
