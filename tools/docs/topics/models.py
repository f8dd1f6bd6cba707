"""Figure blocks of the models pages: the bundled models, their training and serving
defaults (models/<id>/manifest.json) and their evaluation against exact ground truth
(docs/reports/<id>.json), beside the paper's Table 2.

Tables (no arguments), one row per bundled model (or per model and method):

    models-table       the headline figures of each model's report (README and models.md)
    models-training    network, training budget and wall time, reflow (manifests)
    models-collision   collision model: bodies, spheres, pairs checked, free space lost
    models-sampler     served sampler, DLS steps, raw errors, keep rate (manifests)
    models-components  components against ground truth, service beside the baselines
    models-recall      exact components found, by size
    models-errors      errors and times beside the paper's Table 2

One figure, inline, by a path into the JSON (a dotted path; a list index is a number; a
method's name may be written by its alias, e.g. `fm-dls` for "FM + DLS"):

    report MODEL PATH [FORMAT]          docs/reports/MODEL.json
    reflow-report NAME PATH [FORMAT]    docs/reports/reflow/NAME.json
    manifest MODEL PATH [FORMAT]        models/MODEL/manifest.json
    judge NAME PATH [FORMAT]            docs/benchmark/judge-NAME.json
    report-wrong MODEL                  the targets whose count the service got wrong

FORMAT: 3g (default: three significant digits), 2g, 2f (two decimals), pct (x 100, three significant
digits, " %"), int (rounded, thousands separated), min (seconds as whole minutes), text.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from service.manifest import TaskSpec
from tools.docs import sources
from tools.docs.blocks import block
from training.evaluate.paper import PAPER_TABLE_2
from training.evaluate.references.iiwa14 import MIN_SHARE

# The report's method names, by the alias a marker writes (markers allow no spaces or +).
METHODS = {
    "fm-dls": "FM + DLS",
    "fm": "FM",
    "restart": "random-restart DLS",
    "ode": "ODE",
    "fourier": "Fourier (realtime-smm)",
    "fourier-dls": "Fourier (realtime-smm) + DLS",
}
# Rows over every raw point (the flow's samples, the ODE's trace, the Fourier prediction):
# their errors are the raw ones (as training/evaluate/rendering.py reports them).
RAW_ROWS = ("FM", "ODE", "Fourier (realtime-smm)")
ROBOT_ORDER = ("planar3r", "iiwa14", "panda", "ur5")  # simplest first; others after, by name


# --- reading a figure by its path ---------------------------------------------------------


def _number(value: float, digits: int) -> str:
    if value == 0:
        return "0"
    if abs(value) >= 10**digits:
        return f"{value:,.0f}"
    return f"{value:.{digits}g}"


def _pct(value: float) -> str:
    return f"{_number(100 * value, 3)} %"


FORMATS: dict[str, Callable[[Any], str]] = {
    "3g": lambda v: _number(v, 3),
    "2g": lambda v: _number(v, 2),
    "2f": lambda v: f"{v:.2f}",
    "pct": _pct,
    "int": lambda v: f"{round(v):,}",
    "min": lambda v: f"{v / 60:.0f} min",
    "text": str,
}


def format_value(value: Any, fmt: str = "3g") -> str:
    """`value` written in format `fmt` (a list item by item, joined by commas)."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown figure format {fmt!r}; the formats are: {', '.join(FORMATS)}")
    if value is None:
        return "-"
    if isinstance(value, list):
        return ", ".join(format_value(item, fmt) for item in value)
    if isinstance(value, (bool, str)):
        return str(value)
    if isinstance(value, int) and fmt in ("3g", "2g"):
        return f"{value:,}"
    return FORMATS[fmt](value)


def lookup(data: Any, path: str, where: str) -> Any:
    """The value at the dotted `path` of `data` (`sources.lookup`); a method alias (`fm-dls`)
    names its method, and a path that starts with one looks under `methods`."""
    first = path.split(".")[0]
    if isinstance(data, dict) and "methods" in data:
        if first in METHODS:
            path = f"methods.{path}"
        elif first not in data:
            choices = [*sorted(data), *sorted(METHODS)]
            raise KeyError(f"{where}: no {first!r} at the top level; there are: {choices}")
    return sources.lookup(data, path, where, METHODS)


def judge_record(name: str) -> dict[str, Any]:
    """docs/benchmark/judge-<name>.json: the judge's verdict on a candidate's defaults."""
    if name not in sources.judged():
        raise FileNotFoundError(
            f"docs/benchmark/judge-{name}.json does not exist; there are: {sources.judged()}"
        )
    return sources.benchmark(f"judge-{name}")


