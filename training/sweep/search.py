"""The sweep itself: the time grid, then each axis in order, measured against the dense
reference and picked by the rule (`sweep_defaults`); and the sweep whose defaults serve
only if the judge finds them no worse than the served ones (`judged_sweep`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from service.manifest import Defaults
from service.models.registry import ServedModel
from service.pipeline.run import run
from service.pipeline.types import Query
from training.evaluate.judge import (
    JUDGED,
    JUDGED_SEPARATOR,
    REPORT_TARGETS,
    judged_defaults,
    unserved_reasons,
)
from training.sweep.measures import (
    REFERENCE_SEED_OFFSET,
    Candidate,
    Measures,
    SweepTargets,
    TimePowerRow,
    agreement,
    answer,
    connectivity_of,
    raw_error,
    reference_answer,
    summarise,
    sweep_targets,
)
from training.sweep.plan import (
    AXES,
    DEFAULT_PLAN,
    Axis,
    Setting,
    SweepPlan,
    checked_axes,
    settings_on,
)
from training.sweep.reasons import chosen_reasons, figures, raw_figures, time_power_reason
from training.sweep.rule import (
    COUNT_RIGHT_MARGIN,
    COVERAGE_MARGIN,
    KEEP_RATE_MARGIN,
    MERGES_MARGIN,
    RECALL_MARGIN,
    SAMPLER_KEEP_RATE_MARGIN,
    TIME_POWER_GAIN,
    pick,
    pick_time_power,
)


@dataclass(frozen=True)
class SweepResult:
    """The chosen defaults with their reasons, and the table they were chosen from."""

    defaults: Defaults
    chosen: Setting
    table: list[Candidate]  # in the order measured
    time_power_table: list[TimePowerRow]
    targets: int
    seed: int
    plan: SweepPlan
    reference_median_total_ms: float
    wall_time_s: float
    # The defaults as each swept axis left them (the axes after it at their starting
    # values): settings the sweep measured, the last one `defaults`.
    steps: list[tuple[Axis, Defaults]] = field(default_factory=list)

    def as_json(self) -> dict[str, object]:
        return {
            "chosen": asdict(self.chosen),
            "targets": self.targets,
            "seed": self.seed,
            "plan": {**asdict(self.plan), "reference_samples": self.plan.reference_samples},
            "margins": {
                "keep_rate": KEEP_RATE_MARGIN,
                "sampler_steps_keep_rate": SAMPLER_KEEP_RATE_MARGIN,
                "coverage_p95_relative": COVERAGE_MARGIN,
                "count_right": COUNT_RIGHT_MARGIN,
                "recall": RECALL_MARGIN,
                "merges_per_target": MERGES_MARGIN,
                "time_power_gain": TIME_POWER_GAIN,
            },
            "time_power_table": [asdict(row) for row in self.time_power_table],
            "reference_median_total_ms": round(self.reference_median_total_ms, 1),
            "wall_time_s": round(self.wall_time_s, 1),
            "table": [row.as_json() for row in self.table],
            "defaults": self.defaults.model_dump(),
        }


def _quiet(line: str) -> None:
    del line


def sweep_defaults(
    model: ServedModel,
    targets: int,
    seed: int,
    plan: SweepPlan = DEFAULT_PLAN,
    progress: Callable[[str], None] = _quiet,
    axes: Sequence[Axis] = AXES,
) -> SweepResult:
    """Choose the model's flow precision, sampler steps (and the time grid with them), DLS
    steps, num_samples and connectivity step by the rule of docs/sweep.md, starting
    from its manifest's defaults; only `axes` are swept (in AXES order), the rest is kept."""
    axes = checked_axes(plan, axes, targets, model.manifest.redundancy)
    manifest = model.manifest
    redundancy = manifest.redundancy
    start_s = time.perf_counter()
    periodic = np.asarray(manifest.joints.periodic, dtype=bool)
    drawn = sweep_targets(model, targets, seed)
    first = drawn.fields[0]
    run(model, Query.for_model(manifest, position_m=first.position_m,
                               orientation_wxyz=first.orientation_wxyz, axis=first.axis,
                               check_self=False))  # fmt: skip
    # warm-up above: onnxruntime's first-call allocations stay out of the timings.
    reference = plan.reference_setting(redundancy)
    progress(f"sweep: dense reference ({reference.describe()}) on {targets} targets")
    references = [
        reference_answer(
            answer(model, reference, drawn, i, seed + REFERENCE_SEED_OFFSET + i),
            manifest.joints.count,
            manifest.redundancy,
        )
        for i in range(targets)
    ]
    measured: dict[Setting, Measures] = {}
    table: list[Candidate] = []
    steps: list[tuple[Axis, Defaults]] = []
    reasons: dict[str, str] = {}
    chosen = Setting.of(manifest.defaults, redundancy)
    powers: list[TimePowerRow] = []
    power_reason = ""
    if "sampler_steps" in axes:
        powers, chosen, power_reason = _time_grid(model, plan, chosen, drawn, seed, progress)
    for axis in axes:
        rows = []
        for setting in settings_on(plan, axis, manifest, chosen):
            if setting not in measured:
                measured[setting] = summarise(
                    [
                        agreement(answer(model, setting, drawn, i, seed + i), ref, periodic)
                        for i, ref in enumerate(references)
                    ]
                )
            rows.append(Candidate(axis, setting, measured[setting]))
            progress(f"sweep: {figures(rows[-1])} ({time.perf_counter() - start_s:.0f} s)")
        best = pick(rows)
        table += rows
        reasons.update(
            chosen_reasons(rows, best, chosen, axes, seed, plan, redundancy, power_reason)
        )
        chosen = best.setting
        steps.append((axis, _defaults(model, chosen, reasons)))
    return SweepResult(
        defaults=steps[-1][1],
        chosen=chosen,
        table=table,
        time_power_table=powers,
        targets=targets,
        seed=seed,
        plan=plan,
        reference_median_total_ms=float(np.median([r.total_ms for r in references])),
        wall_time_s=time.perf_counter() - start_s,
        steps=steps,
    )


