"""The sweep's plan: the axes it sweeps, the candidates of each (`SweepPlan`), a candidate
setting (`Setting`) and which candidates a model can serve (docs/sweep.md, Candidates)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal, get_args

from service.manifest import (
    FLOW_INT8_FILE,
    REFLOW_FILE,
    Defaults,
    Manifest,
    Precision,
    SamplerSpec,
)

Axis = Literal[
    "flow_precision_bits",
    "sampler_steps",
    "reflow_steps",
    "correction_steps",
    "num_samples",
    "connectivity_step_rad",
]
AXES: tuple[Axis, ...] = get_args(Axis)
# How each axis's value reads in a reason.
UNIT: dict[Axis, str] = {
    "flow_precision_bits": "bit flow",
    "sampler_steps": "Euler steps",
    "reflow_steps": "reflowed Euler steps (0: the base flow's)",
    "correction_steps": "DLS steps",
    "num_samples": "samples",
    "connectivity_step_rad": "rad connectivity step",
}
# The flow network's precision as the flow_precision_bits axis counts it, and back.
_BITS: dict[Precision, int] = {"float32": 32, "int8": 8}
_PRECISION: dict[int, Precision] = {bits: precision for precision, bits in _BITS.items()}
# Axes whose cost falls as their value grows (a longer step takes fewer of them).
LONGER_IS_CHEAPER: frozenset[Axis] = frozenset({"connectivity_step_rad"})

# Axes swept jointly with the DLS steps (docs/sweep.md says why).
JOINT_DLS_AXES: frozenset[str] = frozenset({"reflow_steps"})


def cost(axis: Axis, value: float) -> float:
    """What "cheaper" orders the candidates of an axis by (smaller is cheaper)."""
    return 1.0 / value if axis in LONGER_IS_CHEAPER else value


def connectivity_step_field(redundancy: int) -> str:
    """The ConnectivitySpec field the connectivity axis sets: the trace's continuation step
    for r = 1 (curves traced whole), the local planner's delta for r > 1 (a roadmap)."""
    return "trace_step_rad" if redundancy == 1 else "delta_rad"


@dataclass(frozen=True)
class SweepPlan:
    """The candidates of each axis and the reference's budget."""

    time_powers: tuple[float, ...] = (1.0, 1.5, 2.0)  # the first is the uniform grid
    flow_precision_bits: tuple[int, ...] = (32, 8)  # 8 only where the model has int8
    sampler_steps: tuple[int, ...] = (2, 4, 8, 20)
    # 0: the base flow at the steps chosen above; k > 0: the reflowed flow at k uniform
    # steps (only where the model has reflow.onnx, training/reflow.py).
    reflow_steps: tuple[int, ...] = (0, 1, 2, 4)
    correction_steps: tuple[int, ...] = (3, 6, 10)
    num_samples: tuple[int, ...] = (500, 1000, 2000)
    trace_step_rad: tuple[float, ...] = (0.075, 0.15, 0.3)  # r = 1
    planner_delta_rad: tuple[float, ...] = (0.15, 0.3, 0.6)  # r > 1
    reference_samples_factor: int = 4  # reference N = this x the largest candidate N
    reference_sampler_steps: int = 50
    reference_correction_steps: int = 12

    def candidates(self, axis: Axis, redundancy: int = 1) -> tuple[float, ...]:
        if axis == "connectivity_step_rad":
            return self.trace_step_rad if redundancy == 1 else self.planner_delta_rad
        values: tuple[int, ...] = getattr(self, axis)
        return values

    @property
    def reference_samples(self) -> int:
        return self.reference_samples_factor * max(self.num_samples)

    def reference_setting(self, redundancy: int = 1) -> Setting:
        """The dense reference: most samples, most steps, the finest connectivity step."""
        return Setting(
            self.reference_sampler_steps,
            self.reference_correction_steps,
            self.reference_samples,
            min(self.candidates("connectivity_step_rad", redundancy)),
        )


# The sweep's plan unless one is given.
DEFAULT_PLAN = SweepPlan()


