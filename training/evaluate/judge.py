"""Judging serving defaults against the exact SMMs: is a candidate's answer no worse?

The sweep (training/sweep/) compares settings on 20 targets with a dense answer of the
same pipeline; it cannot see a rare loss. A reflowed few-step sampler chosen by it lost
one of 24 exact components on one of 200 targets and merged the two loops of the planar
3R at rho = 0.999, where they pass 0.1 rad apart: a sampler change that the sweep
accepts is judged here before it serves (training/reflow.py).

Targets: the evaluation report's held-out targets (FK of configurations uniform in the
limits, seed 7, the first `targets`), then `near_singular` targets where components pass
closest to each other: the configurations of smallest task-Jacobian singular value among
NEAR_SINGULAR_DRAWS x as many uniform draws (another seed). Each target is answered by
the candidate and by the incumbent defaults on DRAWS draws (the same sampling seeds),
each at its own num_samples, and every answer is measured against the exact ground truth
(training/evaluate/truth.py) with the evaluation's figures: count right, splits and
merges per target, recall of the counted exact components, coverage p95.

The candidate is worse on a component figure where a paired test over the targets says
so (training/evaluate/paired.py): its mean gain more than Z_REFUSE standard errors below
zero, or a unit the incumbent gets right on every draw lost on every draw (a target's
count, a component); on coverage p95 beyond COVERAGE_MARGIN of the incumbent's (the p95
moves ~1-3 % between samplers that find the same components). A rule of one draw a
target that refuses any worse figure refuses the served sampler against itself on other
seeds (recall 0.996 vs 0.998 on the iiwa14 pose, docs/benchmark/judge-self2000-*): a
difference of the size of a sampler's own spread is no evidence that it finds less.

Only robots with an exact reference can be judged (planar3r, iiwa14, panda);
`has_ground_truth` says which. `judged_defaults` applies the verdict wherever swept
defaults would replace served ones: the reflow's export (training/reflow.py, through
training/export.py `sweep_and_measure`) and `smm-train sweep --write`.

`smm-train judge --model <id> --candidate paper|<JSON>` judges the
paper's configuration, or any change of the served defaults, against what serves,
writing nothing but its `--out` record (`run_command`); with `--write`, a candidate judged no
worse replaces the served defaults (`served_candidate`). That is how a change the sweep
cannot propose serves: the sweep's rule measures agreement with a dense answer of the
same pipeline on 20 targets, a stand-in that counts as merges the components a sampler
unlike the reference's joins where the reference splits them, while the judge measures
against the exact SMMs on 220.

`--candidate-model-dir <dir>` judges another trained network of the same robot and task
(`smm-train train --models-dir`, a narrower one, say) against the served one, at its own
defaults or, with `--candidate`, at the served defaults so changed (`'{}'`: as they are,
so only the network differs). With `--write`, a candidate judged no worse serves: its
directory replaces the model's (copied beside it, then renamed), with the defaults it was
judged at and the verdict in their reasons (`replace_model_directory`).

    smm-train judge --model iiwa14-pose --candidate paper --num-samples 1000
    smm-train judge --model planar3r-position \
        --candidate '{"sampler": {"flow": "reflow", "steps": 2, "time_power": 1.0}}'
    smm-train judge --model planar3r-position \
        --candidate-model-dir /tmp/narrow/models/planar3r-position [--candidate '{}']
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shutil
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR, Defaults
from service.models.registry import ServedModel, load_model
from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.correction import jacobian_on_fibre
from service.pipeline.joint_space import JointLimits
from training.defaults import write_defaults
from training.evaluate.compare import TRUTH_FIGURES, figure_pair, worse_than
from training.evaluate.methods import MethodTarget, served_target
from training.evaluate.metrics import (
    component_agreement,
    counted_components,
    coverage_p95,
    found_components,
    nearest_distance,
)
from training.evaluate.paired import Z_REFUSE, Counts, Paired, paired
from training.evaluate.quality import PAPER_SAMPLER
from training.evaluate.served import serving
from training.evaluate.targets import uniform_configurations
from training.evaluate.truth import AXIS_REFERENCES, REFERENCES, Truth, ground_truth

# The evaluation report's targets (training/evaluate/report.py).
REPORT_SEED = 7
REPORT_TARGETS = 200
NEAR_SINGULAR = 20
NEAR_SINGULAR_DRAWS = 50  # uniform draws per near-singular target kept
COVERAGE_MARGIN = 0.10
# The reason key of the verdict in judged defaults (Defaults.reasons).
JUDGED = "judged"
JUDGED_SEPARATOR = " | "  # between the verdicts of reasons["judged"], earliest first
# The paper's configuration (seed Table 4): 100 Euler steps on the uniform grid, 3 DLS.
PAPER_DLS_STEPS = 3


def near_singular_for(targets: int) -> int:
    """Near-singular targets beside `targets` report targets: NEAR_SINGULAR per
    REPORT_TARGETS (a judge scaled down with a small training budget keeps the share)."""
    return max(1, round(targets * NEAR_SINGULAR / REPORT_TARGETS))


def robot_has_ground_truth(robot: str) -> bool:
    """Whether `robot` has an exact reference to judge against."""
    return robot == "planar3r" or robot in REFERENCES or robot in AXIS_REFERENCES


def has_ground_truth(model: ServedModel) -> bool:
    """Whether the model's robot has an exact reference to judge against."""
    return robot_has_ground_truth(model.manifest.robot)