@block("report")
def report_figure(model_id: str, path: str, fmt: str = "3g") -> str:
    """One figure of docs/reports/<model_id>.json."""
    return format_value(lookup(sources.report(model_id), path, f"{model_id}.json"), fmt)


@block("reflow-report")
def reflow_figure(name: str, path: str, fmt: str = "3g") -> str:
    """One figure of docs/reports/reflow/<name>.json."""
    return format_value(lookup(sources.report(f"reflow/{name}"), path, f"reflow/{name}.json"), fmt)


@block("manifest")
def manifest_figure(model_id: str, path: str, fmt: str = "3g") -> str:
    """One figure of models/<model_id>/manifest.json."""
    return format_value(lookup(sources.manifest(model_id), path, f"{model_id}/manifest.json"), fmt)


@block("judge")
def judge_figure(name: str, path: str, fmt: str = "3g") -> str:
    """One figure of docs/benchmark/judge-<name>.json."""
    return format_value(lookup(judge_record(name), path, f"judge-{name}.json"), fmt)


@block("report-wrong")
def report_wrong(model_id: str, style: str = "full") -> str:
    """The targets of a report whose component count the service (FM + DLS) got wrong:
    `full`: each index (exact count, returned count: splits, merges); `brief`: the indices
    and how many have a split and how many a merge; "none" if there are none."""
    if style not in ("full", "brief"):
        raise ValueError(f"unknown report-wrong style {style!r}; the styles are: full, brief")
    wrong = sources.report(model_id).get("wrong_count_targets", [])
    if not wrong:
        return "none"
    if style == "brief":
        split = sum(1 for entry in wrong if entry["splits"])
        merged = sum(1 for entry in wrong if entry["merges"])
        indices = ", ".join(str(entry["index"]) for entry in wrong)
        return f"{indices} ({split} with a split, {merged} with a merge)"
    items = []
    for entry in wrong:
        faults = [f"{entry['splits']} split" if entry["splits"] else "",
                  f"{entry['merges']} merged" if entry["merges"] else ""]  # fmt: skip
        detail = ", ".join(f for f in faults if f) or "no split or merge"
        items.append(
            f"{entry['index']} ({entry['expected']} exact, {entry['returned']} returned: {detail})"
        )
    return "; ".join(items)


# --- the tables ---------------------------------------------------------------------------


def bundled_models() -> list[str]:
    """Every bundled model id, the planar arm first, then the iiwa14, then the Panda."""

    def order(model_id: str) -> tuple[int, str]:
        robot = sources.manifest(model_id)["robot"]
        rank = ROBOT_ORDER.index(robot) if robot in ROBOT_ORDER else len(ROBOT_ORDER)
        return rank, model_id

    return sorted(sources.model_ids(), key=order)


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def task_words(manifest: dict[str, Any]) -> str:
    """The task in words: `position (x, y)`, `position (x, y, z)`, `pose` or `axis (tool
    axis [0.0, 0.0, 1.0])`."""
    task = TaskSpec.model_validate(manifest["task"])
    axes = ", ".join("xyz"[i] for i in task.position_axes)
    if task.tool_axis is not None:
        return f"position ({axes}) and tool axis {task.tool_axis}"
    return "pose" if task.orientation else f"position ({axes})"


def redundancy(manifest: dict[str, Any]) -> int:
    """r = n - m: joints less the task's dimension."""
    return len(manifest["joints"]["names"]) - TaskSpec.model_validate(manifest["task"]).dimension


def recall(method: dict[str, Any], component_size: str) -> float | None:
    """The fraction of exact components found, over the components the evaluation counts:
    every one on a 1-D SMM (sized by arc length), those of at least 1 % of a 2-D or 4-D
    fibre (sized by share); None where the reference does not label components (planar 3R)."""
    bins = method.get("recall_by_size")
    if bins is None:
        return None
    if component_size.startswith("share"):
        bins = [b for b in bins if float(b["size"].split("-")[0]) >= MIN_SHARE]
    bins = [b for b in bins if b["components"]]  # an empty size bin has no recall
    total = sum(b["components"] for b in bins)
    return sum(b["components"] * b["recall"] for b in bins) / total


