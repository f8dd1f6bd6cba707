"""Where an answer's Python runs: each phase of the pipeline, its wall time, the compiled
work inside it and the rest.

    python -m tools.phase_profile --model iiwa14-pose --targets 40 \
        --json docs/benchmark/phases-iiwa14-pose.json

Answers held-out targets (uniform configurations in the limits, their FK; seed i for
target i) in process on one thread, after one warm-up answer, with the compiled work
(every call into `service.pipeline.native`, the kinematics of a compiled chain among
them, and the flow network) and every phase of PHASES behind timers. A phase's compiled
time is the compiled calls made while it runs; its Python is the rest of its wall time:
the interpreter and numpy between those calls. That rest is what a batch would have to
share between its targets, or compiled code take over, for a target to cost less than
its compiled work (tools/batch_bounds.py: the compiled bound). Phases nest (the trace's
phases inside `connect`): each is timed whole, and its row names the phase it runs in.
Each target is answered `--repeats` times and the repeat with the least wall time kept;
figures are means per target over the targets. Compare figures only within one run (the
CPU, and what else runs on it, differ between runs and machines).
"""

from __future__ import annotations

import argparse
import functools
import importlib
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from types import ModuleType
from typing import Any

from service.config import Settings
from service.manifest import REPO_MODELS_DIR, bundled_model_ids
from service.models.registry import load_model
from service.pipeline.arrays import FloatArray
from service.pipeline.run import run
from tools.connect_profile import KernelTimer, queries_for
from tools.records import command_line, write_record
from training.checkout import git_commit
from training.evaluate.targets import uniform_configurations
from training.machine import Machine


@dataclass(frozen=True)
class Phase:
    """A function of the pipeline timed as one phase: `function` (a module-level function,
    or `Class.method`) of `module`, wherever the pipeline's modules call it from."""

    label: str
    module: str
    function: str
    # The phase it runs in (for a model that draws its samples at once: one that draws in
    # rounds traces while it samples); None for a stage of the answer.
    inside: str | None


_TRACE = "service.pipeline.connect.trace"
_CONNECT = "service.pipeline.connect"
PHASES: tuple[Phase, ...] = (
    Phase("sample", "service.pipeline.run", "sample", None),
    Phase("correct", "service.pipeline.run", "correct_samples", None),
    Phase("accept", "service.pipeline.space", "FibreSpace.accept", None),
    Phase("connect", f"{_CONNECT}.stage", "connect", None),
    Phase("trace", f"{_TRACE}.run", "trace_fibre", "connect"),
    Phase("walk the fronts", f"{_TRACE}.walk", "walk_fronts", "trace"),
    Phase("refine near the limits", f"{_TRACE}.cut", "refine_near_limits", "trace"),
    Phase("cut by the limits", f"{_TRACE}.cut", "cut_by_limits", "trace"),
    Phase("densify", f"{_TRACE}.densify", "densify", "trace"),
    Phase("exact paths", f"{_CONNECT}.curves", "all_exact_paths", "connect"),
    Phase("paths traced twice", f"{_CONNECT}.curves", "duplicate", "connect"),
    Phase("samples onto paths", f"{_CONNECT}.curves", "owner_path", "connect"),
    Phase("splice", f"{_CONNECT}.splicing", "splice_paths", "connect"),
    Phase("attach by walk", f"{_CONNECT}.splicing", "attach_by_walk", "connect"),
    Phase("free pieces", f"{_CONNECT}.free_pieces", "free_pieces", "connect"),
    Phase("roadmap", f"{_CONNECT}.roadmap", "roadmap_components", "connect"),
    Phase("summarise", "service.pipeline.components", "summarise_all", None),
)


@dataclass
class PhaseTime:
    """A phase's calls and times so far (a call inside a call of the same phase counts
    once, as part of the outer one)."""

    calls: int = 0
    wall_s: float = 0.0
    compiled_s: float = 0.0
    depth: int = 0


def _timed_phase(
    function: Callable[..., Any], spent: PhaseTime, compiled: KernelTimer
) -> Callable[..., Any]:
    @functools.wraps(function)
    def call(*args: Any, **kwargs: Any) -> Any:
        if spent.depth:
            return function(*args, **kwargs)
        spent.depth += 1
        start_s, compiled_s = time.perf_counter(), compiled.seconds
        try:
            return function(*args, **kwargs)
        finally:
            spent.wall_s += time.perf_counter() - start_s
            spent.compiled_s += compiled.seconds - compiled_s
            spent.calls += 1
            spent.depth -= 1

    return call


def _callers(name: str, function: object) -> list[ModuleType]:
    """The pipeline's modules that hold `function` under `name`: where it is defined and
    everywhere it is imported by name (each looks it up there when it calls it)."""
    return [
        module
        for module in list(sys.modules.values())
        if getattr(module, "__name__", "").startswith("service.")
        and getattr(module, name, None) is function
    ]