def _time_grid(
    model: ServedModel,
    plan: SweepPlan,
    chosen: Setting,
    drawn: SweepTargets,
    seed: int,
    progress: Callable[[str], None],
) -> tuple[list[TimePowerRow], Setting, str]:
    """The raw error of each of the plan's time powers, `chosen` on the chosen power's grid,
    and why that power."""
    powers = []
    for power in plan.time_powers:
        base = replace(chosen, reflow_steps=0).sampler  # the grid is the base flow's
        sampler = base.model_copy(update={"time_power": power})
        powers.append(raw_error(model, sampler, drawn, chosen.num_samples, seed))
        progress(f"sweep: time power {power:g}: {raw_figures(powers[-1])}")
    power_choice = pick_time_power(powers)
    chosen = replace(chosen, time_power=power_choice.time_power)
    return powers, chosen, time_power_reason(powers, power_choice, chosen, seed)


def _defaults(model: ServedModel, chosen: Setting, reasons: dict[str, str]) -> Defaults:
    """The model's defaults with the swept values of `chosen` and the reasons so far; what
    the sweep does not sweep (the sampler's rounds and rows per call, the connectivity but
    its step) stays."""
    start = model.manifest.defaults
    kept = {"round_samples": start.sampler.round_samples, "call_rows": start.sampler.call_rows}
    sampler = chosen.sampler.model_copy(update=kept)
    return Defaults.model_validate(
        {
            **start.model_dump(),
            "num_samples": chosen.num_samples,
            "sampler": sampler.model_dump(),
            "correction_steps": chosen.correction_steps,
            "connectivity": connectivity_of(model, chosen).model_dump(),
            # A judge's verdict (training/evaluate/judge.py) was on the defaults
            # this sweep replaces: it does not carry over.
            "reasons": {**{k: v for k, v in start.reasons.items() if k != JUDGED}, **reasons},
        }
    )