def shared_cores(report: dict[str, Any]) -> bool:
    """Whether other work shared the cores while the report ran (its 1-min load average
    went over the core count + 0.5: training/machine.py's rule), so its times are inflated."""
    machine = report["machine"]
    loads = [x for x in (machine["load_1min_start"], machine.get("load_1min_end")) if x is not None]
    return bool(loads) and max(loads) > machine["cores"] + 0.5


def timed(report: dict[str, Any], ms: float) -> str:
    """A time of `report`, with " *" when other work shared the cores."""
    return _number(ms, 3) + (" *" if shared_cores(report) else "")


def machine_words(reports: list[dict[str, Any]]) -> str:
    """The machine the reports ran on, if they share one: `a 2-core AMD EPYC`. A virtual
    machine's model name is the same on processors of several generations, so reports
    share a machine only where they record the same generation (training/machine.py); a
    report that predates the record shares none with one that has it."""
    machines = {
        (r["machine"]["cores"], r["machine"]["cpu"], r["machine"].get("generation"))
        for r in reports
    }
    if len(machines) != 1:
        return "each report's machine (times compare within one report only)"
    cores, cpu, _ = machines.pop()
    return f"a {cores}-core {cpu}"


def _served(report: dict[str, Any]) -> dict[str, Any]:
    return report["methods"]["FM + DLS"]


@block("models-table")
def models_table() -> str:
    """The headline figures of every bundled model, from its report (the service, FM + DLS,
    200 held-out targets at N = 1000)."""
    rows, reports = [], []
    for model_id in bundled_models():
        manifest, report = sources.manifest(model_id), sources.report(model_id)
        served = _served(report)
        reports.append(report)
        time = timed(report, served["median_time_ms"])
        rows.append([
            f"`{model_id}`", task_words(manifest), str(redundancy(manifest)),
            _pct(served["component_count"]["right"]),
            format_value(recall(served, report["component_size"]), "pct"),
            _number(served["coverage_rad"]["p95"], 3), _pct(served["keep_rate"]), time,
        ])  # fmt: skip
    header = ["model", "task", "r", "count right", "recall", "coverage p95 (rad)",
              "keep rate", "median ms / answer"]  # fmt: skip
    targets = {(r["targets"], r["num_samples"]) for r in reports}
    scope = (
        "{} held-out targets, {} samples each".format(*targets.pop())
        if len(targets) == 1
        else "held-out targets"
    )
    in_rounds = [
        f"`{model_id}`"
        for model_id in bundled_models()
        if sources.manifest(model_id)["defaults"]["sampler"].get("round_samples")
    ]
    if in_rounds:
        scope += (
            f" (at most: {', '.join(in_rounds)} draws in rounds and stops after a round "
            "that finds no new curve; its keep rate is over the samples drawn)"
        )
    legend = (
        f"From each model's evaluation report (`docs/reports/<model>.md`): {scope}, "
        "against exact ground truth. Count right: the targets whose components match the "
        "exact ones (no split, no merge). Recall: the exact components found (for r = 2 and 4 "
        'those of at least 1 % of the fibre; the planar reference has no labels, so "-"). '
        "Coverage p95: 95 % of the exact SMM's points lie this close (joint metric) to a "
        "returned configuration. Keep rate: the share of samples made exact and kept. Time: "
        f"per answer, median, in process, on {machine_words(reports)}"
        + (
            "; * other work shared the cores, so the time is inflated."
            if any(shared_cores(r) for r in reports)
            else "."
        )
    )
    return _table(header, rows) + "\n\n" + legend


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.0f} min"


@block("models-training")
def models_training() -> str:
    """Every bundled model's network and training budget, from its manifest."""
    rows = []
    for model_id in bundled_models():
        manifest = sources.manifest(model_id)
        training, config = manifest["training"], manifest["training"]["config"]
        budget = f"{training['samples']:,} x {training['epochs']} epochs"
        extras = [f"batch {training['batch_size']}", training["device"].upper()]
        if config.get("autocast_bf16"):
            extras.append("bf16 autocast")
        reflow = manifest.get("reflow")
        reflowed = "-"
        if reflow is not None:
            reflowed = (
                f"{reflow['config']['pairs']:,} pairs x {reflow['config']['steps']:,} steps, "
                f"{_minutes(reflow['wall_time_s'])} + {_minutes(reflow['teacher_wall_time_s'])} "
                "for the teacher's pairs"
            )
        rows.append([
            f"`{model_id}`", f"MLP {config['hidden_width']} x {config['hidden_layers']}",
            f"{budget} ({', '.join(extras)})", _minutes(training["wall_time_s"]),
            f"{training['best_validation_loss']:.4f}", reflowed,
        ])  # fmt: skip
    header = ["model", "network", "training data x epochs", "wall time", "best val. loss",
              "reflow (trained, wall time)"]  # fmt: skip
    return _table(header, rows)