@dataclass(frozen=True)
class Measure:
    """One answer on one target against its exact SMMs: what the evaluation's component
    figures sum over targets."""

    right: bool | None  # the count right (None: the method labels no component)
    splits: int | None  # None: no labels, or no exact component labels (planar 3R)
    merges: int | None
    found: BoolArray | None  # (C,) each counted exact component found (None: no labels)
    coverage_rad: FloatArray  # (P,) each exact point's distance to the nearest answer


def measure(answer: MethodTarget, truth: Truth, periodic: BoolArray) -> Measure:
    """`answer` against `truth` (metrics.py's definitions)."""
    agreement = component_agreement(answer, truth)
    labelled = truth.point_component is not None and truth.size is not None
    return Measure(
        right=None if agreement is None else agreement.right,
        splits=None if agreement is None else agreement.splits,
        merges=None if agreement is None else agreement.merges,
        found=found_components(answer, truth)[counted_components(truth)] if labelled else None,
        coverage_rad=nearest_distance(truth.points, answer.returned, periodic),
    )


def pooled(measures: Sequence[Measure]) -> dict[str, float]:
    """The evaluation's component figures over `measures` (targets, or targets x draws):
    count right over the labelled answers, coverage p95 over every exact point, and
    splits and merges per target and recall of the counted exact components where exact
    component labels exist."""
    known = [m for m in measures if m.right is not None]
    result = {
        "count_right": float(np.mean([m.right for m in known])),
        "coverage_p95_rad": coverage_p95(np.concatenate([m.coverage_rad for m in measures])),
    }
    if known and known[0].splits is not None:
        # Recall over the components the count counts: every one of a 1-D SMM, those of at
        # least 1 % of a 4-D fibre.
        found = [m.found for m in measures if m.found is not None]
        result["splits_per_target"] = float(np.mean([m.splits for m in known]))
        result["merges_per_target"] = float(np.mean([m.merges for m in known]))
        result["recall"] = float(np.concatenate(found).mean())
    return result


def figures(
    model: ServedModel, answers: Sequence[MethodTarget], truths: Sequence[Truth]
) -> dict[str, float]:
    """The evaluation's component figures of one configuration over the targets."""
    periodic = model.limits.periodic
    return pooled([measure(a, t, periodic) for a, t in zip(answers, truths, strict=True)])


def near_singular_configurations(
    model: ServedModel, count: int, seed: int
) -> FloatArray:  # (count, n)
    """The `count` configurations of smallest task-Jacobian singular value among
    NEAR_SINGULAR_DRAWS x count uniform in the limits: targets near a critical value of
    the task map, where the fibre's components pass closest to each other."""
    manifest = model.manifest
    limits = JointLimits.of(manifest.joints)
    q = uniform_configurations(limits, NEAR_SINGULAR_DRAWS * count, seed)
    jacobian = jacobian_on_fibre(model.kinematics(q), manifest.task)  # (D, m, n)
    smallest = np.linalg.svd(jacobian, compute_uv=False)[:, -1]  # (D,)
    return q[np.argsort(smallest)[:count]]


