"""Speed benchmark: every bundled model, warm, on one machine in one run, with the truth.

    python -m tools.benchmark                      # -> docs/benchmark/benchmark.{json,md}
    python -m tools.benchmark --models iiwa14-pose --sizes 1000 --targets 5 --no-http
    python -m tools.benchmark --render             # benchmark.md again from benchmark.json

For each model and N in --sizes and the model's served default N (its manifest's
num_samples, what a request without num_samples gets), over a fixed target set (the
evaluation's held-out targets: FK of configurations uniform in the limits, seed 7, the
first --targets):

- the service's pipeline in process, with the model's defaults and the onnxruntime
  threads the service itself would use on this machine (`Settings`), median and p95 of
  the whole answer and of each stage;
- the same with the float32 flow network where the defaults serve the int8 one (what
  int8 alone changes, in time and in truth);
- the paper's configuration (100 uniform Euler steps, fp32, 3 DLS steps) run by the same
  code, the same way;
- random-restart DLS (pytorch-kinematics, uniform restarts, then the service's own stages
  after its correction: the pull into the limits for r > 1, acceptance, and the connect
  stage with the model's coaxial sets) to the same number of valid configurations as the
  service returned: the restarts are scaled by the measured yield, and the run that
  reaches it is the one timed;
- for a full pose of an arm that ssik has (iiwa14, Panda), ssik's closed-form charts
  (training/evaluate/references/ssik_charts.py): every IK branch cut to the limits, timed
  to the in-limit intervals, with points along the arcs at the path spacing for the
  figures (timed apart as "points");
- the service's default request (self-collision checked, as a client asks without
  options): what the time goals read, timed, not judged (its components are the free
  pieces of the fibre, where the exact truth is the fibre's);
- the same default request over HTTP: `smm-serve` as a real uvicorn process on
  127.0.0.1 (default settings), one request at a time, the client's wall time per answer,
  each sent right after the same request in process;
- many targets in one request: --batch-targets (64) targets of --batch-model as one
  POST /smm/batch against as many POST /smm sent one after another, every batch answer
  checked equal to its single answer (`tools.batch_benchmark`).

For each speed goal not met (tools/goals.py): by how much, and what bounds it, at N = 1000
or at the model's served default where that is fewer (`bound_num_samples`), from the same
run: the stage that alone passes the time goal, or the evaluations of the network that
the other stages leave for sampling; the connect stage's profile on the same targets
(`tools.connect_profile`); the judge's verdicts on the cheaper configurations tried (the
manifest's reasons); the truth figures that are worse, and on the judge's larger target
set where a judgement of the paper's configuration is committed beside the report.

The in-process configurations answer each target in turn, target by target, so that a
drift in the machine's speed over the run moves them alike and leaves their ratios.

Beside every time, the evaluation's figures for that configuration on the same targets
(training/evaluate: count right, splits and merges per target, recall of the exact
components, coverage p95), so that speed and truth are read together. The report names
the machine and its load; compare times only within one report.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from service.client import RetryPolicy, SmmClient
from service.config import Settings
from service.manifest import REPO_MODELS_DIR, Manifest, bundled_model_ids
from service.models.registry import (
    ONNX_FLOW,
    ServedModel,
    compiled_flow,
    int8_flow_here,
    int8_on_compiled_layers,
    load_model,
)
from service.pipeline.joint_space import JointLimits
from service.wire import SmmRequest
from tools.batch_benchmark import batch_against_singles, target_of
from tools.batch_bounds import (
    BATCH_STAGES,
    compiled_bound,
    compiled_sentence,
    cpu_bound,
    cpu_sentence,
    network_bound,
    network_sentence,
    same_work_bound,
    same_work_sentence,
    stage_bound,
)
from tools.connect_profile import profile_connect
from tools.connect_profile import summarise as summarise_connect
from tools.goals import (
    BASE,
    BATCH_GOAL_X,
    BATCH_NUM_SAMPLES,
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
from tools.local_server import LocalServer
from tools.network_floor import avx2_network_products, every_core_peak
from tools.records import command_line, write_record
from training.checkout import git_commit
from training.evaluate.compare import better_than, worse_than
from training.evaluate.judge import JUDGED_SEPARATOR, figures, paper_defaults
from training.evaluate.methods import MethodTarget, restart_target, served_target, ssik_target
from training.evaluate.metrics import median_stage_ms, p95_stage_ms
from training.evaluate.references.ssik_charts import supported as ssik_supports
from training.evaluate.served import serving, with_defaults
from training.evaluate.targets import uniform_configurations
from training.evaluate.truth import ground_truth
from training.kinematics import load_chain
from training.machine import Machine
from training.robots import robot_spec

ROOT = Path(__file__).resolve().parents[1]
OUT_DIR = ROOT / "docs" / "benchmark"
SIZES = (250, 1000, 4000)
COMPILED_ON_AMX = compiled_flow("amx")
MATCH_ROUNDS = 4  # rescaled restart runs at most, to reach the service's valid count


@dataclass(frozen=True)
class Timed:
    """One configuration over the targets: its answers as the evaluation reads them."""

    answers: list[MethodTarget]
    # Process CPU time per answer (every thread: onnxruntime's workers too), ms; what a
    # core is busy for, where the wall time of a multi-threaded network is less.
    cpu_ms: list[float] | None = None

    def times(self) -> dict[str, object]:
        total = [a.time_ms for a in self.answers]
        stages = [a.stage_ms for a in self.answers if a.stage_ms]
        return {
            "median_ms": float(np.median(total)),
            "p95_ms": float(np.percentile(total, 95)),
            "cpu_median_ms": None if self.cpu_ms is None else float(np.median(self.cpu_ms)),
            "median_stage_ms": median_stage_ms(stages) if stages else None,
            "p95_stage_ms": p95_stage_ms(stages) if stages else None,
            "valid_configurations_mean": float(np.mean([a.kept for a in self.answers])),
        }


def interleaved(
    served: dict[str, ServedModel],
    restart_model: ServedModel | None,
    q_targets: np.ndarray,
    num_samples: int,
    over_http: OverHttp | None = None,
) -> dict[str, Timed]:
    """Each configuration's answers, target by target: for each target, every configuration
    in `served` in turn (with the process CPU time of each answer; `DEFAULT_REQUEST` asks
    with self-collision checked, as a request without options does, and with `over_http`
    the same request goes over HTTP right after it, cold then warm, its times kept
    there), then, with
    `restart_model`, random-restart DLS to the first configuration's valid count for
    that target (`RESTART`). The HTTP request follows its in-process twin, not restart
    DLS: right after restart DLS the server's answer took about 3 ms longer than the same
    answer in process (iiwa14 pose, N = 500), right after the twin about 0.7 ms. Taking
    the configurations in turn per target, rather than one after another over all
    targets, leaves their ratios unmoved by the machine's drift in speed over the run
    (measured here at up to 29 % between runs)."""
    restart = None if restart_model is None else RestartMatch(restart_model, num_samples)
    charts = restart_model is not None and ssik_covers(restart_model)
    for name, model in served.items():  # warm-up
        served_target(model, q_targets[0], num_samples, seed=0, check_self=name == DEFAULT_REQUEST)
    if charts and restart_model is not None:
        ssik_target(restart_model, q_targets[0])
    if over_http is not None:
        over_http.warm_up(q_targets[0])
    answers: dict[str, list[MethodTarget]] = {name: [] for name in served}
    cpu_ms: dict[str, list[float]] = {name: [] for name in served}
    restarts: list[MethodTarget] = []
    closed_form: list[MethodTarget] = []
    first = next(iter(served))
    for i, q in enumerate(q_targets):
        for name, model in served.items():
            start_s = time.process_time()
            asked = name == DEFAULT_REQUEST
            answers[name].append(served_target(model, q, num_samples, seed=i, check_self=asked))
            cpu_ms[name].append((time.process_time() - start_s) * 1e3)
            if asked and over_http is not None:
                over_http(q, seed=i, q_before=q_targets[i - 1])
        if restart is not None:
            restarts.append(restart(q, answers[first][-1].kept, seed=i))
        if charts and restart_model is not None:
            closed_form.append(ssik_target(restart_model, q))
    timed = {name: Timed(answers[name], cpu_ms[name]) for name in served}
    if restart is not None:
        timed[RESTART] = Timed(restarts)
    if closed_form:
        timed[SSIK] = Timed(closed_form)
    return timed


def ssik_covers(model: ServedModel) -> bool:
    """Whether ssik's closed-form charts answer the model's targets: a full pose of an arm
    ssik has, with ssik installed (the `train` extra)."""
    manifest = model.manifest
    return (
        manifest.task.name == "pose" and manifest.redundancy == 1 and ssik_supports(manifest.robot)
    )


class RestartMatch:
    """Random-restart DLS (pytorch-kinematics) on one model's chain, run to a valid count."""

    def __init__(self, model: ServedModel, num_samples: int) -> None:
        robot = robot_spec(model.manifest.robot)
        self.model, self.num_samples = model, num_samples
        self.chain = load_chain(
            REPO_MODELS_DIR / robot.urdf, robot.end_effector_link, robot.base_link
        )
        self.warmed = False

    def __call__(self, q_target: np.ndarray, wanted: int, seed: int) -> MethodTarget:
        """At least `wanted` valid configurations: from num_samples restarts, the restarts
        are scaled by the measured yield (and 10 % more) until a run has enough (at most
        MATCH_ROUNDS rescaled runs); that run is the one timed."""
        if not self.warmed:
            restart_target(self.model, self.chain, q_target, min(self.num_samples, 100), seed)
            self.warmed = True
        restarts = self.num_samples
        answer = restart_target(self.model, self.chain, q_target, restarts, seed=seed)
        for _ in range(MATCH_ROUNDS):
            if answer.kept >= wanted:
                break
            restarts = int(np.ceil(1.1 * restarts * wanted / max(answer.kept, 1)))
            answer = restart_target(self.model, self.chain, q_target, restarts, seed=seed)
        return answer