@dataclass(frozen=True)
class Setting:
    """The swept serving defaults of one candidate."""

    sampler_steps: int
    correction_steps: int
    num_samples: int
    connectivity_step_rad: float  # trace step h (r = 1) or planner delta (r > 1)
    time_power: float = 1.0  # of the sampler's time grid, chosen before the axes
    flow_precision_bits: int = 32  # 32: flow.onnx (float32), 8: flow_int8.onnx
    # 0: the base flow at sampler_steps on the grid of time_power; k > 0: the reflowed
    # flow (reflow.onnx, or reflow_int8.onnx at 8 bits) at k uniform steps.
    reflow_steps: int = 0

    @classmethod
    def of(cls, defaults: Defaults, redundancy: int) -> Setting:
        step = getattr(defaults.connectivity, connectivity_step_field(redundancy))
        sampler = defaults.sampler
        reflow_steps = sampler.steps if sampler.flow == "reflow" else 0
        return cls(
            sampler.steps, defaults.correction_steps, defaults.num_samples, step,
            sampler.time_power, _BITS[sampler.precision], reflow_steps,
        )  # fmt: skip

    @property
    def sampler(self) -> SamplerSpec:
        precision = _PRECISION[self.flow_precision_bits]
        if self.reflow_steps:  # straight paths: the uniform grid
            return SamplerSpec(flow="reflow", steps=self.reflow_steps, precision=precision)
        return SamplerSpec(
            method="euler",
            steps=self.sampler_steps,
            time_power=self.time_power,
            precision=precision,
        )

    def value(self, axis: Axis) -> float:
        value: float = getattr(self, axis)
        return value

    def cost(self, axis: Axis) -> float:
        """What "cheaper" orders the candidates of `axis` by, where a count or a step says
        it (not on a joint axis: `Candidate.cost`)."""
        if axis in JOINT_DLS_AXES:
            raise ValueError(f"{axis} is ordered by measured time (Candidate.cost)")
        return cost(axis, self.value(axis))

    def with_value(self, axis: Axis, value: float) -> Setting:
        if axis == "connectivity_step_rad":
            return replace(self, connectivity_step_rad=float(value))
        if axis == "sampler_steps":  # the base flow's steps: the base flow samples
            return replace(self, sampler_steps=int(value), reflow_steps=0)
        return replace(self, **{axis: int(value)})

    def describe(self, *, leaving_out: Axis | None = None) -> str:
        grid = "" if self.time_power == 1.0 else f" (time power {self.time_power:g})"
        return ", ".join(
            f"{self.value(axis)} {UNIT[axis]}{grid if axis == 'sampler_steps' else ''}"
            for axis in AXES
            if axis != leaving_out
        )


def candidates_of(plan: SweepPlan, axis: Axis, manifest: Manifest) -> tuple[float, ...]:
    """The plan's candidates of `axis` that the model can serve: 8 bits only with an int8
    network (models exported before training/quantise.py have none)."""
    values = plan.candidates(axis, manifest.redundancy)
    if axis == "flow_precision_bits" and FLOW_INT8_FILE not in manifest.files:
        values = tuple(v for v in values if v == _BITS["float32"]) or (_BITS["float32"],)
    if axis == "reflow_steps" and REFLOW_FILE not in manifest.files:
        values = (0,)
    return values


def settings_on(plan: SweepPlan, axis: Axis, manifest: Manifest, chosen: Setting) -> list[Setting]:
    """The settings measured on `axis` from `chosen`: one per candidate value, and on a
    joint axis each value at every DLS candidate (a model without a reflowed network has
    only the base flow to offer there, at the chosen DLS steps)."""
    values = candidates_of(plan, axis, manifest)
    if axis not in JOINT_DLS_AXES or len(values) == 1:
        return [chosen.with_value(axis, value) for value in values]
    return [
        replace(chosen.with_value(axis, value), correction_steps=dls)
        for value in values
        for dls in plan.correction_steps
    ]


def checked_axes(
    plan: SweepPlan, axes: Sequence[Axis], targets: int, redundancy: int
) -> list[Axis]:
    """`axes` in AXES order; ValueError for no targets, unknown or no axes, or a plan
    whose candidates are not positive (counts at least 1, reflow steps at least 0)."""
    if targets < 1:
        raise ValueError(f"a sweep needs at least 1 target, got {targets}")
    unknown = [axis for axis in axes if axis not in AXES]
    if unknown or not axes:
        raise ValueError(f"unknown or no axes {list(axes)}; choose from {list(AXES)}")
    for axis in AXES:
        values = plan.candidates(axis, redundancy)
        if axis in LONGER_IS_CHEAPER:
            valid = bool(values) and min(values) > 0
        else:  # counts; reflow_steps 0 is the base flow
            valid = bool(values) and min(values) >= (0 if axis == "reflow_steps" else 1)
        if not valid:
            raise ValueError(
                f"{axis}: candidates must be positive (counts at least 1, reflow steps at "
                f"least 0), got {plan}"
            )
    return [axis for axis in AXES if axis in axes]