def judged_configurations(
    model: ServedModel, targets: int, near_singular: int, seed: int
) -> FloatArray:  # (targets + near_singular, n)
    """The configurations whose FK the judge answers: the report's first `targets` (uniform
    in the limits, `seed`), then `near_singular` ones (`near_singular_configurations`,
    seed + 1); target i's truth is drawn from seed + i and its samples from seed i."""
    return np.concatenate(
        [
            uniform_configurations(model.limits, targets, seed),
            near_singular_configurations(model, near_singular, seed + 1),
        ]
    )


# Each side answers every target on DRAWS draws: target i's draw j samples from seed
# i + j * DRAW_SEED_STRIDE (+ the candidate's offset), so draw 0 is seed i. Four draws
# make a unit lost on every one rare for a sampler against itself (paired.py: 4^-4 at
# worst) at four times one draw's answers.
DRAWS = 4
DRAW_SEED_STRIDE = 100_000


def draw_seed(target: int, draw: int, offset: int = 0) -> int:
    """The sampling seed of `target`'s `draw` (DRAWS)."""
    return target + offset + draw * DRAW_SEED_STRIDE


@dataclass(frozen=True)
class Judgement:
    """A candidate's and the incumbent's figures on the same targets and draws, each
    component figure's paired test (paired.py), and the verdict."""

    targets: int
    near_singular_targets: int
    seed: int
    candidate: dict[str, float]  # pooled over the targets and draws
    incumbent: dict[str, float]
    worse: list[str]  # the candidate's worse figures, each with why; empty: no worse
    # The candidate's sampling seeds are the incumbent's moved by this (0: the same seeds).
    candidate_seed_offset: int = 0
    draws: int = 1
    tests: dict[str, Paired] = dataclasses.field(default_factory=dict)  # by figure key

    @property
    def no_worse(self) -> bool:
        return not self.worse

    def summary(self) -> str:
        """One line for a manifest's reasons."""
        where = (
            f"{self.targets} report targets (seed {self.seed}) and {self.near_singular_targets} "
            f"near-singular ones, {self.draws} draw{'s' if self.draws > 1 else ''} each, "
            "against the exact SMMs"
        )
        if self.candidate_seed_offset:
            where += f", the candidate's sampling seeds moved by {self.candidate_seed_offset}"
        if self.no_worse:
            return f"no worse than the incumbent on {where}"
        return f"worse than the incumbent on {where}: " + "; ".join(self.worse)


def judge(
    model: ServedModel,
    candidate: Defaults,
    incumbent: Defaults,
    targets: int = REPORT_TARGETS,
    near_singular: int = NEAR_SINGULAR,
    seed: int = REPORT_SEED,
    progress: Callable[[str], None] = lambda line: None,
    candidate_model: ServedModel | None = None,
    candidate_seed_offset: int = 0,
    draws: int = DRAWS,
) -> Judgement:
    """Both defaults on the same targets and draws, measured against the exact SMMs
    (`ground_truth` refuses a robot without a reference, naming those with one); the
    candidate is worse where a paired test over the targets says so (`verdict`).

    `candidate_model`: another trained network for the same robot and task (a narrower
    one, say) that answers with `candidate`; None: `model`'s own network answers both.
    `candidate_seed_offset`: the candidate's draws of target i sample from the seeds of
    target i + offset (`draw_seed`). The incumbent judged against itself so is the judge's
    own noise: the same sampler on other draws, which the rule should find no worse.
    """
    if draws < 1:
        raise ValueError(f"draws: at least 1, got {draws}")
    if candidate_model is not None:
        check_same_problem(candidate_model, model)
    q_targets = judged_configurations(model, targets, near_singular, seed)
    truths = [ground_truth(model, q, seed + i) for i, q in enumerate(q_targets)]
    periodic = model.limits.periodic
    measured: dict[str, list[list[Measure]]] = {}
    networks = {"candidate": candidate_model or model, "incumbent": model}
    offsets = {"candidate": candidate_seed_offset, "incumbent": 0}
    for name, defaults in (("candidate", candidate), ("incumbent", incumbent)):
        served = serving(networks[name], defaults)
        plural = "s" if draws > 1 else ""
        progress(f"judge: {name} on {len(q_targets)} targets, {draws} draw{plural} each")
        measured[name] = [
            [
                measure(
                    served_target(
                        served, q, defaults.num_samples, seed=draw_seed(i, j, offsets[name])
                    ),
                    truth,
                    periodic,
                )
                for j in range(draws)
            ]
            for i, (q, truth) in enumerate(zip(q_targets, truths, strict=True))
        ]
    ours, theirs = measured["candidate"], measured["incumbent"]
    candidate_figures = pooled([m for row in ours for m in row])
    incumbent_figures = pooled([m for row in theirs for m in row])
    tests = compared(ours, theirs)
    return Judgement(
        targets=targets,
        near_singular_targets=near_singular,
        seed=seed,
        candidate=candidate_figures,
        incumbent=incumbent_figures,
        worse=verdict(candidate_figures, incumbent_figures, tests),
        candidate_seed_offset=candidate_seed_offset,
        draws=draws,
        tests=tests,
    )