@block("models-collision")
def models_collision() -> str:
    """Every bundled model's collision model, from collision.json and its manifest record."""
    rows = []
    for model_id in bundled_models():
        manifest = sources.manifest(model_id)
        record = manifest.get("collision")
        if record is None:
            rows.append([f"`{model_id}`", "none (its URDF has no collision geometry)"]
                        + ["-"] * 4)  # fmt: skip
            continue
        spec = sources.collision(model_id)
        bodies = len(spec["bodies"])
        pairs = bodies * (bodies - 1) // 2
        checked = pairs - len(spec["disabled_pairs"])
        source = "its SRDF" if record["srdf"] else "sampled, as MoveIt's setup assistant"
        vertices = sum(len(hull) for body in spec["bodies"] for hull in body.get("hulls_m", []))
        hulls = f", their hulls {vertices:,} vertices" if vertices else ""
        rows.append([
            f"`{model_id}`", f"{bodies} bodies, {record['sphere_count']} spheres{hulls}",
            f"{checked} of {pairs}", source,
            f"{100 * record['free_space_lost_fraction']:.2g} % of "
            f"{record['configurations_sampled']:,}",
            f"{record['wall_time_s']:.1f} s",
        ])  # fmt: skip
    header = ["model", "collision model", "body pairs checked", "pairs never checked from",
              "free space lost (random configurations)", "build time"]  # fmt: skip
    return _table(header, rows)


def sampler_words(sampler: dict[str, Any]) -> str:
    """A served sampler in words: `int8, 4 Euler steps, time power 2`."""
    flow = "reflowed " if sampler.get("flow", "base") == "reflow" else ""
    grid = "uniform" if sampler["time_power"] == 1.0 else f"time power {sampler['time_power']:g}"
    return f"{flow}{sampler['precision']}, {sampler['steps']} Euler steps, {grid}"


def raw_row(manifest: dict[str, Any], steps: int, flow: str = "base") -> dict[str, Any]:
    """The manifest's raw-error row measured at `steps` Euler steps of `flow`."""
    for row in manifest["quality"]["raw"]:
        if row["sampler_steps"] == steps and row.get("sampler_flow", "base") == flow:
            return row
    measured = [
        (r["sampler_steps"], r.get("sampler_flow", "base")) for r in manifest["quality"]["raw"]
    ]
    raise LookupError(
        f"{manifest['model_id']}: no raw error at {steps} {flow} steps; there are {measured}"
    )


def raw_words(row: dict[str, Any]) -> str:
    """Mean raw error: position in mm and % of the reach, orientation in deg and % of pi."""
    mm, pct = row["position_error_mm_mean"], row["position_error_pct_reach_mean"]
    words = f"{_number(mm, 3)} mm = {pct:.2f} %"
    if row.get("orientation_error_deg_mean") is not None:
        words += (
            f"; {_number(row['orientation_error_deg_mean'], 3)} deg"
            f" = {row['orientation_error_pct_mean']:.2f} %"
        )
    return words


PAPER_SAMPLER_STEPS = 100  # the paper's sampler: 100 uniform float32 Euler steps


@block("models-sampler")
def models_sampler() -> str:
    """Every bundled model's served sampler and correction, the raw error of its flow at that
    sampler and at the paper's, the best of 1000 samples, and its keep rate (manifests)."""
    rows = []
    for model_id in bundled_models():
        manifest = sources.manifest(model_id)
        defaults = manifest["defaults"]
        sampler = defaults["sampler"]
        served = raw_row(manifest, sampler["steps"], sampler.get("flow", "base"))
        paper = raw_row(manifest, PAPER_SAMPLER_STEPS)
        best = (
            f"{served['best_of_n_position_error_pct_reach_mean']:.2g} % / "
            f"{paper['best_of_n_position_error_pct_reach_mean']:.2g} %"
        )
        rows.append([
            f"`{model_id}`", f"{manifest['reach_m']:.3g}", sampler_words(sampler),
            str(defaults["correction_steps"]), str(defaults["num_samples"]),
            raw_words(served), raw_words(paper), best, _pct(manifest["quality"]["keep_rate"]),
        ])  # fmt: skip
    samples = {sources.manifest(m)["quality"]["samples_per_target"] for m in bundled_models()}
    best_of = f"best of {samples.pop()}" if len(samples) == 1 else "best of N"
    header = ["model", "reach m", "served sampler", "DLS steps", "default samples",
              "raw error, served sampler", "raw error, paper's sampler", best_of,
              "keep rate"]  # fmt: skip
    return _table(header, rows)


