"""Figure blocks of the Speed and Operations pages, from the committed benchmark reports.

    <!-- figures: bench models.iiwa14-pose.sizes.1000.service.median_ms -->   one figure
    <!-- figures: bench-machine -->                  the machine and commit a report ran on
    <!-- figures: speed-table -->                    every model at N = 1000, every configuration
    <!-- figures: speed-goals -->                    each speed goal against the report
    <!-- figures: speed-bound iiwa14-pose -->        what bounds a model's time goal
    <!-- figures: speed-stages -->                   where the service's time goes
    <!-- figures: speed-batch -->                    the batch against single requests
    <!-- figures: speed-judged paper-iiwa14-pose-n1000 -->  a judge's record, side by side
    <!-- figures: speed-verdicts planar3r-position -->  the judge's verdicts on its defaults
    <!-- figures: bench-rows 1000 report=n1000-iiwa14-pose-planar3r/benchmark -->  raw rows
    <!-- figures: replicas -->                       CPU time per request and pods per load
    <!-- figures: replicas-example iiwa14-pose 100 -->  pods for a load of one model
    <!-- figures: load-table -->                     the load test (docs/benchmark/load.json)
    <!-- figures: load-models -->                    its latency per model
    <!-- figures: model-default correction_steps --> a served default, every model
    <!-- figures: parallel-min-rows -->              the least rows a flow call runs on all threads
    <!-- figures: compiled-parallel-min-rows -->     the same, on the compiled 512-wide int8 layers
    <!-- figures: int8-exactness -->                 onnxruntime's int8 against the exact network
    <!-- figures: network-floor -->                  the AVX2 product's peak, the layers against it
    <!-- figures: phases -->                         an answer's Python and compiled work by phase
    <!-- figures: batch-processes -->                a batch on threads and on processes

Options are `key=value` words: `report=NAME` reads docs/benchmark/NAME.json (default
`benchmark`, the benchmark of record), `n=N` a size other than the goals' N, `fmt=SPEC` a
Python format spec for `bench`. In `bench` paths the configurations are written by their
short names: service, float32, base, paper, restart, http.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import yaml

from service.models import int8_mlp
from service.models.sessions import PARALLEL_MIN_ROWS
from tools.batch_bounds import (
    BATCH_STAGES,
    compiled_bound,
    compiled_sentence,
    cpu_bound,
    cpu_sentence,
    network_bound,
    network_sentence,
    processes_sentence,
    same_work_bound,
    same_work_sentence,
    stage_bound,
)
from tools.docs import sources
from tools.docs.blocks import block
from tools.goals import (
    BASE,
    BATCH_GOAL_X,
    CONFIGURATIONS,
    DEFAULT_REQUEST,
    FLOAT32,
    GOAL_NUM_SAMPLES,
    GOALS,
    HTTP_GOALS,
    PAPER,
    RESTART,
    SERVICE,
    SSIK,
    bound_label,
    bound_num_samples,
    http_bound,
    timed_run,
)
from training.evaluate.compare import TRUTH_FIGURES, worse_than
from training.evaluate.paired import Z_REFUSE, together
from training.machine import Machine

# Short names for the configurations a report keys by their long names.
ALIASES = {
    "service": SERVICE,
    "default": DEFAULT_REQUEST,
    "float32": FLOAT32,
    "base": BASE,
    "paper": PAPER,
    "restart": RESTART,
    "ssik": SSIK,
    "http": "http",
}
STAGES = ("sample", "correct", "connect")
# The truth figures (training.evaluate.compare's) and their names in the tables.
TABLE_NAMES = {"splits_per_target": "splits / target", "merges_per_target": "merges / target"}
TRUTH = tuple((key, TABLE_NAMES.get(key, name)) for key, name, _ in TRUTH_FIGURES)
DEPLOYMENT = sources.ROOT / "deploy" / "base" / "deployment.yaml"
AUTOSCALER = sources.ROOT / "deploy" / "base" / "hpa.yaml"


# -- reading ---------------------------------------------------------------------------


def options(arguments: tuple[str, ...], allowed: dict[str, str]) -> dict[str, str]:
    """`key=value` words over `allowed` defaults; an unknown key lists the valid ones."""
    chosen = dict(allowed)
    for word in arguments:
        key, sep, value = word.partition("=")
        if not sep or key not in allowed:
            raise ValueError(
                f"unknown option {word!r}; the options are: {sorted(allowed)} (key=value)"
            )
        chosen[key] = value
    return chosen


def lookup(data: Any, path: str, where: str) -> Any:
    """`data` at the dotted `path`, configurations by their short names (`sources.lookup`)."""
    return sources.lookup(data, path, where, ALIASES)


def model_entry(report: dict[str, Any], model_id: str, name: str) -> dict[str, Any]:
    models = report["models"]
    if model_id not in models:
        raise KeyError(f"{name}: no model {model_id!r}; there are: {sorted(models)}")
    return models[model_id]


def size_row(entry: dict[str, Any], n: int, name: str) -> dict[str, Any]:
    sizes = entry["sizes"]
    if str(n) not in sizes:
        raise KeyError(f"{name}: no N = {n}; there are: {sorted(sizes, key=int)}")
    return sizes[str(n)]


# -- writing ---------------------------------------------------------------------------


def auto(value: Any, key: str = "") -> str:
    """A figure as the pages write it: ms to 0.1, counts whole, other numbers to 3
    significant digits, booleans as yes / no, None as -."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if key.endswith("_ms"):
            return f"{value:.1f}"
        return f"{value:.3g}"
    return str(value)


def ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def _whole(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def sampler_words(flow: str, steps: int, precision: str) -> str:
    """`base flow, 4 int8 steps`."""
    kind = "reflowed" if flow == "reflow" else "base flow"
    return f"{kind}, {steps} {precision} step{'s' if steps != 1 else ''}"


def cpu_time_ms(row: dict[str, Any]) -> float:
    """t, the CPU time one request costs a server: the default request's CPU time in
    process plus what HTTP adds to the wall time (over-HTTP median less in-process median,
    at least 0)."""
    asked = timed_run(row)
    added = max(row["http"]["median_ms"] - asked["median_ms"], 0.0)
    return float(asked["cpu_median_ms"]) + added


def pod_cores() -> float:
    """The pod's CPU limit (deploy/base/deployment.yaml)."""
    deployment = yaml.safe_load(DEPLOYMENT.read_text())
    (container,) = deployment["spec"]["template"]["spec"]["containers"]
    return float(container["resources"]["limits"]["cpu"])


def autoscaler_target() -> float:
    """The autoscaler's CPU utilisation target, as a fraction (deploy/base/hpa.yaml)."""
    hpa = yaml.safe_load(AUTOSCALER.read_text())
    (metric,) = hpa["spec"]["metrics"]
    return float(metric["resource"]["target"]["averageUtilization"]) / 100.0


# -- blocks ----------------------------------------------------------------------------


@block("parallel-min-rows")
def parallel_min_rows() -> str:
    """The fewest rows a flow call runs on every thread (service/models/sessions.py)."""
    return str(PARALLEL_MIN_ROWS)


@block("compiled-parallel-min-rows")
def compiled_parallel_min_rows() -> str:
    """The fewest rows a call of the compiled 512-wide int8 layers runs on two threads
    (service/models/int8_mlp.py)."""
    return str(int8_mlp.PARALLEL_MIN_WORK // 512)


@block("int8-exactness")
def int8_exactness() -> str:
    """onnxruntime's int8 velocities against the exact quantised network's, per bundled
    network, on the machine of docs/benchmark/int8-exactness.json (`tools.int8_exactness`)."""
    report = sources.benchmark("int8-exactness")
    machine = Machine.from_json(report["machine"]).describe()
    product = "exact" if report["onnxruntime_exact"] else "saturating (neither VNNI nor AMX)"
    times = ", ".join(f"{t:g}" for t in report["times"])
    lead = (
        f"Measured by `{report['command']}` on {machine}: onnxruntime's int8 product there "
        f"is {product}, the compiled layers run on {report['kernel'].upper()}; "
        f"{report['rows_per_call']} rows per call at t = {times}:\n\n"
    )
    rows = [
        [r["model"], f"`{r['network']}`", f"{r['largest_difference']:.3g}",
         f"{r['largest_velocity']:.3g}", f"{100 * r['rows_differing_share']:.1f} %"]
        for r in report["results"]
    ]  # fmt: skip
    header = ["model", "network", "largest difference", "largest velocity", "rows differing"]
    return lead + table(header, rows)


@block("network-floor")
def network_floor() -> str:
    """The AVX2 product's peak on the machine of docs/benchmark/network-floor.json
    (`tools.network_floor`), the compiled layers against it, and the least time each
    model's default request's network work can take there, beside its time goal."""
    report = sources.benchmark("network-floor")
    machine = Machine.from_json(report["machine"]).describe()
    served = report["served_kernel"].upper()
    lead = (
        f"Measured by `{report['command']}` on {machine}, where the service serves the "
        f"{served} kernel: vpmaddwd alone does "
        f"{report['peak_every_core_per_s'] / 1e9:.1f} G integer products a second on its "
        f"{report['cores']} cores at once.\n\n"
    )
    rows = []
    for r in report["results"]:
        goal = "-" if r["goal_ms"] is None else f"{r['goal_ms']:g}"
        out = "" if r["goal_ms"] is None or r["floor_ms"] <= r["goal_ms"] else " (over)"
        rows.append([
            r["model"], f"`{r['network']}`", f"{r['products_per_row']:,}",
            f"{r['call_ms']:.1f}", f"{r['efficiency']:.0%}",
            f"{r['evaluations']} x {r['least_rows']}", f"{r['floor_ms']:.1f}{out}", goal,
        ])  # fmt: skip
    header = [
        "model", "network", "products a row", f"layers ms ({report['results'][0]['rows']} "
        "rows, one core)", "of the peak", "evaluations x rows", "floor ms", "goal ms",
    ]  # fmt: skip
    return lead + table(header, rows)


@block("bench")
def bench(path: str, *arguments: str) -> str:
    """One figure of a report at a dotted path, e.g.
    `models.iiwa14-pose.sizes.1000.service.median_ms` or `batch.singles_over_batch`."""
    chosen = options(arguments, {"report": "benchmark", "fmt": ""})
    value = lookup(sources.benchmark(chosen["report"]), path, f"{chosen['report']}.json")
    if chosen["fmt"]:
        return format(value, chosen["fmt"])
    return auto(value, path.rsplit(".", 1)[-1])


@block("bench-machine")
def bench_machine(*arguments: str) -> str:
    """The machine a report ran on (CPU, cores, Python, load average) and its onnxruntime
    threads per session, as one phrase (the commit it ran at is in the report itself: a
    page says what is measured, not the history of the code)."""
    chosen = options(arguments, {"report": "benchmark"})
    report = sources.benchmark(chosen["report"])
    own = str(report.get("command", "")).startswith(
        ("python -m tools.soak", "python -m tools.load")
    )
    own_load = "the run's own server and clients load the cores, by design" if own else None
    text = Machine.from_json(report["machine"]).describe(own_load)
    if "onnx_threads" in report:
        threads = report["onnx_threads"]
        text += f", {threads} onnxruntime thread{'s' if threads != 1 else ''} per session"
    return text


@block("speed-table")
def speed_table(*arguments: str) -> str:
    """Every model at N (the goals' N by default), medians over the report's targets: the
    service (and its CPU time), the default request (self-collision checked), the service
    with the other network or flow, the paper's
    configuration and its ratio to the service, random-restart DLS, ssik's closed-form
    charts where the report has them, over HTTP, and the count right of the service and
    of the paper's configuration."""
    chosen = options(arguments, {"report": "benchmark", "n": str(GOAL_NUM_SAMPLES)})
    report, n = sources.benchmark(chosen["report"]), int(chosen["n"])
    rows = []
    for model_id, entry in report["models"].items():
        row = size_row(entry, n, chosen["report"])
        service, paper = row[SERVICE], row[PAPER]
        served = sampler_words(
            entry.get("sampler_flow", "base"), entry["sampler_steps"], entry["sampler_precision"]
        )
        other = "-"
        if FLOAT32 in row:
            other = f"float32 network: {ms(row[FLOAT32]['median_ms'])}"
        elif BASE in row:
            other = f"base flow: {ms(row[BASE]['median_ms'])}"
        cpu = service.get("cpu_median_ms")
        asked = row.get(DEFAULT_REQUEST)
        rows.append([
            f"`{model_id}`", served,
            f"**{ms(service['median_ms'])}**" + ("" if cpu is None else f" ({ms(cpu)})"),
            "-" if asked is None else ms(asked["median_ms"]),
            other,
            f"{ms(paper['median_ms'])} ({paper['median_ms'] / service['median_ms']:.1f}x)",
            ms(row[RESTART]["median_ms"]) if RESTART in row else "-",
            _ssik_cell(row),
            ms(row["http"]["median_ms"]) if "http" in row else "-",
            f"{service['figures']['count_right']:.3g} / {paper['figures']['count_right']:.3g}",
        ])  # fmt: skip
    header = ["model", "sampler", "service ms (CPU ms)", "default request ms",
              "other network or flow ms",
              "paper's configuration ms (x service)", "random-restart DLS ms",
              "ssik charts ms (count right)", "over HTTP ms",
              "count right (service / paper's)"]  # fmt: skip
    return table(header, rows)


def _ssik_cell(row: dict) -> str:
    """ssik's closed-form charts cut to the limits, where the report ran them: the median
    time to its in-limit intervals and its count right."""
    if SSIK not in row:
        return "-"
    charts = row[SSIK]
    return f"{ms(charts['median_ms'])} ({charts['figures']['count_right']:.3g})"


@block("speed-goals")
def speed_goals(*arguments: str) -> str:
    """Each speed goal (tools/goals.py) against the report: the default request's time at
    N = 1000 and at the model's served default N where it differs, the ratio to the paper's
    configuration (kinematic answers both),
    truth no worse than the paper's configuration on the same targets, and the batch
    against single requests."""
    chosen = options(arguments, {"report": "benchmark"})
    report = sources.benchmark(chosen["report"])
    rows = []
    for model_id, most_ms, least_x in GOALS:
        if model_id not in report["models"]:
            continue
        entry = report["models"][model_id]
        row = size_row(entry, GOAL_NUM_SAMPLES, chosen["report"])
        service, paper = row[SERVICE], row[PAPER]
        took = timed_run(row)["median_ms"]
        rows.append([
            f"`{model_id}`", f"at most {most_ms:g} ms", f"{took:.1f} ms",
            "yes" if took <= most_ms else f"no, {took / most_ms:.2f}x the goal",
        ])  # fmt: skip
        default_row = _served_default_row(entry)
        if default_row is not None:
            n, at_default = default_row
            took_there = timed_run(at_default)["median_ms"]
            rows.append([
                f"`{model_id}`", f"at most {most_ms:g} ms at its served default N = {n}",
                f"{took_there:.1f} ms",
                "yes" if took_there <= most_ms else f"no, {took_there / most_ms:.2f}x the goal",
            ])  # fmt: skip
        if least_x is not None:  # the kinematic answers: the question both answer
            x = paper["median_ms"] / service["median_ms"]
            rows.append([
                f"`{model_id}`", f"at least {least_x:g}x faster than the paper's configuration",
                f"{x:.1f}x", "yes" if x >= least_x else "no",
            ])  # fmt: skip
        http_goal = dict(HTTP_GOALS).get(model_id)
        http_rows = [("", row)]
        if default_row is not None:
            http_rows.append((f" at its served default N = {default_row[0]}", default_row[1]))
        for where, measured in http_rows:
            if http_goal is None or "http" not in measured:
                continue
            over_http = measured["http"]["median_ms"]
            rows.append([
                f"`{model_id}`", f"over HTTP at most {http_goal:g} ms{where}",
                f"{over_http:.1f} ms",
                "yes" if over_http <= http_goal else f"no, {over_http / http_goal:.2f}x the goal",
            ])  # fmt: skip
        lost = worse_than(service["figures"], paper["figures"])
        rows.append([
            f"`{model_id}`", "truth no worse than the paper's configuration",
            "; ".join(lost) if lost else "no worse", "no" if lost else "yes",
        ])  # fmt: skip
    for key, name in (("batch", "default"), ("batch_one_thread", "one thread")):
        if key in report:
            batch = report[key]
            x = batch["singles_over_batch"]
            rows.append([
                f"batch of {batch['targets']}, {name}",
                f"at least {BATCH_GOAL_X:g}x faster than single requests", f"{x:.2f}x",
                "yes" if x >= BATCH_GOAL_X else "no",
            ])  # fmt: skip
    return table(["model", "goal", "measured", "met"], rows)


def _served_default_row(entry: dict[str, Any]) -> tuple[int, dict[str, Any]] | None:
    """The model's served default N and its row, where that N is not the goals' and the
    report measured it (reports from before it recorded the default have none)."""
    n = entry.get("default_num_samples")
    if n is None or n == GOAL_NUM_SAMPLES or str(n) not in entry["sizes"]:
        return None
    return int(n), entry["sizes"][str(n)]


@block("speed-bound")
def speed_bound(model_id: str, *arguments: str) -> str:
    """What bounds a model's time goal: its stages at N = 1000, or at its served default
    where that is fewer (`bound_num_samples`), then either the stage that alone passes the
    goal or the network evaluations the other stages leave for sampling, the connect stage
    profiled alone, and where its HTTP goal is not met, the time outside the pipeline."""
    chosen = options(arguments, {"report": "benchmark"})
    report = sources.benchmark(chosen["report"])
    goals = {goal[0]: goal[1] for goal in GOALS}
    if model_id not in goals:
        raise KeyError(f"no time goal for {model_id!r}; the goals are for: {sorted(goals)}")
    most_ms = goals[model_id]
    entry = model_entry(report, model_id, chosen["report"])
    asked = timed_run(size_row(entry, bound_num_samples(entry), chosen["report"]))
    took, stage = asked["median_ms"], asked["median_stage_ms"]
    spans = {name: stage.get(name, 0.0) for name in STAGES}
    steps = entry["sampler_steps"]
    per_evaluation = spans["sample"] / steps
    lines = [
        f"- **{took:.1f} ms** at {bound_label(entry)}, against the goal's {most_ms:g} ms: "
        f"sample {spans['sample']:.1f} "
        f"({steps} evaluations of the {entry['sampler_precision']} network, "
        f"{per_evaluation:.2f} ms each), correct {spans['correct']:.1f}, connect "
        f"{spans['connect']:.1f}, the rest {max(took - sum(spans.values()), 0.0):.1f} ms."
    ]
    slowest = max(STAGES, key=lambda name: spans[name])
    if spans[slowest] >= most_ms:
        lines.append(
            f"- The {slowest} stage alone takes {spans[slowest] / most_ms:.1f}x the goal: "
            f"nothing else meets it without a cheaper {slowest} stage."
        )
    else:
        rest = took - spans["sample"]
        left = most_ms - rest
        evaluations = max(math.floor(left / per_evaluation), 0)
        lines.append(
            f"- Everything but sampling takes {rest:.1f} ms, which leaves "
            f"{max(left, 0.0):.1f} ms for sampling: {evaluations} network evaluation"
            f"{'s' if evaluations != 1 else ''}, where the sampler takes {steps}."
        )
    profile = entry.get("connect_profile")
    if profile:
        n = profile.get("num_samples")
        at = "the model's default N" if n is None else f"N = {n}"
        head = (
            f"- The connect stage profiled alone (the service's threads, the same targets at "
            f"{at}): "
            f"{profile['connect_ms']:.1f} ms, of which "
        )
        if "kernels_ms" in profile:  # tools/connect_profile times the compiled kernels
            lines.append(
                f"{head}the compiled kernels on its own thread {profile['kernels_ms']:.1f} ms in "
                f"{profile['kernel_calls']:.0f} calls; the rest is the stage's own Python and "
                "numpy between those calls."
            )
        else:  # a report from before the kernels: the kinematics behind a timer
            lines.append(
                f"{head}the kinematics {profile['kinematics_ms']:.1f} ms in "
                f"{profile['kinematics_calls']:.0f} calls over "
                f"{profile['configurations_evaluated']:.0f} configurations; the rest is the "
                "stage's own array work between those calls."
            )
    http_goal = dict(HTTP_GOALS).get(model_id)
    over_http = None if http_goal is None else http_bound(entry, http_goal)
    if over_http is not None:
        lines.append(f"- {over_http[0].upper()}{over_http[1:]}")
    return "\n".join(lines)


@block("speed-stages")
def speed_stages(*arguments: str) -> str:
    """The service's stages at N = 1000 (medians over the targets) in ms and as shares of
    its median, and one evaluation of the flow network (sample over Euler steps)."""
    chosen = options(arguments, {"report": "benchmark", "n": str(GOAL_NUM_SAMPLES)})
    report, n = sources.benchmark(chosen["report"]), int(chosen["n"])
    rows = []
    for model_id, entry in report["models"].items():
        service = size_row(entry, n, chosen["report"])[SERVICE]
        stage, took = service["median_stage_ms"], service["median_ms"]
        steps = entry["sampler_steps"]
        rows.append([
            f"`{model_id}`",
            sampler_words(entry.get("sampler_flow", "base"), steps, entry["sampler_precision"]),
            f"{stage['sample'] / steps:.1f}",
            *(f"{stage[s]:.1f} ({100 * stage[s] / took:.0f} %)" for s in STAGES),
            f"{took:.1f}",
        ])  # fmt: skip
    header = ["model", "sampler", "ms per network evaluation", "sample ms (%)",
              "correct ms (%)", "connect ms (%)", "whole answer ms"]  # fmt: skip
    return table(header, rows)


@block("speed-batch")
def speed_batch(*arguments: str) -> str:
    """The batch against its targets sent one by one (default, and one thread), where the
    default batch's time goes per target, and the ratio sampling and transport alone
    leave."""
    chosen = options(arguments, {"report": "benchmark"})
    report = sources.benchmark(chosen["report"])
    if "batch" not in report:
        names = sources.names(sources.BENCHMARK)
        with_batch = [r for r in names if "batch" in sources.benchmark(r)]
        raise KeyError(f"{chosen['report']}.json has no batch; reports with one: {with_batch}")
    batch = report["batch"]
    threads = batch.get("batch_threads", "cores // workers")
    runs = [(f"default (`SMM_BATCH_THREADS=0`: {threads} threads here)", batch)]
    if "batch_one_thread" in report:
        runs.append(("one thread (`SMM_BATCH_THREADS=1`)", report["batch_one_thread"]))

    def whole(run: dict[str, Any]) -> list[str]:
        """The batch read as one JSON object (reports from before it was measured: -)."""
        if "batch_json_median_ms" not in run:
            return ["-", "-"]
        return [f"{run['batch_json_median_ms']:.0f}", f"{run['singles_over_batch_json']:.2f}x"]

    rows = [
        [name, f"{run['singles_median_ms']:.0f}", f"{run['batch_median_ms']:.0f}",
         f"{run['singles_over_batch']:.2f}x", *whole(run), "yes" if run["identical"] else "no"]
        for name, run in runs
    ]  # fmt: skip
    first = table(
        ["server", "singles median ms", "batch median ms, read as lines", "singles / batch",
         "read as one JSON object, ms", "singles / that", "same answers"],
        rows,
    )  # fmt: skip
    bound = stage_bound(batch)
    second = table(
        ["singles", "batch", *BATCH_STAGES, "outside"],
        [[f"{bound.singles_ms:.1f}", f"{bound.batch_ms:.1f}",
          *(f"{bound.stage_ms[s]:.1f}" for s in BATCH_STAGES), f"{bound.outside_ms:.1f}"]],
    )  # fmt: skip
    cpu = cpu_bound(batch)
    one = report.get("batch_one_thread")
    one_cpu = None if one is None else cpu_bound(one)
    network = network_bound(batch)
    compiled = compiled_bound(batch)
    same_work = same_work_bound(batch)
    return (
        f"{first}\n\nWhere the default batch's time goes, ms per target (each target's own "
        f"stages, {bound.at_once} targets at a time; outside: the client's wall time less the "
        "server's total, i.e. HTTP, validation and JSON at both ends):\n\n"
        f"{second}\n\nWith correction, connection and summaries free, sampling "
        f"({bound.at_once} targets at a time) and what lies outside the pipeline would still "
        f"take {bound.floor_ms:.1f} ms per target: at most **{bound.most_x:.1f}x** the singles."
        + ("" if cpu is None else f"\n\n{cpu_sentence(cpu, one_cpu)}")
        + ("" if compiled is None else f"\n\n{compiled_sentence(compiled)}")
        + ("" if same_work is None else f"\n\n{same_work_sentence(same_work)}")
        + ("" if network is None else f"\n\n{network_sentence(network)}")
    )


@block("speed-judged")
def speed_judged(name: str) -> str:
    """docs/benchmark/judge-<name>.json side by side: the incumbent's and the candidate's
    defaults (their connectivity settings where the two differ; the model, where it
    differs) and truth figures, each component figure's paired gain and z where the
    record holds them (training/evaluate/paired.py), and the verdict, with the rule of a
    record of one draw a target that holds no paired tests."""
    if name not in sources.judged():
        raise FileNotFoundError(
            f"no docs/benchmark/judge-{name}.json; the records are: {sources.judged()}"
        )
    record = sources.benchmark(f"judge-{name}")
    tests = record.get("tests") or {}

    def defaults(side: str) -> str:
        d = record[f"{side}_defaults"]
        sampler = d["sampler"]
        words = sampler_words(sampler.get("flow", "base"), sampler["steps"], sampler["precision"])
        rounds = sampler.get("round_samples")
        drawn = f"N = {d['num_samples']}" + (f" in rounds of {rounds}" if rounds else "")
        call_rows = sampler.get("call_rows")
        drawn += f", calls of at most {call_rows} rows" if call_rows else ""
        other = record["incumbent_defaults" if side == "candidate" else "candidate_defaults"]
        connectivity = [
            f", {key} {value}"
            for key, value in d["connectivity"].items()
            if other["connectivity"].get(key) != value
        ]
        return f"{words}, {d['correction_steps']} DLS, {drawn}" + "".join(connectivity)

    def gain(key: str) -> list[str]:
        if not tests:
            return []
        if key not in tests:
            return ["-"]
        test, z = tests[key], record["z"][key]
        lost = f", lost on targets {test['lost_targets']}" if test["lost_targets"] else ""
        z_text = "inf" if z is None else f"{z:.2f}"
        return [f"{test['gain']:+.3g} (z {z_text}){lost}"]

    blank = [""] if tests else []
    rows = [["defaults", defaults("incumbent"), defaults("candidate"), *blank]]
    if record.get("candidate_model"):
        rows.append(["model", "served", f"`{record['candidate_model']}`", *blank])
    if offset := record.get("candidate_seed_offset"):
        rows.append(["sampling seed of target i", "i", f"i + {offset}", *blank])
    for key, label in TRUTH:
        if key in record["incumbent"] or key in record["candidate"]:
            rows.append([
                label, auto(record["incumbent"].get(key)), auto(record["candidate"].get(key)),
                *gain(key),
            ])  # fmt: skip
    targets = record["targets"] + record["near_singular_targets"]
    draws = record.get("draws", 1)
    plural = "s" if draws > 1 else ""
    header = [f"{targets} targets (seed {record['seed']}), {draws} draw{plural} each",
              "incumbent", "candidate"] + (["candidate's gain (z)"] if tests else [])  # fmt: skip
    rule = "" if tests else " (one draw a target, refused on any figure worse)"
    return table(header, rows) + f"\n\nVerdict{rule}: the candidate is {record['verdict']}."


@block("speed-judged-together")
def speed_judged_together(*names: str) -> str:
    """docs/benchmark/judge-<name>.json of one candidate on independent target sets (their
    seeds), each component figure's z combined (training/evaluate/paired.py `together`:
    Stouffer's), and whether the sets together refuse it on any."""
    missing = [n for n in names if n not in sources.judged()]
    if len(names) < 2 or missing:
        raise FileNotFoundError(
            f"speed-judged-together needs two judge records or more, not {missing or names}; "
            f"the records are: {sources.judged()}"
        )
    records = [sources.benchmark(f"judge-{name}") for name in names]
    candidates = {json.dumps(r["candidate_defaults"], sort_keys=True) for r in records}
    seeds = [r["seed"] for r in records]
    if len(candidates) > 1 or len(set(seeds)) < len(seeds):
        raise ValueError(f"{names}: not one candidate on target sets of different seeds")
    refused, parts = [], []
    for key, label in TRUTH:
        if not all(key in r.get("z", {}) for r in records):
            continue
        z = together([r["z"][key] for r in records])
        parts.append(f"{label} {z:+.2f}")
        if z < -Z_REFUSE:
            refused.append(label)
    seeds_words = " and ".join(str(s) for s in seeds)
    verdict = f"refused on {', '.join(refused)}" if refused else "no worse on any component figure"
    return (
        f"The {len(records)} target sets (seeds {seeds_words}) together, z = sum z / sqrt "
        f"{len(records)} (Stouffer's; refused below -{Z_REFUSE}): {'; '.join(parts)}. "
        f"Together the candidate is {verdict}."
    )


def _short_names(words: str) -> list[str]:
    """`service,base` -> its configurations' short names; an unknown one lists them."""
    names = [w for w in words.split(",") if w]
    unknown = [w for w in names if w not in ALIASES or w == "http"]
    if unknown:
        valid = [a for a in ALIASES if a != "http"]
        raise KeyError(f"no configuration {unknown}; the configurations are: {valid}")
    return names


@block("bench-rows")
def bench_rows(n: str, *arguments: str) -> str:
    """Every configuration (or `configurations=service,base`) of every model (or of
    `models=a,b`) at N: median, stages and truth, as the report has them."""
    chosen = options(arguments, {"report": "benchmark", "models": "", "configurations": ""})
    report = sources.benchmark(chosen["report"])
    wanted = [m for m in chosen["models"].split(",") if m] or list(report["models"])
    names = [ALIASES[c] for c in _short_names(chosen["configurations"])] or list(CONFIGURATIONS)
    rows = []
    for model_id in wanted:
        entry = model_entry(report, model_id, chosen["report"])
        row = size_row(entry, int(n), chosen["report"])
        for name in names:
            if name not in row:
                continue
            run, stage = row[name], row[name]["median_stage_ms"] or {}
            label = name
            if name == SERVICE:
                label += ": " + sampler_words(
                    entry.get("sampler_flow", "base"), entry["sampler_steps"],
                    entry["sampler_precision"],
                )  # fmt: skip
            rows.append([
                f"`{model_id}`", label, f"{run['median_ms']:.1f}", f"{run['p95_ms']:.1f}",
                ms(stage.get("sample", stage.get("solve"))), ms(stage.get("correct")),
                ms(stage.get("connect")),
                *(auto((run["figures"] or {}).get(key)) for key, _ in TRUTH),
            ])  # fmt: skip
    header = ["model", "configuration", "median ms", "p95 ms", "sample", "correct", "connect",
              *(label for _, label in TRUTH)]  # fmt: skip
    return table(header, rows)


@block("replicas")
def replicas(*arguments: str) -> str:
    """Per model at N = 1000: in-process median (CPU ms), over-HTTP median, t (CPU ms plus
    what HTTP adds to the wall time), and the requests per second one core and one pod
    (deploy/base/deployment.yaml's CPU limit) can answer, 1000 / t and cores x 1000 / t."""
    chosen = options(arguments, {"report": "benchmark", "n": str(GOAL_NUM_SAMPLES)})
    report, n = sources.benchmark(chosen["report"]), int(chosen["n"])
    cores = pod_cores()
    rows = []
    for model_id, entry in report["models"].items():
        row = size_row(entry, n, chosen["report"])
        t, asked = cpu_time_ms(row), timed_run(row)
        rows.append([
            f"`{model_id}`",
            f"{asked['median_ms']:.1f} ({asked['cpu_median_ms']:.1f})",
            f"{row['http']['median_ms']:.1f}", f"{t:.1f}", f"{1000 / t:.1f}",
            f"{cores * 1000 / t:.1f}",
        ])  # fmt: skip
    header = ["model", "in process ms (CPU ms)", "over HTTP ms", "t ms", "requests/s per core",
              f"per {cores:g}-CPU pod"]  # fmt: skip
    return table(header, rows)


@block("replicas-example")
def replicas_example(model_id: str, load: str, *arguments: str) -> str:
    """The pods a steady `load` (requests/s) of one model needs: load x t cores busy, over
    the pod's cores at the autoscaler's target, rounded up."""
    chosen = options(arguments, {"report": "benchmark", "n": str(GOAL_NUM_SAMPLES)})
    report = sources.benchmark(chosen["report"])
    entry = model_entry(report, model_id, chosen["report"])
    t_s = cpu_time_ms(size_row(entry, int(chosen["n"]), chosen["report"])) / 1000
    rate = float(load)
    cores, target = pod_cores(), autoscaler_target()
    busy = rate * t_s
    pods = math.ceil(busy / (cores * target))
    return (
        f"{rate:g} requests/s of `{model_id}` keep {rate:g} x {t_s:.4f} = {busy:.1f} cores "
        f"busy: ceil({busy:.1f} / ({cores:g} x {target:g})) = **{pods} pods**"
    )


@block("load-table")
def load_table(*arguments: str) -> str:
    """docs/benchmark/load.json: per run (clients), requests, answers per second, latency
    of the answers, errors, 503s, and the server's resident memory before and after."""
    chosen = options(arguments, {"report": "load"})
    report = sources.benchmark(chosen["report"])
    rows = []
    for run in report["runs"]:
        rss = run.get("server_rss_mib") or {}
        rows.append([
            str(run["clients"]), f"{run['duration_s']:g} s", str(run["requests"]),
            f"{run['throughput_rps']:.2f}", f"{run['p50_ms']:.0f}", f"{run['p95_ms']:.0f}",
            f"{run['p99_ms']:.0f}", f"**{run['errors']}**", str(run["rejected_503"]),
            " -> ".join(f"{v:.0f}" for v in rss.values()) or "-",
        ])  # fmt: skip
    header = ["clients", "duration", "requests", "answered / s", "p50 ms", "p95 ms", "p99 ms",
              "errors", "503s", "server RSS MiB (start -> end)"]  # fmt: skip
    return table(header, rows)


@block("load-models")
def load_models(*arguments: str) -> str:
    """docs/benchmark/load.json: per model, the median latency of its answers in each run
    (whole ms)."""
    chosen = options(arguments, {"report": "load"})
    runs = sources.benchmark(chosen["report"])["runs"]
    models = sorted({m for run in runs for m in run["by_model"]})
    rows = [
        [f"`{m}`", *(_whole(run["by_model"].get(m, {}).get("p50_ms")) for run in runs)]
        for m in models
    ]
    return table(["model", *(f"p50 ms, {run['clients']} clients" for run in runs)], rows)


@block("speed-verdicts")
def speed_verdicts(model_id: str, *arguments: str) -> str:
    """The judge's verdicts on the cheaper configurations tried for a model (its manifest's
    `defaults.reasons.judged` when the report ran), one bullet each, or a line saying none."""
    chosen = options(arguments, {"report": "benchmark"})
    entry = model_entry(sources.benchmark(chosen["report"]), model_id, chosen["report"])
    verdicts = entry.get("judged") or []
    if not verdicts:
        return f"- The judge has no verdict on `{model_id}`'s defaults."
    # Each verdict ends with both sides' figures as a dict; the worse ones are named before.
    return "\n".join(f"- {verdict.split('; incumbent {')[0]}" for verdict in verdicts)


@block("model-default")
def model_default(path: str, *models: str) -> str:
    """A served default (models/<id>/manifest.json, `defaults.<path>`) over every bundled
    model or those named: one value where they agree, else `value (models), ...`."""
    chosen = list(models) or sources.model_ids()
    unknown = sorted(set(chosen) - set(sources.model_ids()))
    if unknown:
        raise KeyError(f"no model {unknown}; the models are: {sources.model_ids()}")
    by_value: dict[str, list[str]] = {}
    for model_id in chosen:
        value = lookup(sources.manifest(model_id)["defaults"], path, f"{model_id} defaults")
        by_value.setdefault(auto(value), []).append(model_id)
    if len(by_value) == 1:
        return next(iter(by_value))
    return ", ".join(f"{value} ({', '.join(ids)})" for value, ids in by_value.items())


@block("soak-goals")
def soak_goals(*arguments: str) -> str:
    """docs/benchmark/soak.json: the soak's three goals, each with what was measured."""
    chosen = options(arguments, {"report": "soak"})
    record = sources.benchmark(chosen["report"])
    v = record["verdicts"]
    settle_min = v["settle_s"] / 60

    def met(value: bool | None) -> str:
        return "not measured" if value is None else ("yes" if value else "**no**")

    rows = [
        [
            f"RSS after {settle_min:g} min within 5 % above its value at {settle_min:g} min",
            f"{v['rss_at_settle_mib']:.1f} MiB at {settle_min:g} min; after it "
            f"{v['rss_min_after_mib']:.1f} to {v['rss_max_after_mib']:.1f} MiB "
            f"(x{v['rss_min_ratio']:.3f} to x{v['rss_max_ratio']:.3f})",
            met(v["rss_goal_met"]),
        ],
        [
            f"single p99 over the last {record['settings']['p99_span_s'] / 60:g} min within "
            f"10 % of its p99 over the {record['settings']['p99_span_s'] / 60:g} min up to "
            f"minute {settle_min:g}",
            f"{v['single_p99_at_settle_ms']:.0f} ms -> {v['single_p99_last_ms']:.0f} ms "
            f"(x{v['single_p99_ratio']:.3f})",
            met(v["p99_goal_met"]),
        ],
        [
            "(no goal) the machine's speed: the speed probe's median over the same two spans "
            "(the same Python work in the soak's own process; a slower machine slows it, a "
            "slower server does not), and the p99's change over the probe's: the latency's "
            "drift with the machine's speed taken out",
            _probe(v),
            "-",
        ],
        [
            f"(no goal) RSS trend after {settle_min:g} min: least-squares slope, and the median "
            "RSS of the first and last ten minutes after it",
            _rss_trend(record["windows"], v["settle_s"]),
            "-",
        ],
        [
            "no 5xx other than 503",
            f"{v['server_errors']} in {v['requests']} requests ({v['errors']} errors of any kind)",
            met(v["server_errors_goal_met"]),
        ],
    ]
    return table(["goal", "measured", "met"], rows)


def _probe(v: dict[str, Any]) -> str:
    if v.get("probe_at_settle_ms") is None or v.get("probe_last_ms") is None:
        return "not taken in this run"
    probe = (
        f"{v['probe_at_settle_ms']:.2f} ms -> {v['probe_last_ms']:.2f} ms (x{v['probe_ratio']:.3f})"
    )
    if not v.get("single_p99_ratio") or not v["probe_ratio"]:
        return probe
    net = v["single_p99_ratio"] / v["probe_ratio"]
    return f"{probe}; the single p99's ratio over it: x{net:.3f}"


def _rss_trend(windows: list[dict[str, Any]], settle_s: float) -> str:
    """The RSS readings after `settle_s`: their least-squares slope in MiB per hour, and
    the median reading of the first and of the last ten of them."""
    after = [w for w in windows if w["end_s"] > settle_s and w["rss_mib"] is not None]
    if len(after) < 2:
        return "-"
    minutes = np.array([w["end_s"] / 60 for w in after])
    rss = np.array([w["rss_mib"] for w in after])
    slope = float(np.polyfit(minutes, rss, 1)[0]) * 60
    first, last = float(np.median(rss[:10])), float(np.median(rss[-10:]))
    return f"{slope:+.1f} MiB per hour; median {first:.1f} MiB, then {last:.1f} MiB"


@block("soak-timeline")
def soak_timeline(*arguments: str) -> str:
    """docs/benchmark/soak.json: every `every`-th window (default 10): its end, the
    server's RSS, requests, single p50/p99, p50/p99 in a scene (a record that sent
    requests in a scene) and batch p50/p99 in that window, and the speed probe taken at
    its end."""
    chosen = options(arguments, {"report": "soak", "every": "10"})
    record = sources.benchmark(chosen["report"])
    every = int(chosen["every"])
    windows = record["windows"]
    shown = [w for w in windows if (w["index"] + 1) % every == 0 or w is windows[-1]]
    if windows and windows[0] not in shown:
        shown.insert(0, windows[0])
    scenes = all("scene_p50_ms" in w for w in windows)  # a record that sent them
    rows = [
        [
            f"{w['end_s'] / 60:g}", _whole(w["rss_mib"]), str(w["requests"]),
            _whole(w["single_p50_ms"]), _whole(w["single_p99_ms"]),
            *([_whole(w["scene_p50_ms"]), _whole(w["scene_p99_ms"])] if scenes else []),
            _whole(w["batch_p50_ms"]), _whole(w["batch_p99_ms"]),
            "-" if w.get("probe_ms") is None else f"{w['probe_ms']:.2f}",
        ]
        for w in shown
    ]  # fmt: skip
    return table(
        ["minute", "RSS MiB", "requests", "single p50 ms", "single p99 ms",
         *(["scene p50 ms", "scene p99 ms"] if scenes else []), "batch p50 ms",
         "batch p99 ms", "probe ms"],
        rows,
    )  # fmt: skip


@block("batch-processes")
def batch_processes(*arguments: str) -> str:
    """docs/benchmark/batch-processes-<model>.json (`tools.batch_processes`): the same
    targets in process one after another, on the service's batch threads and on as many
    processes, and what sharing one process costs the threads, with the command and the
    machine that measured it."""
    chosen = options(arguments, {"report": "batch-processes-iiwa14-pose"})
    record = sources.benchmark(chosen["report"])
    machine = Machine.from_json(record["machine"]).describe()
    return f"Measured by `{record['command']}` on {machine}: {processes_sentence(record)}"


@block("phases")
def phases(*arguments: str) -> str:
    """docs/benchmark/phases-<model>.json (`tools.phase_profile`): the answer and each of
    its phases, ms per target: wall, compiled, Python, and the phase's share of the
    answer's Python; a phase inside another is indented under it. Then the largest share
    of a phase with none timed inside it."""
    chosen = options(arguments, {"report": "phases-iiwa14-pose"})
    record = sources.benchmark(chosen["report"])
    answer = record["answer"]
    depth: dict[str, int] = {}  # each label's indentation
    rows = []
    for row in [answer, *record["phases"]]:
        level = 0 if row["inside"] is None else depth[row["inside"]] + 1
        depth[row["label"]] = level
        name = f"{'&nbsp;&nbsp;' * 2 * level}{row['label']}"
        rows.append(
            [
                name if row is not answer else "**the answer**",
                f"{row['calls']:.1f}",
                f"{row['wall_ms']:.2f}",
                f"{row['compiled_ms']:.2f}",
                f"{row['python_ms']:.2f}",
                f"{100 * row['python_ms'] / answer['python_ms']:.0f} %",
            ]
        )
    parents = {row["inside"] for row in record["phases"]}
    leaves = [row for row in record["phases"] if row["label"] not in parents]
    largest = max(leaves, key=lambda row: row["python_ms"])
    share = 100 * largest["python_ms"] / answer["python_ms"]
    return (
        table(
            ["phase", "calls", "wall ms", "compiled ms", "Python ms", "of the answer's Python"],
            rows,
        )
        + f"\n\nOf the phases with no phase timed inside them, the one with the most Python "
        f"({largest['label']}) holds {share:.0f} % of the answer's."
    )