def _counts(measured: list[list[Measure]], key: str) -> Counts | None:
    """One side's figure `key` as paired.py reads it; None where an answer lacks it."""
    targets = len(measured)
    if key == "recall":
        if any(m.found is None for row in measured for m in row):
            return None
        found = [
            np.stack([m.found for m in row if m.found is not None], axis=1) for row in measured
        ]
        sums = np.array([f.sum(axis=0) for f in found], dtype=float)  # (T, S)
        units = np.array([len(f) for f in found], dtype=float)  # (T,)
        unit_target = np.repeat(np.arange(targets), [len(f) for f in found])  # (U,)
        return Counts(sums, units, np.concatenate(found), unit_target)
    field_name = {
        "count_right": "right",
        "splits_per_target": "splits",
        "merges_per_target": "merges",
    }[key]
    values = [[getattr(m, field_name) for m in row] for row in measured]
    if any(v is None for row in values for v in row):
        return None
    sums = np.array(values, dtype=float)  # (T, S)
    good = sums > 0 if key == "count_right" else sums == 0  # (T, S)
    return Counts(sums, np.ones(targets), good, np.arange(targets))


def compared(candidate: list[list[Measure]], incumbent: list[list[Measure]]) -> dict[str, Paired]:
    """Each component figure both sides measure (count right, splits, merges, recall),
    paired over the targets (`paired.paired`); `candidate[i][j]`: target i, draw j."""
    tests = {}
    for key, _, more_is_better in TRUTH_FIGURES:
        if key == "coverage_p95_rad":
            continue
        ours, theirs = _counts(candidate, key), _counts(incumbent, key)
        if ours is None or theirs is None or not theirs.units.sum():
            continue
        tests[key] = paired(ours, theirs, more_is_better)
    return tests


def verdict(
    candidate: dict[str, float], incumbent: dict[str, float], tests: dict[str, Paired]
) -> list[str]:
    """The candidate's worse figures, each "name candidate vs incumbent" and why: its
    paired gain more than Z_REFUSE standard errors below zero, or the targets where it lost
    a unit on every draw (paired.py); coverage p95 beyond COVERAGE_MARGIN of the
    incumbent's (it moves ~1-3 % between samplers that find the same components)."""
    worse = []
    for key, name, _ in TRUTH_FIGURES:
        test = tests.get(key)
        if test is None:
            continue
        pair = f"{name} {figure_pair(candidate[key], incumbent[key])}"
        if test.z < -Z_REFUSE:
            worse.append(f"{pair}, {test.gain:+.3g} at z {test.z:.2f} < -{Z_REFUSE}")
        if test.lost_targets:
            worse.append(f"{pair}, lost on every draw on targets {test.lost_targets}")
    coverage = "coverage_p95_rad"
    worse += worse_than(
        {coverage: candidate.get(coverage)}, {coverage: incumbent.get(coverage)}, COVERAGE_MARGIN
    )
    return worse


def check_same_problem(candidate: ServedModel, model: ServedModel) -> None:
    """Raise ValueError unless `candidate` answers `model`'s problem: the same robot, task
    and joints (names and limits), so that both answer the same targets."""
    ours, theirs = model.manifest, candidate.manifest
    for field in ("robot", "task", "joints"):
        if getattr(ours, field) != getattr(theirs, field):
            raise ValueError(
                f"the candidate model {theirs.model_id} differs from {ours.model_id} in "
                f"{field}: {getattr(theirs, field)} against {getattr(ours, field)}; a "
                "candidate network must share robot, task and joints"
            )