class OverHttp:
    """One model's requests over HTTP at one N: the client's wall time per answer and the
    server's own total, one request at a time, on a warm server and on a cold one.

    The client is the project's (`service.client.SmmClient`, retries off): a wall time
    ends with the answer parsed into its typed model, as a Python planner gets it. The
    request is the default one (no options but N and the seed), the question
    `DEFAULT_REQUEST` asks in process; `interleaved` sends it right after that one, target
    by target, so a drift in the machine's speed moves the two alike.

    Each target is asked twice. Cold: first, right after the in-process runs, which share
    the server's two cores and leave its caches holding the benchmark process's data, not
    the server's (a server of its own never sees that). Warm: after the server has just
    answered another target (the previous one, with a seed of its own, untimed), as a
    server answering a planner's stream of requests is, and as the in-process rows are
    timed (each after other work of the same model in the same process). The goals read the
    warm figure; the report gives both."""

    WARM_UP_SEED = 1_000_000  # + the target's index: a seed no timed request uses

    def __init__(self, client: SmmClient, model: ServedModel, num_samples: int) -> None:
        self.client, self.model, self.num_samples = client, model, num_samples
        self.wall_ms: list[float] = []
        self.server_total_ms: list[float] = []
        self.cold_wall_ms: list[float] = []
        self.cold_server_total_ms: list[float] = []

    def request(self, q_target: np.ndarray, seed: int) -> SmmRequest:
        manifest = self.model.manifest
        return SmmRequest.model_validate(
            {"robot": manifest.robot, "task": manifest.task.name,
             "target": target_of(self.model, q_target), "num_samples": self.num_samples,
             "seed": seed}
        )  # fmt: skip

    def warm_up(self, q_target: np.ndarray) -> None:
        self.client.smm(self.request(q_target, seed=0))

    def _timed(self, request: SmmRequest, wall_ms: list[float], server_ms: list[float]) -> None:
        start = time.perf_counter()
        answer = self.client.smm(request)
        wall_ms.append((time.perf_counter() - start) * 1e3)
        server_ms.append(float(answer.timings_ms["total"]))

    def __call__(self, q_target: np.ndarray, seed: int, q_before: np.ndarray) -> None:
        """Target `q_target` cold, then warm: after an untimed request for `q_before`."""
        request = self.request(q_target, seed)
        self._timed(request, self.cold_wall_ms, self.cold_server_total_ms)
        self.client.smm(self.request(q_before, self.WARM_UP_SEED + seed))
        self._timed(request, self.wall_ms, self.server_total_ms)

    def times(self) -> dict[str, float]:
        return {
            "median_ms": float(np.median(self.wall_ms)),
            "p95_ms": float(np.percentile(self.wall_ms, 95)),
            "server_median_ms": float(np.median(self.server_total_ms)),
            "cold_median_ms": float(np.median(self.cold_wall_ms)),
            "cold_server_median_ms": float(np.median(self.cold_server_total_ms)),
        }