def judged_sweep(
    model: ServedModel,
    targets: int,
    seed: int,
    incumbent: Defaults,
    plan: SweepPlan = DEFAULT_PLAN,
    progress: Callable[[str], None] = _quiet,
    axes: Sequence[Axis] = AXES,
    first: SweepResult | None = None,
    judge_targets: int = REPORT_TARGETS,
) -> Defaults:
    """The sweep's defaults (`first`: that sweep, already run with `plan`) if judged no
    worse than `incumbent` against the exact SMMs (training/evaluate/judge.py
    `judged_defaults`), else the first judged no worse of the defaults as each earlier
    axis left them, last axis first, else the incumbent's.

    Each of those is a setting the sweep measured (`SweepResult.steps`), changing fewer
    of the served values, so one axis the judge refuses does not take the others' gains
    with it: on the iiwa14 position model the num_samples axis, with no candidate within
    every margin, fell back to 500 samples (coverage p95 1.75 vs 1.44 rad on the judge's
    targets) and the judge refused the whole sweep with it.

    Where the judge refuses the defaults as the reflowed sampler's axis left them with
    k > 0 reflowed steps, the sweep runs again without the reflowed step counts up to k,
    so the next costlier reflowed sampler (or the base flow) is swept and judged, until
    one serves or none is left: the sweep's 20 targets rank the candidates by cost, and
    the judge's 220 decide how few reflowed steps serve (the planar 3R's 1-step sampler
    merged two loops on one of them). Every refusal stays in reasons["judged"] before the
    final verdict. `judge_targets`: the judge's report targets (`judged_defaults`)."""
    refused: list[str] = []
    while True:
        swept = first or sweep_defaults(model, targets, seed, plan, progress, axes)
        first = None
        judged, reflow_refused = _judge_steps(
            model, swept, incumbent, progress, refused, judge_targets
        )
        costlier = tuple(v for v in plan.reflow_steps if v > reflow_refused)
        if judged is not None or not reflow_refused or not costlier:
            break
        progress(
            f"sweep: the judge refused {reflow_refused} reflowed steps; sweeping {costlier} again"
        )
        plan = replace(plan, reflow_steps=tuple(v for v in plan.reflow_steps if v == 0) + costlier)
    if judged is None:  # nothing the sweep measured serves: the incumbent does
        unserved = unserved_reasons(swept.defaults, incumbent)
        judged = incumbent.model_copy(update={"reasons": {**unserved, **incumbent.reasons}})
        last = "so the incumbent defaults serve"
    elif not refused:
        return judged
    else:  # defaults equal to the incumbent's come back from judged_defaults unjudged
        last = judged.reasons.get(
            JUDGED, "what serves was not judged: the sweep kept the served values"
        )
    verdict = JUDGED_SEPARATOR.join([*(f"refused first, {r}" for r in refused), last])
    return judged.model_copy(update={"reasons": {**judged.reasons, JUDGED: verdict}})


def _judge_steps(
    model: ServedModel,
    swept: SweepResult,
    incumbent: Defaults,
    progress: Callable[[str], None],
    refused: list[str],
    judge_targets: int = REPORT_TARGETS,
) -> tuple[Defaults | None, int]:
    """The first of the sweep's steps, last first, that the judge lets serve (None if
    none), and the reflowed step count whose refusal stopped the search (0 if none did);
    each refusal is appended to `refused`."""
    tried: list[dict[str, object]] = []
    kept = incumbent.model_dump(exclude={"reasons"})
    for axis, defaults in reversed(swept.steps):
        values = defaults.model_dump(exclude={"reasons"})
        if values in tried or (values == kept and tried):
            continue  # judged already, or the incumbent itself after a refusal
        tried.append(values)
        judged = judged_defaults(model, defaults, incumbent, progress, judge_targets)
        if judged.model_dump(exclude={"reasons"}) == values:
            return judged, 0
        reflowed = defaults.sampler.steps if defaults.sampler.flow == "reflow" else 0
        if axis == "reflow_steps" and reflowed:
            refused.append(f"{reflowed} reflowed steps: {judged.reasons[JUDGED]}")
            return None, reflowed
        refused.append(f"the sweep's defaults up to {axis}: {judged.reasons[JUDGED]}")
        progress(f"sweep: the judge refused the sweep's defaults up to {axis}")
    return None, 0