def judged_defaults(
    served: ServedModel, swept: Defaults, incumbent: Defaults,
    progress: Callable[[str], None] = lambda line: None, targets: int = REPORT_TARGETS,
) -> Defaults:  # fmt: skip
    """The swept defaults if they serve what the incumbent did or are judged no worse
    against the exact SMMs (`judge`, on `targets` report targets and
    `near_singular_for(targets)` near-singular ones), else the incumbent's; the verdict
    in reasons["judged"]. The sweep's 20 targets cannot see a rare lost component; the
    judge's 200 report targets and 20 near-singular ones can (`smm-train` judges on fewer
    after a small training budget, training/budget.py). A robot without an exact
    reference keeps the swept defaults, its reason saying they were not judged."""
    swept_values = swept.model_dump(exclude={"reasons"})
    incumbent_values = incumbent.model_dump(exclude={"reasons"})
    if swept_values == incumbent_values:
        return swept
    if not has_ground_truth(served):
        reason = (
            f"not judged: no exact reference for robot {served.manifest.robot!r}; the "
            "sweep's agreement with its dense answer alone chose these defaults over the "
            "incumbent's"
        )
        return swept.model_copy(update={"reasons": {**swept.reasons, JUDGED: reason}})
    judgement = judge(
        served, swept, incumbent, targets=targets, near_singular=near_singular_for(targets),
        progress=progress,
    )  # fmt: skip
    changed = _changes(incumbent, swept)
    if judgement.no_worse:
        reason = f"the sweep's change ({changed}) serves: {judgement.summary()}"
        return swept.model_copy(update={"reasons": {**swept.reasons, JUDGED: reason}})
    reason = (
        f"the sweep's change ({changed}) does not serve, the incumbent defaults do: "
        f"{judgement.summary()}; incumbent {_rounded(judgement.incumbent)}, swept "
        f"{_rounded(judgement.candidate)}"
    )
    reasons = {**unserved_reasons(swept, incumbent), **incumbent.reasons, JUDGED: reason}
    return incumbent.model_copy(update={"reasons": reasons})


def unserved_reasons(swept: Defaults, incumbent: Defaults) -> dict[str, str]:
    """The sweep's measures of an axis the incumbent has no reason for (one it was never
    swept on, as the reflow's), to stay beside the incumbent's, marked as not served."""
    return {
        key: f"the sweep's choice, not served (reasons.judged): {text}"
        for key, text in swept.reasons.items()
        if key not in incumbent.reasons
    }


# The reasons (Defaults.reasons keys) that explain each field of the defaults (dotted keys;
# a field not listed has its group's reason: sampler.steps, sampler.round_samples ->
# "sampler").
_REASONS_OF_FIELD: dict[str, tuple[str, ...]] = {
    "num_samples": ("num_samples",),
    "sampler": ("sampler",),
    "sampler.flow": ("sampler_flow",),
    "sampler.precision": ("sampler_precision",),
    "correction_steps": ("correction_steps",),
    "damping": ("damping",),
    "connectivity": ("connectivity",),
    "tolerance_position_m": ("tolerance",),
    "tolerance_orientation_rad": ("tolerance",),
}


def served_candidate(
    incumbent: Defaults, candidate: Defaults, judgement: Judgement, proposal: str
) -> Defaults:
    """`candidate` as it serves once judged no worse than `incumbent`: the verdict in
    reasons["judged"], after the verdicts that set the incumbent (JUDGED_SEPARATOR,
    earliest first), and each reason of a changed field marked, once, as set by a judged
    candidate (the measures it quoted kept after the mark). `proposal` says where the
    candidate came from."""
    if not judgement.no_worse:
        raise ValueError(f"a candidate judged worse does not serve: {judgement.summary()}")
    marked = {
        key: _marked(incumbent.reasons.get(key, "no reason before"))
        for field in _changed(incumbent, candidate)
        for key in _REASONS_OF_FIELD.get(field) or _REASONS_OF_FIELD[field.split(".")[0]]
    }
    changed = _changes(incumbent, candidate)
    verdict = f"{proposal}, changing {changed}, serves: {judgement.summary()}"
    earlier = incumbent.reasons.get(JUDGED)
    verdicts = verdict if earlier is None else JUDGED_SEPARATOR.join([earlier, verdict])
    reasons = {**incumbent.reasons, **marked, JUDGED: verdicts}
    return candidate.model_copy(update={"reasons": reasons})