@contextmanager
def phases_timed(phases: Sequence[Phase], compiled: KernelTimer) -> Iterator[dict[str, PhaseTime]]:
    """Every phase timed while entered (their functions put back after), with the compiled
    time `compiled` counts inside each."""
    spent = {phase.label: PhaseTime() for phase in phases}
    patched: list[tuple[object, str, object]] = []
    try:
        for phase in phases:
            module = importlib.import_module(phase.module)
            owner_name, _, name = phase.function.rpartition(".")
            if owner_name:  # a method, on its class
                owner = getattr(module, owner_name)
                function = owner.__dict__[name]
                owners: list[object] = [owner]
            else:
                function = getattr(module, name)
                owners = [*_callers(name, function)]
            wrapper = _timed_phase(function, spent[phase.label], compiled)
            for holder in owners:
                setattr(holder, name, wrapper)
                patched.append((holder, name, function))
        yield spent
    finally:
        for holder, name, function in reversed(patched):
            setattr(holder, name, function)


@dataclass(frozen=True)
class PhaseRow:
    """One phase's means per target (ms) and calls per target."""

    label: str
    inside: str | None
    calls: float
    wall_ms: float
    compiled_ms: float

    @property
    def python_ms(self) -> float:
        return self.wall_ms - self.compiled_ms


@dataclass(frozen=True)
class Profile:
    model: str  # <model-id>@<version>
    targets: int
    repeats: int
    answer: PhaseRow  # the whole answer (stages 1-6)
    phases: list[PhaseRow]  # as PHASES lists them; those that never ran left out


def profile_phases(
    model_id: str, q_targets: FloatArray, repeats: int = 1, phases: Sequence[Phase] = PHASES
) -> Profile:
    """The phases of each target's answer (the model opened on one thread), each target
    answered `repeats` times and its least-time repeat kept; means per target."""
    model = load_model(
        REPO_MODELS_DIR / model_id, threads=1, compiled_int8=Settings().compiled_int8
    )
    compiled = KernelTimer()
    timed = replace(model, networks={k: compiled.timed(f) for k, f in model.networks.items()})
    queries = queries_for(timed, q_targets)
    run(timed, queries[0])  # warm-up
    keys = ["answer", *(phase.label for phase in phases)]
    totals = {key: [0.0, 0.0, 0.0] for key in keys}  # calls, wall s, compiled s
    with compiled.timing(), phases_timed(phases, compiled) as spent:
        for query in queries:
            best: dict[str, tuple[float, float, float]] | None = None
            for _ in range(repeats):
                before = {k: (t.calls, t.wall_s, t.compiled_s) for k, t in spent.items()}
                start_s, compiled_s = time.perf_counter(), compiled.seconds
                run(timed, query)
                taken: dict[str, tuple[float, float, float]] = {
                    label: (
                        float(t.calls - before[label][0]),
                        t.wall_s - before[label][1],
                        t.compiled_s - before[label][2],
                    )
                    for label, t in spent.items()
                }
                taken["answer"] = (
                    1.0,
                    time.perf_counter() - start_s,
                    compiled.seconds - compiled_s,
                )
                if best is None or taken["answer"][1] < best["answer"][1]:
                    best = taken
            assert best is not None, "repeats must be at least 1"
            for key in keys:
                totals[key] = [a + b for a, b in zip(totals[key], best[key], strict=True)]
    count = len(queries)

    def row(label: str, inside: str | None) -> PhaseRow:
        calls, wall_s, compiled_s = totals[label]
        return PhaseRow(
            label, inside, calls / count, wall_s * 1e3 / count, compiled_s * 1e3 / count
        )

    return Profile(
        model=model.reference,
        targets=count,
        repeats=repeats,
        answer=row("answer", None),
        phases=[row(p.label, p.inside) for p in phases if totals[p.label][0] > 0],
    )


def format_profile(profile: Profile) -> str:
    lines = [
        f"{profile.model}: {profile.targets} targets, least of {profile.repeats} each, "
        "ms per target (in process, one thread)",
        f"{'phase':28s} {'inside':10s} {'calls':>6s} {'wall':>7s} {'compiled':>9s} {'python':>7s}",
    ]
    for r in [profile.answer, *profile.phases]:
        lines.append(
            f"{r.label:28s} {r.inside or '-':10s} {r.calls:6.1f} {r.wall_ms:7.2f} "
            f"{r.compiled_ms:9.2f} {r.python_ms:7.2f}"
        )
    return "\n".join(lines)


def as_json(profile: Profile) -> dict[str, Any]:
    def fields(r: PhaseRow) -> dict[str, Any]:
        return {**asdict(r), "python_ms": r.python_ms}

    return {
        "model": profile.model,
        "targets": profile.targets,
        "repeats": profile.repeats,
        "answer": fields(profile.answer),
        "phases": [fields(r) for r in profile.phases],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    parser.add_argument("--model", default="iiwa14-pose", choices=bundled_model_ids())
    parser.add_argument("--targets", type=int, default=40)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--repeats", type=int, default=3, help="answers per target, least kept")
    parser.add_argument("--json", help="write the record here")
    args = parser.parse_args(argv)
    if args.targets < 1 or args.repeats < 1:
        parser.error("--targets and --repeats must be at least 1")
    machine = Machine.now()
    limits = load_model(REPO_MODELS_DIR / args.model, threads=1).limits
    q_targets = uniform_configurations(limits, args.targets, args.seed)
    profile = profile_phases(args.model, q_targets, args.repeats)
    print(format_profile(profile))
    if args.json:
        record = {
            "command": command_line("tools.phase_profile", argv),
            "git_commit": git_commit(),
            "machine": machine.ended().as_json(),
            "seed": args.seed,
            **as_json(profile),
        }
        write_record(args.json, record)
    return 0


if __name__ == "__main__":
    sys.exit(main())