def benchmark_model(
    model: ServedModel,
    num_targets: int,
    sizes: Sequence[int],
    seed: int,
    client: SmmClient | None,
    progress: Callable[[str], None],
) -> dict[str, object]:
    manifest = model.manifest
    limits = JointLimits.of(manifest.joints)
    q_targets = uniform_configurations(limits, num_targets, seed)
    truths = [ground_truth(model, q, seed + i) for i, q in enumerate(q_targets)]
    paper = serving(model, paper_defaults(manifest.defaults))
    sampler = manifest.defaults.sampler
    float32 = with_defaults(model, sampler=sampler.model_copy(update={"precision": "float32"}))
    base = None  # what the reflow alone changes: the base sampler it replaced
    if sampler.flow == "reflow" and manifest.reflow and manifest.reflow.base_sampler:
        base = with_defaults(model, sampler=manifest.reflow.base_sampler)
    rows: dict[str, object] = {}
    default_n = manifest.defaults.num_samples
    for n in sorted({*sizes, default_n}):
        progress(f"{manifest.model_id} N={n}")
        # The service first: restart DLS matches its count. Then the default request, the
        # same with self-collision checked: what the time goals and a client wait for.
        served = {SERVICE: model, DEFAULT_REQUEST: model}
        if manifest.defaults.sampler.precision != "float32":
            served[FLOAT32] = float32
        if base is not None:
            served[BASE] = base
        served[PAPER] = paper
        # Random-restart DLS (pytorch-kinematics' IK) constrains a whole pose or a position,
        # never a tool axis with its rotation free: an axis model has no restart row.
        restart_model = None if manifest.task.tool_axis is not None else model
        http = None if client is None else OverHttp(client, model, n)
        runs = interleaved(served, restart_model, q_targets, n, http)
        # The default request's components are the free pieces of the fibre, not the
        # fibre the exact truth describes: it is timed, not judged.
        row: dict[str, object] = {
            name: {
                **run.times(),
                "figures": None if name == DEFAULT_REQUEST else figures(model, run.answers, truths),
            }
            for name, run in runs.items()
        }
        if http is not None:
            row["http"] = http.times()
        rows[str(n)] = row
    judged = manifest.defaults.reasons.get("judged")
    bound_n = min(GOAL_NUM_SAMPLES, default_n)  # what `bound_num_samples` reads the bounds at
    return {
        "model": model.reference,
        "targets": num_targets,
        "default_num_samples": default_n,
        # Where the connect stage's time goes on the same targets at the N the bounds read
        # (tools.connect_profile).
        "connect_profile": {
            **summarise_connect(profile_connect(model, q_targets, bound_n)),
            "num_samples": bound_n,
        },
        # The judge's verdicts on configurations tried for these defaults, from the manifest.
        "judged": [] if judged is None else judged.split(JUDGED_SEPARATOR),
        "paper_judgement": paper_judgement(manifest),
        "sampler_steps": manifest.defaults.sampler.steps,
        "sampler_precision": manifest.defaults.sampler.precision,
        "sampler_flow": manifest.defaults.sampler.flow,
        "sizes": rows,
        **network_floor_at(model, bound_n),
    }