def _marked(reason: str) -> str:
    """`reason` marked as set by a judged candidate, once."""
    mark = f"set by the judged candidate (reasons.{JUDGED}), not by this rule: "
    return reason if reason.startswith(mark) else mark + reason


def _changed(before: Defaults, after: Defaults) -> dict[str, tuple[object, object]]:
    """The changed values, by dotted key: (old, new)."""
    old = _flat(before.model_dump(exclude={"reasons"}))
    new = _flat(after.model_dump(exclude={"reasons"}))
    return {key: (old[key], new[key]) for key in new if old[key] != new[key]}


def _changes(before: Defaults, after: Defaults) -> str:
    """The changed values, "key old -> new" with dotted keys."""
    changed = _changed(before, after).items()
    return ", ".join(f"{key} {old} -> {new}" for key, (old, new) in changed) or "nothing"


def _flat(values: dict[str, object], prefix: str = "") -> dict[str, object]:
    """Nested settings as dotted keys: {"sampler": {"steps": 4}} -> {"sampler.steps": 4}."""
    flat: dict[str, object] = {}
    for key, value in values.items():
        if isinstance(value, dict):
            flat.update(_flat(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _rounded(figures: dict[str, float]) -> dict[str, float]:
    return {key: float(f"{value:.4g}") for key, value in figures.items()}


def paper_defaults(defaults: Defaults) -> Defaults:
    """The paper's configuration (100 float32 Euler steps of the base flow on the uniform
    grid, 3 DLS steps) with the rest of `defaults`."""
    return defaults.model_copy(
        update={"sampler": PAPER_SAMPLER, "correction_steps": PAPER_DLS_STEPS}
    )


def candidate_defaults(served: Defaults, candidate: str) -> Defaults:
    """`candidate`: "paper" (`paper_defaults`), or a JSON object of the served defaults'
    fields to change, each group of fields ("sampler", "connectivity") merged into the
    served group."""
    if candidate == "paper":
        return paper_defaults(served)
    try:
        update = json.loads(candidate)
    except json.JSONDecodeError as error:
        raise ValueError(
            f"--candidate: 'paper' or a JSON object of defaults to change, got {candidate!r}"
        ) from error
    if not isinstance(update, dict):
        raise ValueError(f"--candidate: a JSON object, got {candidate!r}")
    # Only the fields the served manifest sets, and the candidate's: what --write writes.
    fields = served.model_dump(exclude_unset=True)
    for name, value in update.items():
        group = fields.get(name)
        merged = isinstance(group, dict) and isinstance(value, dict)
        fields[name] = group | value if merged else value
    return Defaults.model_validate(fields)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train judge`."""
    parser.add_argument("--model", required=True, help="a model id under models/")
    parser.add_argument(
        "--candidate", help="paper, or a JSON object: a change of the served defaults"
    )
    parser.add_argument(
        "--candidate-model-dir", type=Path,
        help="another trained model directory of the same robot and task (smm-train "
        "train --models-dir): its network answers, at its own defaults, or with --candidate at "
        "the served defaults so changed ('{}': the served defaults as they are)",
    )  # fmt: skip
    parser.add_argument(
        "--num-samples", type=int, help="both at this num_samples (default: each its own)"
    )
    parser.add_argument("--targets", type=int, default=REPORT_TARGETS)
    parser.add_argument("--near-singular", type=int, default=NEAR_SINGULAR)
    parser.add_argument("--seed", type=int, default=REPORT_SEED)
    parser.add_argument(
        "--draws", type=int, default=DRAWS,
        help=f"answers of each side on each target, other sampling seeds (default {DRAWS}; "
        "at 1 a unit lost once is lost on every draw: no spread to tell a sampler from itself)",
    )  # fmt: skip
    parser.add_argument(
        "--candidate-seed-offset", type=int, default=0,
        help="draw the candidate's samples for target i from seed i + this (default 0: the "
        "incumbent's seeds); with --candidate '{}' the served defaults are judged against "
        "themselves on other draws: the judge's own noise",
    )  # fmt: skip
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, help="write the judgement as JSON here")
    parser.add_argument(
        "--write", action="store_true",
        help="serve the candidate (write it into the model's manifest) if judged no worse",
    )  # fmt: skip
    parser.add_argument("--models-dir", type=Path, default=REPO_MODELS_DIR)


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train judge`: judge the candidate, print (and --out) the judgement, --write it."""
    if args.candidate is None and args.candidate_model_dir is None:
        parser.error("give --candidate, --candidate-model-dir or both")
    if args.draws < 1:
        parser.error(f"--draws: at least 1 answer a target, got {args.draws}")
    if args.write and args.num_samples is not None:
        parser.error("--write serves the candidate as given: leave out --num-samples")
    if args.write and args.candidate_seed_offset:
        parser.error("--write serves the candidate as given: leave out --candidate-seed-offset")
    model_dir = args.models_dir / args.model
    model = load_model(model_dir, threads=args.threads)
    incumbent = model.manifest.defaults
    candidate_model = None
    try:
        if args.candidate_model_dir is not None:
            candidate_model = load_model(args.candidate_model_dir, threads=args.threads)
            check_same_problem(candidate_model, model)
        if args.candidate is not None:
            candidate = candidate_defaults(incumbent, args.candidate)
        else:
            assert candidate_model is not None
            candidate = candidate_model.manifest.defaults
    except ValueError as error:
        parser.error(str(error))
    if args.num_samples is not None:
        incumbent = incumbent.model_copy(update={"num_samples": args.num_samples})
        candidate = candidate.model_copy(update={"num_samples": args.num_samples})
    judgement = judge(
        model, candidate, incumbent, args.targets, args.near_singular, args.seed,
        progress=lambda line: print(line, flush=True), candidate_model=candidate_model,
        candidate_seed_offset=args.candidate_seed_offset, draws=args.draws,
    )  # fmt: skip
    record = {
        "model": args.model,
        "candidate_argument": args.candidate,  # "candidate" below: its figures
        "candidate_model": None if candidate_model is None else candidate_model.reference,
        "num_samples": args.num_samples,
        "candidate_defaults": candidate.model_dump(exclude={"reasons"}),
        "incumbent_defaults": incumbent.model_dump(exclude={"reasons"}),
        **asdict(judgement),
        "z": {key: _finite(test.z) for key, test in judgement.tests.items()},
        "verdict": judgement.summary(),
    }
    text = json.dumps(record, indent=1)
    if args.out:
        args.out.write_text(text + "\n")
    print(text)
    if args.write:
        if not judgement.no_worse:
            raise SystemExit(f"not written: {judgement.summary()}")
        base, what = incumbent, f"the candidate {args.candidate}"
        command = f"smm-train judge --model {args.model}"
        if candidate_model is not None:  # the candidate network serves in the model's place
            command += f" --candidate-model-dir {args.candidate_model_dir}"
            base, what = candidate_model.manifest.defaults, "the candidate network"
            if args.candidate is not None:
                what += f" with {args.candidate}"
            replace_model_directory(model_dir, args.candidate_model_dir)
        if args.candidate is not None:
            command += f" --candidate '{args.candidate}'"
        proposal = f"{what} ({command} --write)"
        write_defaults(model_dir, served_candidate(base, candidate, judgement, proposal))
        print(f"written to {model_dir / MANIFEST_FILE}", flush=True)


def _finite(value: float) -> float | None:
    """`value` for JSON: None for an infinite z (every target's gain the same nonzero one)."""
    return value if math.isfinite(value) else None


def replace_model_directory(model_dir: Path, candidate_dir: Path) -> None:
    """`model_dir`'s files replaced by `candidate_dir`'s (a copy beside it, then renamed)."""
    staging = model_dir.with_name(f".{model_dir.name}.staging")
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copytree(candidate_dir, staging)
    retired = model_dir.with_name(f".{model_dir.name}.retired")
    shutil.rmtree(retired, ignore_errors=True)
    model_dir.rename(retired)
    staging.rename(model_dir)
    shutil.rmtree(retired)