@block("models-components")
def models_components() -> str:
    """Components against ground truth, every method of every report that groups
    components (the service and the baselines run through the same stages)."""
    rows = []
    for model_id in bundled_models():
        report = sources.report(model_id)
        for name, method in report["methods"].items():
            count = method.get("component_count")
            if count is None:
                continue
            median = method.get("median_stage_ms") or {}
            p95 = method.get("p95_stage_ms") or {}
            connect = "-"
            if "connect" in median:
                connect = f"{_number(median['connect'], 3)} / {timed(report, p95['connect'])}"
            rows.append([
                f"`{model_id}`", name, _number(count["expected_mean"], 3),
                _number(count["returned_mean"], 3), _pct(count["right"]),
                format_value(method.get("splits_per_target")),
                format_value(method.get("merges_per_target")),
                format_value(recall(method, report["component_size"]), "pct"),
                _number(method["coverage_rad"]["p95"], 3),
                format_value(method.get("near_singular_targets"), "pct"), connect,
                timed(report, method["median_time_ms"]),
            ])  # fmt: skip
    header = ["model", "method", "exact / target", "returned / target", "count right",
              "splits / target", "merges / target", "recall", "coverage p95 rad",
              "flagged near-singular", "connect ms median / p95", "answer ms median"]  # fmt: skip
    return _table(header, rows)


@block("models-recall")
def models_recall() -> str:
    """Exact components found by the service and by random-restart DLS, by size (arc length
    on a 1-D SMM, share of the fibre on a 2-D or 4-D one), from every report that labels
    them; a size with no exact component has no row."""
    rows = []
    for model_id in bundled_models():
        report = sources.report(model_id)
        served = _served(report).get("recall_by_size")
        if served is None:
            continue
        restart = report["methods"].get("random-restart DLS", {}).get("recall_by_size")
        share = report["component_size"].startswith("share")
        for i, size in enumerate(served):
            if not size["components"]:  # no exact component of this size: no row
                continue
            span = size_words(size["size"], share)
            restart_found = _pct(restart[i]["recall"]) if restart else "-"
            rows.append([f"`{model_id}`", span, f"{size['components']:,}",
                         _pct(size["recall"]), restart_found])  # fmt: skip
    header = ["model", "exact component size", "exact components", "found by the service",
              "found by random-restart DLS"]  # fmt: skip
    return _table(header, rows)


def size_words(size: str, share: bool) -> str:
    """A report's size bin ("0.5-2", "0.01-0.1", "2-inf") in words."""
    low, high = (float(x) for x in size.split("-"))
    scale, unit = (100, " % of the fibre") if share else (1, " rad")
    low_words, high_words = _number(scale * low, 2), _number(scale * high, 2)
    if low == 0:
        return f"under {high_words}{unit}"
    if high == float("inf"):
        return f"over {low_words}{unit}"
    return f"{low_words}-{high_words}{unit}"


def method_errors(name: str, method: dict[str, Any]) -> dict[str, Any]:
    """A raw row's errors are over every raw point, the others' over what is returned."""
    return method["raw"] if name in RAW_ROWS else method["returned"]


@block("models-errors")
def models_errors() -> str:
    """Errors (% of the reach; orientation % of pi) and median time per target, every
    method of every report, beside the paper's figure for the same row where it has one."""
    rows = []
    for model_id in bundled_models():
        paper = PAPER_TABLE_2.get(model_id, {})
        report = sources.report(model_id)
        for name, method in report["methods"].items():
            errors = method_errors(name, method)
            quoted = paper.get(name, (None,) * 4)
            ours = [format_value(errors[k]) for k in ("e_p_pct", "e_o_pct", "e_pct")]
            rows.append([
                f"`{model_id}`", name, *ours, timed(report, method["median_time_ms"]),
                *(format_value(q) for q in quoted),
            ])  # fmt: skip
    header = ["model", "method", "e_p %", "e_o %", "e %", "median ms", "paper e_p %",
              "paper e_o %", "paper e %", "paper ms"]  # fmt: skip
    return _table(header, rows)