def network_floor_at(model: ServedModel, num_samples: int) -> dict[str, object]:
    """Where this processor serves the model's int8 network on the AVX2 kernel: the network
    work's products at `num_samples` and the AVX2 product's every-core peak, measured right
    after the model's runs (tools.network_floor: no exact AVX2 kernel multiplies faster
    than vpmaddwd alone). Empty elsewhere."""
    products = avx2_network_products(model, num_samples)
    if products is None:
        return {}
    return {
        "network_floor": {
            "products": products,
            "num_samples": num_samples,
            "peak_every_core_per_s": every_core_peak(),
        }
    }


def markdown(report: dict) -> str:
    machine = Machine.from_json(report["machine"])
    runs = [
        row[name]
        for entry in report["models"].values()
        for row in entry["sizes"].values()
        for name in CONFIGURATIONS
        if name in row
    ]
    # CPU time per answer, where the report measured it.
    cpu = any(run.get("cpu_median_ms") is not None for run in runs)
    commit = f" at commit {report['git_commit']}" if report.get("git_commit") else ""
    lines = [
        "# Benchmark: time and truth, warm, on one machine in one run",
        "",
        f"Produced by `{report['command']}`{commit} on {machine.describe()}. "
        f"onnxruntime threads per session: {report['onnx_threads']} "
        "(the service's own setting on this machine)"
        + (
            # A report without "int8_flow" predates the AVX2 kernel: compiled meant AMX then.
            f"; the int8 flow networks on the {report.get('int8_flow', COMPILED_ON_AMX)}"
            if report.get("compiled_int8")
            else ""
        )
        + ". Targets per model: "
        f"{report['targets']} held-out (seed {report['seed']}). Times are comparable only "
        "within this report.",
        "",
        "| model | N | configuration | median ms | p95 ms | "
        + ("CPU ms | " if cpu else "")
        + "sample | correct | connect | valid configs | count right | splits / target | "
        "merges / target | recall | coverage p95 rad |",
        "|---|---|---|---|---|" + ("---|" if cpu else "") + "---|---|---|---|---|---|---|---|---|",
    ]
    for model_id, entry in report["models"].items():
        for n, row in entry["sizes"].items():
            for name in CONFIGURATIONS:
                if name not in row:
                    continue
                run = row[name]
                stage = run["median_stage_ms"] or {}
                f = run["figures"]
                sample = stage.get("sample", stage.get("solve"))
                truth = (
                    "- | - | - | - | - |"
                    if f is None
                    else f"{f['count_right']:.3g} | {_num(f.get('splits_per_target'))} | "
                    f"{_num(f.get('merges_per_target'))} | {_num(f.get('recall'))} | "
                    f"{f['coverage_p95_rad']:.3g} |"
                )
                lines.append(
                    f"| {model_id} | {n} | {name} | {run['median_ms']:.1f} | {run['p95_ms']:.1f} | "
                    + (f"{_ms(run.get('cpu_median_ms'))} | " if cpu else "")
                    + f"{_ms(sample)} | {_ms(stage.get('correct'))} | "
                    f"{_ms(stage.get('connect'))} | {run['valid_configurations_mean']:.0f} | "
                    + truth
                )
    if any("http" in row for e in report["models"].values() for row in e["sizes"].values()):
        lines += [
            "",
            "Over HTTP (`smm-serve` on 127.0.0.1, default settings, one request at a time; "
            "client wall time, and the server's own `timings_ms.total`; in process: the same "
            "default request, self-collision checked). Warm: right after the server answered "
            "another target, as a server answering a stream of requests is (the goals read "
            "it); cold: right after the in-process runs, which share the server's cores and "
            "caches:",
            "",
            "| model | N | median ms | p95 ms | server median ms | cold median ms | "
            "cold server median ms | in process median ms |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for model_id, entry in report["models"].items():
            for n, row in entry["sizes"].items():
                if "http" in row:
                    h = row["http"]
                    lines.append(
                        f"| {model_id} | {n} | {h['median_ms']:.1f} | {h['p95_ms']:.1f} | "
                        f"{h['server_median_ms']:.1f} | {_ms(h.get('cold_median_ms'))} | "
                        f"{_ms(h.get('cold_server_median_ms'))} | "
                        f"{timed_run(row)['median_ms']:.1f} |"
                    )
    lines += ["", *_goals(report), "", *_bounds(report), "", *_where_the_time_goes(report)]
    if "batch" in report:
        lines += ["", *_batch(report["batch"], report.get("batch_one_thread"))]
    lines += [
        "",
        "Configurations: service, each model's defaults when the report ran (their flow, "
        "Euler steps and network are in the table of where the time goes), asked for the "
        "kinematic fibre, collisions aside, as the other configurations and the exact truth "
        "answer it; service, default request, the same asked as a client asks without "
        "options, with self-collision checked on the models with collision geometry (its "
        "components are the free pieces, so it is timed, not judged; the time goals read "
        "it); service, float32 "
        "network, the same with the float32 network where the defaults serve the int8 one; "
        "service, base flow, a reflowed sampler's base flow at the steps it replaced; paper, "
        "the paper's configuration (100 uniform Euler steps in float32, 3 DLS steps) run by "
        "the same code; random-restart DLS, pytorch-kinematics from uniform restarts, then "
        "the service's own stages after its correction. "
        + (
            "CPU ms: the process's CPU time per answer (median; every thread, onnxruntime's "
            "workers included, and the evaluation's reading of the answer), what a core is "
            "busy for; the wall time is less where the network runs on several threads. "
            if cpu
            else ""
        )
        + "Stages: sample (the flow's Euler steps; `solve` for restart DLS), correct (DLS, and "
        "for r > 1 the pull into the limits, which alone is restart DLS's correct), "
        "connect (components on the fibre); the median of each over the targets, so they "
        "need not add up to the median of the whole. Valid configs: configurations within "
        "tolerance and the limits per target (restart DLS is run to the service's count). "
        "Figures against the exact ground truth of `training/evaluate` (definitions: "
        "docs/reports/iiwa14-pose.md); recall: the fraction of exact components holding a "
        "returned configuration, of those the count counts (every one of a 1-D SMM, those "
        "of at least 1 % of a 4-D fibre).",
        "",
    ]
    return "\n".join(lines)


def _goals(report: dict) -> list[str]:
    lines = [
        f"Speed goals (N = {GOAL_NUM_SAMPLES}, and each model's served default N where it "
        "differs, in process, median; the time is the default request's, self-collision "
        "checked, and the ratio to the paper's configuration and the truth compare the "
        "kinematic answers):",
        "",
        "| model | N | median ms | goal ms | x the paper's time | goal x | time met | truth "
        "against the paper's configuration |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for model_id, most_ms, least_x in GOALS:
        entry = report["models"].get(model_id, {})
        for n, label in goal_sizes(entry):
            row = entry["sizes"][str(n)]
            ms = timed_run(row)["median_ms"]
            speed_up = row[PAPER]["median_ms"] / row[SERVICE]["median_ms"]
            met = ms <= most_ms and (least_x is None or speed_up >= least_x)
            worse = worse_than(row[SERVICE]["figures"], row[PAPER]["figures"])
            lines.append(
                f"| {model_id} | {label} | {ms:.1f} | {most_ms:g} | {speed_up:.1f} | "
                f"{'-' if least_x is None else f'{least_x:g}'} | "
                f"{'yes' if met else f'no: {ms / most_ms:.2f}x the goal'} | "
                f"{'no worse' if not worse else 'worse: ' + '; '.join(worse)} |"
            )
    for model_id, most_ms in HTTP_GOALS:
        entry = report["models"].get(model_id, {})
        for n, label in goal_sizes(entry):
            row = entry["sizes"][str(n)]
            if "http" not in row:
                continue
            ms = row["http"]["median_ms"]
            met = "yes" if ms <= most_ms else f"no: {ms / most_ms:.2f}x the goal"
            lines.append(
                f"| {model_id} over HTTP | {label} | {ms:.1f} | {most_ms:g} | - | - | {met} | - |"
            )
    return lines


def goal_sizes(entry: dict) -> list[tuple[int, str]]:
    """The N a model's goals are measured at, with their labels: N = 1000, and its served
    default where that differs (and the report has it)."""
    sizes = entry.get("sizes", {})
    chosen = [(GOAL_NUM_SAMPLES, f"{GOAL_NUM_SAMPLES}")] if str(GOAL_NUM_SAMPLES) in sizes else []
    default_n = entry.get("default_num_samples")
    if default_n is not None and default_n != GOAL_NUM_SAMPLES and str(default_n) in sizes:
        chosen.append((default_n, f"{default_n} (served default)"))
    return chosen


def paper_judgement(manifest: Manifest, records_dir: Path = OUT_DIR) -> dict | None:
    """The committed judgement of the paper's configuration against the served defaults
    on the judge's targets (`smm-train judge --model <id> --candidate
    paper --num-samples 1000 --out docs/benchmark/judge-paper-<id>-n1000.json`), if there
    is one: both sides' figures, and whether the defaults it judged still serve."""
    path = records_dir / f"judge-paper-{manifest.model_id}-n{GOAL_NUM_SAMPLES}.json"
    if not path.exists():
        return None
    record = json.loads(path.read_text())
    served = manifest.defaults.model_dump(mode="json", exclude={"reasons"})
    served["num_samples"] = record.get("num_samples", served["num_samples"])  # judged at N
    return {
        "record": str(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path),
        "targets": record["targets"] + record["near_singular_targets"],
        "service": record["incumbent"],
        "paper": record["candidate"],
        "judged_the_served_defaults": record["incumbent_defaults"] == served,
    }


def _bounds(report: dict) -> list[str]:
    """For each goal not met, by how much and what bounds it: the service's stages, the
    stage that alone passes the time goal or what the others leave for sampling (in
    evaluations of the network at its measured cost), the connect stage's profile, the
    judge's verdicts on the cheaper configurations tried; for truth, the figures that are
    worse, and the judgement on the judge's larger target set where one is committed."""
    lines = [
        f"What bounds each goal not met (at N = {GOAL_NUM_SAMPLES}, or at the model's served "
        "default where that is fewer: a goal is met at either, and the fewer asks less; "
        "medians over the same targets):",
        "",
    ]
    for model_id, most_ms, least_x in GOALS:
        entry = report["models"].get(model_id)
        row = None if entry is None else entry["sizes"].get(str(bound_num_samples(entry)))
        if entry is None or row is None:
            continue
        run = timed_run(row)
        ms, stage = run["median_ms"], run["median_stage_ms"] or {}
        speed_up = row[PAPER]["median_ms"] / row[SERVICE]["median_ms"]
        if ms > most_ms or (least_x is not None and speed_up < least_x):
            lines += [
                f"- {model_id}, time ({bound_label(entry)}): "
                + _time_bound(entry, ms, most_ms, stage)
            ]
            lines += [f"  - {verdict}" for verdict in entry.get("judged", [])]
        worse = worse_than(row[SERVICE]["figures"], row[PAPER]["figures"])
        if worse:
            lines.append(f"- {model_id}, truth: {_truth_bound(entry, worse)}")
    for model_id, most_ms in HTTP_GOALS:
        entry = report["models"].get(model_id)
        over_http = None if entry is None else http_bound(entry, most_ms)
        if over_http is not None:
            lines.append(f"- {model_id}, {over_http}")
    return lines if len(lines) > 2 else []


def _time_bound(entry: dict, ms: float, most_ms: float, stage: dict[str, float]) -> str:
    spans = {name: stage.get(name, 0.0) for name in STAGES}
    text = (
        f"{ms:.1f} ms, {ms - most_ms:.1f} ms ({ms / most_ms:.2f}x) over the goal of "
        f"{most_ms:g} ms; "
        + ", ".join(f"{name} {spans[name]:.1f}" for name in STAGES)
        + f", the rest {max(ms - sum(spans.values()), 0.0):.1f} ms. "
    )
    slowest = max(STAGES, key=lambda name: spans[name])
    if spans[slowest] >= most_ms:
        text += (
            f"The {slowest} stage alone takes {spans[slowest] / most_ms:.1f}x the goal: no "
            f"change to the other stages meets it without a cheaper {slowest} stage. "
        )
    else:
        steps = entry["sampler_steps"]
        per_evaluation_ms = spans["sample"] / steps
        left_ms = most_ms - (ms - spans["sample"])
        evaluations = max(int(left_ms // per_evaluation_ms), 0)
        text += (
            f"Everything but sampling takes {ms - spans['sample']:.1f} ms, which leaves "
            f"{max(left_ms, 0.0):.1f} ms for sampling: {evaluations} evaluations of the "
            f"network at its {per_evaluation_ms:.2f} ms each, where the served sampler takes "
            f"{steps}. "
        )
    floor = entry.get("network_floor")
    if floor is not None:
        least_ms = floor["products"] / floor["peak_every_core_per_s"] * 1e3
        text += (
            "On this processor's AVX2 kernel the network's products at N = "
            f"{floor.get('num_samples', GOAL_NUM_SAMPLES)} "
            f"({floor['products']:,}) take at least {least_ms:.1f} ms at vpmaddwd's peak on "
            f"every core ({floor['peak_every_core_per_s'] / 1e9:.1f} G a second, measured in "
            "the run)"
            + (
                ": the goal is out of reach of this network here. "
                if least_ms > most_ms
                else ", under the goal. "
            )
        )
    profile = entry.get("connect_profile")
    if profile is not None:
        # A report without the profile's N profiled at each model's default N.
        n = profile.get("num_samples")
        at = "the model's default N" if n is None else f"N = {n}"
        text += (
            f"The connect stage profiled alone (`tools.connect_profile`, the same targets at "
            f"{at}, the service's threads): {profile['connect_ms']:.1f} ms, of which the "
            "compiled kernels on its own thread "
            f"{profile['kernels_ms']:.1f} ms in {profile['kernel_calls']:.0f} calls, and "
            f"{profile['connect_ms'] - profile['kernels_ms']:.1f} ms the stage's own Python "
            "and numpy between those calls (steps, neighbour searches, bookkeeping on a few "
            "dozen rows at a time)."
        )
    if entry.get("judged"):
        text += " The judge's verdicts on the configurations tried (the manifest's reasons):"
    return text


def _truth_bound(entry: dict, worse: list[str]) -> str:
    text = f"worse than the paper's configuration on these targets: {'; '.join(worse)}."
    judgement = entry.get("paper_judgement")
    if judgement is None:
        return text
    service, paper = judgement["service"], judgement["paper"]
    defaults = "the served" if judgement["judged_the_served_defaults"] else "earlier"
    worse_there, better_there = worse_than(service, paper), better_than(service, paper)
    return text + (
        f" On the judge's {judgement['targets']} targets ({judgement['record']}, "
        f"{defaults} defaults), service vs paper: worse on "
        + ("; ".join(worse_there) if worse_there else "none")
        + ", better on "
        + ("; ".join(better_there) if better_there else "none")
        + "."
    )


def _where_the_time_goes(report: dict) -> list[str]:
    """The service's stages at N = 1000 as shares of its median, and the cost of one
    evaluation of the flow network (the sample stage over its Euler steps)."""
    lines = [
        "Where the service's time goes (N = 1000, medians): the share of each stage and the "
        "cost of one evaluation of the flow network for the N samples (sample / Euler steps):",
        "",
        "| model | flow | Euler steps | network | ms per network evaluation | sample % "
        "| correct % | connect % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for model_id, entry in report["models"].items():
        row = entry["sizes"].get("1000")
        if row is None:
            continue
        run, steps = row[SERVICE], entry["sampler_steps"]
        precision = entry.get("sampler_precision", "float32")
        stage, total = run["median_stage_ms"] or {}, run["median_ms"]
        lines.append(
            f"| {model_id} | {entry.get('sampler_flow', 'base')} | {steps} | {precision} | "
            f"{stage.get('sample', float('nan')) / steps:.1f} | "
            + " | ".join(f"{100 * stage.get(s, float('nan')) / total:.0f}" for s in STAGES)
            + " |"
        )
    return lines


STAGES = ("sample", "correct", "connect")


def _batch(batch: dict, one_thread: dict | None) -> list[str]:
    threads = batch.get("batch_threads", "cores // workers")
    runs = [(f"default (`SMM_BATCH_THREADS=0`: {threads} threads here)", batch)]
    if one_thread is not None:
        runs.append(("one thread (`SMM_BATCH_THREADS=1`)", one_thread))
    mismatched = sorted({i for _, run in runs for i in run["mismatched"]})
    lines = [
        f"Many targets in one request (`tools.batch_benchmark`, over HTTP, {batch['rounds']} "
        f"rounds): {batch['targets']} targets of {batch['model']} at N = "
        f"{batch['num_samples']}{' (served default)' if batch.get('served_default') else ''}"
        ", target i with seed i, as one POST /smm/batch against as "
        "many POST /smm sent one after another (the batch read as the server streams it, "
        "NDJSON, each answer parsed while the server computes the next, and where measured "
        "also as one JSON object, parsed once it has all arrived); every batch answer "
        + (
            "equal to its single answer."
            if not mismatched
            else f"NOT equal to its single answer on targets {mismatched}."
        ),
        "",
        "| server | singles median ms | batch median ms | singles / batch | goal | met |",
        "|---|---|---|---|---|---|",
    ]
    for name, run in runs:
        forms = [("", run["batch_median_ms"])]
        if "batch_json_median_ms" in run:  # read as lines, and as one JSON object
            forms = [(", read as lines", run["batch_median_ms"])]
            forms.append((", read as one JSON object", run["batch_json_median_ms"]))
        for form, batch_ms in forms:
            x = run["singles_median_ms"] / batch_ms
            met = "yes" if x >= BATCH_GOAL_X else f"no: {BATCH_GOAL_X / x:.1f}x short"
            lines.append(
                f"| {name}{form} | {run['singles_median_ms']:.0f} | {batch_ms:.0f} | "
                f"{x:.2f} | {BATCH_GOAL_X:g}x | {met} |"
            )
    return [
        *lines,
        "",
        *batch_profile(batch, one_thread),
        "",
        "The batch answers each target with the same stages a single request runs "
        "(`service/pipeline/batch.py` says why the network is not called on all targets' "
        "samples at once: the cost per row does not fall past ~50 rows, and the int8 "
        "network's per-call activation scale would change the answers), so it saves the "
        "per-request HTTP, validation and JSON round trips, and answers targets on every "
        "core at once, not less computation; on two cores, two threads can at most halve "
        "the computation.",
    ]


def batch_profile(batch: dict, one_thread: dict | None = None) -> list[str]:
    """Where the default batch's time goes, per target, and what bounds it
    (tools/batch_bounds.py): the network and the transport alone, and the cores (with the
    one-thread batch's CPU beside the default's, when measured)."""
    bound = stage_bound(batch)
    lines = [
        "Where the default batch's time goes, ms per target (the server's stages, each "
        f"target's own, {bound.at_once} targets at a time; outside: the client's wall time less "
        "the server's total, i.e. HTTP, validation and JSON at both ends):",
        "",
        "| singles | batch | " + " | ".join(BATCH_STAGES) + " | outside |",
        "|---|---|" + "---|" * (len(BATCH_STAGES) + 1),
        f"| {bound.singles_ms:.1f} | {bound.batch_ms:.1f} | "
        + " | ".join(f"{bound.stage_ms[stage]:.1f}" for stage in BATCH_STAGES)
        + f" | {bound.outside_ms:.1f} |",
        "",
        f"Even with correction, connection and summaries free, the batch would take the "
        f"sampling ({bound.at_once} targets at a time) and what lies outside the pipeline, "
        f"{bound.floor_ms:.1f} ms per target: at most "
        f"{bound.most_x:.1f}x the singles (goal {BATCH_GOAL_X:g}x). "
        + (
            "The rest of the goal needs a cheaper network evaluation or answer transport, "
            "not only batching."
            if bound.most_x < BATCH_GOAL_X
            else "This bound does not rule the goal out; the cores' bound below does."
        ),
    ]
    cpu = cpu_bound(batch)
    if cpu is not None:
        lines += ["", cpu_sentence(cpu, None if one_thread is None else cpu_bound(one_thread))]
    compiled = compiled_bound(batch)
    if compiled is not None:
        lines += ["", compiled_sentence(compiled)]
    same_work = same_work_bound(batch)
    if same_work is not None:
        lines += ["", same_work_sentence(same_work)]
    network = network_bound(batch)
    if network is not None:
        lines += ["", network_sentence(network)]
    return lines


def _ms(value: object) -> str:
    return "-" if value is None else f"{float(value):.1f}"  # type: ignore[arg-type]


def _num(value: object) -> str:
    return "-" if value is None else f"{float(value):.3g}"  # type: ignore[arg-type]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    bundled = bundled_model_ids()
    parser.add_argument("--models", nargs="+", default=bundled, choices=bundled)
    parser.add_argument("--sizes", nargs="+", type=int, default=list(SIZES))
    parser.add_argument("--targets", type=int, default=20)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--no-http", action="store_true", help="skip the HTTP measurement")
    parser.add_argument("--batch-model", default="iiwa14-pose", help="the batch's model")
    parser.add_argument(
        "--batch-targets", type=int, default=64, help="targets in the batch (0: no batch)"
    )
    parser.add_argument("--out", type=Path, default=OUT_DIR)
    parser.add_argument(
        "--render",
        action="store_true",
        help="measure nothing: write <out>/benchmark.md from <out>/benchmark.json",
    )
    args = parser.parse_args()
    if args.render:
        record = json.loads((args.out / "benchmark.json").read_text())
        (args.out / "benchmark.md").write_text(markdown(record))
        return
    settings = Settings()
    threads = settings.onnx_threads_per_session
    machine = Machine.now()
    report: dict = {
        "command": command_line("tools.benchmark"),
        "git_commit": git_commit(),  # the code measured, at the run's start
        "onnx_threads": threads,
        # The int8 flow networks on the compiled layers (the exact product), and on which kernel.
        "compiled_int8": settings.compiled_int8 and int8_on_compiled_layers(),
        "int8_flow": int8_flow_here() if settings.compiled_int8 else ONNX_FLOW,
        "targets": args.targets,
        "seed": args.seed,
        "models": {},
    }
    server = None if args.no_http else LocalServer().start()
    client = None
    if server is not None:
        client = SmmClient(server.url, timeout=120.0, retry=RetryPolicy(max_attempts=1))
    try:
        for model_id in args.models:
            model = load_model(REPO_MODELS_DIR / model_id, threads, settings.compiled_int8)
            report["models"][model_id] = benchmark_model(
                model, args.targets, args.sizes, args.seed, client,
                lambda line: print(line, flush=True),
            )  # fmt: skip
    finally:
        if client is not None:
            client.close()
        if server is not None:
            server.stop()
    if args.batch_targets > 0 and not args.no_http and args.batch_model in args.models:
        model = load_model(REPO_MODELS_DIR / args.batch_model, threads, settings.compiled_int8)
        limits = model.limits
        q_targets = uniform_configurations(limits, args.batch_targets, args.seed)
        print(f"{args.batch_model}: batch of {args.batch_targets} against singles", flush=True)
        report["batch"] = batch_against_singles(model, q_targets, BATCH_NUM_SAMPLES)
        report["batch"]["batch_threads"] = settings.batch_threads_per_request
        # The same with the batch's targets answered one after another.
        report["batch_one_thread"] = batch_against_singles(
            model, q_targets, BATCH_NUM_SAMPLES, batch_threads=1
        )
    report["machine"] = machine.ended().as_json()
    args.out.mkdir(parents=True, exist_ok=True)
    write_record(args.out / "benchmark.json", report)
    (args.out / "benchmark.md").write_text(markdown(report))
    print(markdown(report))


if __name__ == "__main__":
    main()
