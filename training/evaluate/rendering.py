"""The report as Markdown: errors beside the paper's Table 2, components against ground
truth (count right, splits, merges), the connect stage's time, the returned paths
(r = 1), exact components found by size, the targets the service got wrong, and which
baselines ran how (the Fourier model's training) or were skipped and why."""

from __future__ import annotations

from typing import Any

from training.evaluate.metrics import COUNT_RIGHT_DEFINITION, COVERAGE_RADIUS_RAD
from training.evaluate.paper import PAPER_TABLE_2
from training.machine import Machine

# Rows whose errors are over every raw point (the flow's samples, the ODE's trace, the
# Fourier prediction) and that judge nothing, so they have no keep rate.
RAW_ROWS = ("FM", "ODE", "Fourier (realtime-smm)")


def _cell(value: object) -> str:
    return "-" if value is None else f"{value:.3g}" if isinstance(value, float) else str(value)


def _table(header: list[str], rows: list[list[object]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(_cell(v) for v in row) + " |" for row in rows]


def _recall_lines(methods: dict[str, dict[str, Any]], size_name: str) -> list[str]:
    rows = [
        [name, bucket["size"], bucket["components"], bucket["recall"]]
        for name, summary in methods.items()
        for bucket in summary.get("recall_by_size", [])
    ]
    if not rows:
        return []
    header = ["method", f"exact component {size_name}", "exact components", "found"]
    return ["", f"Exact components found, by {size_name}:", "", *_table(header, rows)]


def _wrong_count(entry: dict[str, Any]) -> str:
    text = f"{entry['returned']} for {entry['expected']}"
    if "splits" in entry:
        text += f", {entry['splits']} split, {entry['merges']} merged"
    return text


def _listed_targets(report: dict[str, Any]) -> list[str]:
    boundary = report["near_boundary"]
    served = boundary.get("FM + DLS") or {}
    count = served.get("component_count") or {}
    coverage = served.get("coverage_rad") or {}
    lines = [
        "",
        f"Near-boundary targets (outer 10 % of the reach): {boundary['targets']}, indices "
        f"{boundary['indices']}. There the service (FM + DLS) keeps "
        f"{_cell(served.get('keep_rate'))} of its samples, gets the count right on "
        f"{_cell(count.get('right'))} of the targets (too many {_cell(count.get('too_many'))}, "
        f"too few {_cell(count.get('too_few'))}) and covers the exact SMM to p95 "
        f"{_cell(coverage.get('p95'))} rad.",
    ]
    wrong = report.get("wrong_count_targets")
    if wrong is not None:
        listed = ", ".join(f"{w['index']} ({_wrong_count(w)})" for w in wrong[:40])
        more = f", and {len(wrong) - 40} more" if len(wrong) > 40 else ""
        lines.append(
            "Targets whose count is not right (returned for exact"
            + (", splits, merges" if any("splits" in w for w in wrong) else "")
            + f"): {len(wrong)}"
            + (f": {listed}{more}." if wrong else ".")
        )
    missed = report.get("missed_component_targets")
    if missed is not None:
        edges = report["methods"]["FM + DLS"]["recall_by_size"]
        smallest = edges[1]["size"].split("-")[0] if len(edges) > 1 else "0"
        near = set(boundary["indices"])
        listed = ", ".join(
            f"{m['index']}{'*' if m['index'] in near else ''} ({', '.join(map(str, m['sizes']))})"
            for m in missed[:40]
        )
        more = f", and {len(missed) - 40} more" if len(missed) > 40 else ""
        lines.append(
            f"Targets where the service missed an exact component of {report.get('component_size')}"
            f" at least {smallest} (the missed sizes; * near the boundary): {len(missed)}"
            + (f": {listed}{more}." if missed else ".")
        )
    return lines


def _machine_lines(report: dict[str, Any]) -> list[str]:
    """Where the times were measured (older reports did not record it)."""
    if "machine" not in report:
        return []
    machine = Machine.from_json(report["machine"])
    return ["", f"Times measured in process, warm, on: {machine.describe()}."]


def markdown(model_id: str, report: dict[str, Any]) -> str:
    """The report's two tables: errors and time beside the paper's Table 2, then components."""
    methods: dict[str, dict[str, Any]] = report["methods"]
    paper = PAPER_TABLE_2.get(model_id, {})
    error_rows: list[list[object]] = []
    for name, summary in methods.items():
        errors = _method_errors(name, summary)
        quoted = paper.get(name)
        error_rows.append(
            [name, errors["e_p_pct"], errors["e_o_pct"], errors["e_pct"], errors["mm"],
             errors["deg"], None if name in RAW_ROWS else summary["keep_rate"],
             summary["median_time_ms"], ", ".join(_cell(v) for v in quoted) if quoted else None]
        )  # fmt: skip
    component_rows: list[list[object]] = []
    for name, summary in methods.items():
        if "coverage_rad" not in summary:
            continue
        count = summary.get("component_count") or {}
        coverage, precision = summary["coverage_rad"], summary.get("precision_rad") or {}
        component_rows.append(
            [name, count.get("right"), count.get("too_many"), count.get("too_few"),
             summary.get("splits_per_target"), summary.get("merges_per_target"),
             summary.get("extra_small_per_target"), coverage["mean"], coverage["p95"],
             coverage[f"within_{COVERAGE_RADIUS_RAD}"], precision.get("p95"),
             summary["limit_violations"]]
        )  # fmt: skip
    lines = [
        f"# {model_id}: evaluation against ground truth",
        "",
        f"Model `{report['model']}`; {report['targets']} held-out targets (seed {report['seed']}), "
        f"{report['num_samples']} samples (or restarts) per target. Produced by "
        f"`smm-train report --model {model_id} --targets {report['targets']}`.",
        *_machine_lines(report),
        "",
        *_table(
            [
                "method",
                "e_p %",
                "e_o %",
                "e %",
                "mean mm",
                "mean deg",
                "keep rate",
                "median ms",
                "paper (e_p, e_o, e, ms)",
            ],
            error_rows,
        ),
        "",
        *_table(
            [
                "method",
                "count right",
                "too many",
                "too few",
                "splits / target",
                "merges / target",
                "extra small / target",
                "coverage mean rad",
                "coverage p95 rad",
                f"within {COVERAGE_RADIUS_RAD} rad",
                "precision p95 rad",
                "limit violations",
            ],
            component_rows,
        ),
        *_regular_lines(methods),
        *_stage_lines(methods),
        *_path_lines(methods),
        *_recall_lines(methods, report.get("component_size", "size")),
        *_listed_targets(report),
        *_baseline_lines(model_id, report),
        "",
        "Errors: the FM and ODE rows are over every raw sample or trace point, the others over "
        "returned configurations (accepted samples and, for a 1-D SMM, the points of each "
        "component's path). The paper's numbers are from one target, on kept samples only.",
        "",
        "Count right: " + report.get("count_right_definition", COUNT_RIGHT_DEFINITION),
    ]
    return "\n".join(lines) + "\n"


def _baseline_lines(model_id: str, report: dict[str, Any]) -> list[str]:
    """How the Fourier model was trained, when it ran; each skipped method and why, with the
    paper's figures for it where it quotes some."""
    lines: list[str] = []
    training = report.get("fourier_training")
    if training is not None:
        budget, clusters = training.get("budget", {}), training.get("clusters", [])
        wall = training.get("wall_time_s", {})
        lines += [
            "",
            f"Fourier (realtime-smm): Clark and Xie's package {training.get('realtime_smm')} "
            f"(training/evaluate/baselines/fourier.py), trained on {training.get('grid_nodes')} "
            f"targets {budget.get('pos_resolution_m')} m apart on the half-plane line "
            f"({training.get('nodes_ok')} traced), "
            + ", ".join(
                f"{c['branches']} branch{'es' if c['branches'] > 1 else ''} for rho in "
                f"[{c['rho_m'][0]:g}, {c['rho_m'][1]:g}] m ({c['nodes']} targets)"
                for c in clusters
            )
            + f"; {len(budget.get('hidden_dims', []))} x {max(budget.get('hidden_dims', [0]))} "
            f"{budget.get('activation')} networks, {budget.get('epochs')} epochs, FFT cutoff "
            f"{budget.get('fft_cutoff')}; {_cell(wall.get('total'))} s on {training.get('cpus')} "
            f"CPU cores ({_cell(wall.get('grid'))} s grid, {_cell(wall.get('networks'))} s "
            "networks). Its raw row returns every predicted point, one component per predicted "
            "branch; + DLS: the same points after the service's DLS correction and acceptance "
            "(model defaults), branch labels kept (no connect stage); its time includes the "
            "prediction.",
        ]
    for name, why in report.get("skipped", {}).items():
        quoted = [
            f"{row}: e {_cell(values[2])} %, {_cell(values[3])} ms"
            for row, values in PAPER_TABLE_2.get(model_id, {}).items()
            if row.startswith(name)
        ]
        lines += [
            "",
            f"Not run: {name}: {why}."
            + (f" The paper quotes {'; '.join(quoted)}." if quoted else ""),
        ]
    return lines


def _regular_lines(methods: dict[str, dict[str, object]]) -> list[str]:
    """The component figures again over the targets not flagged near-singular."""
    rows = []
    for name, summary in methods.items():
        regular = summary.get("regular_targets")
        if isinstance(regular, dict):
            rows.append([name, regular["targets"], regular["count_right"],
                         regular["splits_per_target"], regular["merges_per_target"]])  # fmt: skip
    if not rows:
        return []
    return [
        "",
        "Over the targets the answer did not flag as near a singular value (`structure."
        "near_singular`; there components may touch, and the answer says so):",
        "",
        *_table(["method", "targets", "count right", "splits / target", "merges / target"], rows),
    ]


def _stage_lines(methods: dict[str, dict[str, Any]]) -> list[str]:
    rows = []
    for name, summary in methods.items():
        median, p95 = summary.get("median_stage_ms") or {}, summary.get("p95_stage_ms") or {}
        if "connect" in median:
            rows.append(
                [name, median["connect"], p95.get("connect"), median.get("total"),
                 p95.get("total"), summary.get("near_singular_targets")]
            )  # fmt: skip
    if not rows:
        return []
    header = ["method", "connect median ms", "connect p95 ms", "total median ms",
              "total p95 ms", "near-singular targets"]  # fmt: skip
    return [
        "",
        "The connect stage (components decided on the fibre), over the targets; near-singular: "
        "the fraction of targets the connect stage flags as near a singular value:",
        "",
        *_table(header, rows),
    ]


def _path_lines(methods: dict[str, dict[str, Any]]) -> list[str]:
    rows = [
        [name, summary["path_points_mean"], summary["path_max_gap_rad"],
         summary.get("path_max_gap_rad_not_near_singular"),
         summary["path_points_outside_limits"], summary["path_max_position_error_m"],
         summary["path_max_orientation_error_rad"]]
        for name, summary in methods.items()
        if "path_points_mean" in summary
    ]  # fmt: skip
    if not rows:
        return []
    header = ["method", "path points / target", "max gap rad",
              "max gap rad, targets not near-singular", "points outside limits",
              "max position error m", "max orientation error rad"]  # fmt: skip
    return [
        "",
        "Returned paths (r = 1): the largest joint-metric step between consecutive points "
        "(closing step of a loop included) over every path, and every path point checked "
        "against the limits and the target:",
        "",
        *_table(header, rows),
    ]


def _method_errors(name: str, summary: dict[str, Any]) -> dict[str, Any]:
    # Raw rows (the flow's samples, the ODE's trace) over every point; the others over
    # what a client gets back.
    return summary["raw"] if name in RAW_ROWS else summary["returned"]


def table_2(reports: dict[str, dict[str, Any]]) -> str:
    """The paper's Table 2 beside ours, and the components against ground truth, per model."""
    rows: list[list[object]] = []
    component_rows: list[list[object]] = []
    for model_id, report in reports.items():
        paper = PAPER_TABLE_2.get(model_id, {})
        for name, summary in report["methods"].items():
            errors = _method_errors(name, summary)
            quoted = paper.get(name, (None,) * 4)
            rows.append([model_id, name, errors["e_p_pct"], errors["e_o_pct"], errors["e_pct"],
                         summary["median_time_ms"], *quoted])  # fmt: skip
            count = summary.get("component_count")
            if count is not None:
                coverage = summary["coverage_rad"]
                median = summary.get("median_stage_ms") or {}
                p95 = summary.get("p95_stage_ms") or {}
                component_rows.append([model_id, name, count["expected_mean"],
                    count["returned_mean"], count["right"], count["too_many"], count["too_few"],
                    summary.get("splits_per_target"), summary.get("merges_per_target"),
                    coverage["p95"], coverage[f"within_{COVERAGE_RADIUS_RAD}"],
                    median.get("connect"), p95.get("connect")])  # fmt: skip
    header = ["model", "method", "e_p %", "e_o %", "e %", "median ms",
              "paper e_p %", "paper e_o %", "paper e %", "paper ms"]  # fmt: skip
    component_header = ["model", "method", "exact components", "returned", "count right",
                        "too many", "too few", "splits / target", "merges / target",
                        "coverage p95 rad", f"within {COVERAGE_RADIUS_RAD} rad",
                        "connect median ms", "connect p95 ms"]  # fmt: skip
    return "\n".join([*_table(header, rows), "", *_table(component_header, component_rows)])
