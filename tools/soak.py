"""Soak: the server's resident memory and latency over a long run of mixed requests.

    python -m tools.soak --duration-s 3600 --clients 4 --json docs/benchmark/soak.json
    python -m tools.soak --duration-s 480 --clients 4 --interval-s 30 --settle-s 120

starts a server on 127.0.0.1 (tools.local_server) unless `--url` names a running one
(loopback only; `--pid` then names its process, for its memory), and runs `--clients`
concurrent clients for `--duration-s` seconds. Each client loops over a fixed mix, one
cycle after another: POST /smm to every bundled model in turn (a reachable target of it,
as tools.load sends), one POST /smm in a scene (obstacles and self-collision checked: a
request the scenes report evaluated, docs/reports/scenes, the models with collision
geometry in turn), one POST /smm/batch of `--batch-targets` targets of one model (the
model changes from cycle to cycle; half the batches ask for NDJSON lines, as the Python
client does, half for one JSON object, and a stream of lines without its end line
counts as a failed request), and two bad requests (malformed JSON, an unknown
robot, a target of the wrong shape, num_samples out of range, a wrong content type, an
oversized body, bad batches...; each must be answered with a 4xx). A 503 is honoured by
sleeping its Retry-After (unless `--no-backoff`).

Every `--interval-s` seconds it reads the server's resident set size (VmRSS, /proc) and
prints one line for the window that ended: requests, statuses by kind (single, scene,
batch, bad), p50/p99 latency of the answered (200) single requests, of the answered
requests in a scene and of the answered batches, separately, and the probe: the time a
fixed piece of Python work takes in this process right then (`speed_probe_ms`), a
reading of the machine's speed under the run's own load. The server is CPU-bound on
every core, so its CPU time per request moves with the machine's speed as much as with
its own work; the probe, the same work under the same load all along, moves with the
machine's speed.
At the end it compares the window ending at `--settle-s` (5 minutes by default) with what
follows, against the goals of a flat server:

- RSS: no window after the settle window more than 5 % above the RSS at settle (the
  report gives the largest and the smallest RSS after it and their ratios to it);
- latency: the single requests' p99 over the last `--p99-span-s` (5 minutes) no more than
  10 % above their p99 over the same span up to the settle window's end (a span's
  hundreds of answers, not one window's few slowest);
- no 5xx other than 503.

The goals bound growth: an RSS that malloc trims back, or a p99 that falls, is reported
(the ratios) and does not fail them.

Errors are: a transport failure, a 5xx other than 503, a 2xx to a bad request, a status
other than 200 or 503 to a valid one. Exit code 1 when there is any. `--json` writes the
record: the command, the commit, the machine (load average at the start and the end), the
settings, every window and the verdicts.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import random
import sys
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import httpx
import numpy as np

from service.wire import NDJSON
from tools.load import (
    add_client_arguments,
    machine_description,
    percentiles_ms,
    request_bodies,
    require_loopback,
)
from tools.local_server import LocalServer
from tools.procfs import resident_memory_bytes
from tools.records import command_line, write_record
from training.checkout import git_commit
from training.machine import Machine

Kind = Literal["single", "scene", "batch", "bad"]
KINDS: tuple[Kind, ...] = ("single", "scene", "batch", "bad")

RSS_GOAL = 0.05  # no RSS after the settle window over 5 % above the RSS at settle
P99_GOAL = 0.10  # the last window's single-request p99 at most 10 % above the settle window's
# The speed probe: a loop of PROBE_LOOP multiply-adds in Python, its least time of
# PROBE_REPEATS runs (about 6 ms of the event loop's time a window).
PROBE_LOOP = 50_000
PROBE_REPEATS = 3
BAD_PER_CYCLE = 2
BATCHES_PER_MODEL = 8
SCENES_DIR = Path(__file__).resolve().parents[1] / "docs" / "reports" / "scenes"
SCENES_PER_MODEL = 8  # the first targets of each model's scenes report
# Environment variables that change how the server's process holds memory: recorded.
MEMORY_ENVIRONMENT = (
    "MALLOC_ARENA_MAX",
    "MALLOC_TRIM_THRESHOLD_",
    "MALLOC_MMAP_THRESHOLD_",
    "MALLOC_TOP_PAD_",
    "PYTHONMALLOC",
    "LD_PRELOAD",
    "OMP_NUM_THREADS",
)


@dataclass(frozen=True)
class Call:
    """One request of the mix, its body already encoded."""

    kind: Kind
    name: str  # the model id, or what is wrong with a bad request
    path: str
    content: bytes
    content_type: str | None = "application/json"
    expected_status: int = 200  # a bad one's documented status (docs/bad-inputs.md)
    accept: str | None = None  # NDJSON: a batch asked for as lines

    @property
    def headers(self) -> dict[str, str]:
        headers = {"content-type": self.content_type} if self.content_type else {}
        return headers | ({"accept": self.accept} if self.accept else {})


def whole(call: Call, status: int, body: bytes) -> int:
    """The status an answer counts as: a 200 stream of lines without its end line (the
    SmmBatchEnd, `{"status": ...}`) was cut off, a failure like a dropped connection (0)."""
    if status == 200 and call.accept == NDJSON:
        last = body.rstrip(b"\n").rsplit(b"\n", 1)[-1]
        if not last.startswith(b'{"status"'):
            return 0
    return status


@dataclass
class Outcome:
    kind: Kind
    name: str
    status: int  # 0 for a transport failure
    latency_s: float
    done_s: float  # since the start of the run


@dataclass
class Window:
    index: int
    start_s: float
    end_s: float  # nominal: a multiple of the interval, or the duration for the last one
    rss_mib: float | None  # read just after end_s; None without a server pid
    requests: int
    statuses: dict[str, dict[str, int]]  # kind -> status -> count
    errors: int
    server_errors: int  # 5xx other than 503
    single_p50_ms: float | None
    single_p99_ms: float | None
    batch_p50_ms: float | None
    batch_p99_ms: float | None
    probe_ms: float | None = None  # speed_probe_ms at the window's end; None: not taken
    scene_p50_ms: float | None = None
    scene_p99_ms: float | None = None
    # The answered single requests' latencies, for the p99 over several windows (not
    # written to the record).
    single_latencies_ms: list[float] = field(default_factory=list, repr=False)


@dataclass
class Verdicts:
    settle_s: float
    settle_window: int | None  # index of the window ending at settle_s (None: run too short)
    rss_at_settle_mib: float | None
    rss_max_after_mib: float | None
    rss_min_after_mib: float | None
    rss_max_ratio: float | None  # max after / at settle
    rss_min_ratio: float | None  # min after / at settle
    rss_goal_met: bool | None  # None: not measured
    single_p99_at_settle_ms: float | None
    single_p99_last_ms: float | None
    single_p99_ratio: float | None  # last / at settle
    p99_goal_met: bool | None
    # The speed probe's median over the same two spans (no goal: it tells a slower machine
    # from a slower server); None where no window of a span took it.
    probe_at_settle_ms: float | None
    probe_last_ms: float | None
    probe_ratio: float | None  # last / at settle
    server_errors: int
    server_errors_goal_met: bool
    errors: int
    requests: int
    statuses: dict[str, dict[str, int]] = field(default_factory=dict)


def is_server_error(status: int) -> bool:
    return 500 <= status < 600 and status != 503


def is_error(kind: Kind, status: int) -> bool:
    """Anything but the expected kind of answer; a 503 (at capacity) is never an error."""
    if status == 503:
        return False
    if kind == "bad":
        return not 400 <= status < 500
    return status != 200


def _json(body: Any) -> bytes:
    return json.dumps(body).encode()


def single_calls(bodies: dict[str, list[dict[str, Any]]]) -> dict[str, list[Call]]:
    """Per model id, its POST /smm bodies as calls."""
    return {
        model: [Call("single", model, "/smm", _json(body)) for body in model_bodies]
        for model, model_bodies in bodies.items()
    }


def batch_calls(bodies: dict[str, list[dict[str, Any]]], targets: int) -> dict[str, list[Call]]:
    """Per model id, POST /smm/batch bodies of `targets` of its targets (each with its own
    seed), taken in turn from its single bodies."""
    calls: dict[str, list[Call]] = {}
    for model, model_bodies in bodies.items():
        first = model_bodies[0]
        calls[model] = []
        for b in range(BATCHES_PER_MODEL):
            chosen = [model_bodies[(b * targets + i) % len(model_bodies)] for i in range(targets)]
            body = {
                "robot": first["robot"],
                "task": first["task"],
                "max_configurations_per_component": first["max_configurations_per_component"],
                "targets": [{"target": c["target"], "seed": c["seed"]} for c in chosen],
            }
            accept = NDJSON if b % 2 else None  # every other batch as lines
            calls[model].append(Call("batch", model, "/smm/batch", _json(body), accept=accept))
    return calls


def scene_calls(scenes_dir: Path = SCENES_DIR) -> list[Call]:
    """POST /smm bodies in a scene: the first SCENES_PER_MODEL requests each model's
    scenes report evaluated (its boxes, self-collision checked, its margin), with at most
    5 configurations per component as the single requests ask; the models in turn."""
    per_model: list[list[Call]] = []
    for report_path in sorted(scenes_dir.glob("*.json")):
        report = json.loads(report_path.read_text())
        calls = []
        for row in report["per_target"][:SCENES_PER_MODEL]:
            body = {**row["request"], "max_configurations_per_component": 5}
            calls.append(Call("scene", report["model"], "/smm", _json(body)))
        per_model.append(calls)
    return [call for turn in zip(*per_model, strict=True) for call in turn]


def bad_calls(bodies: dict[str, list[dict[str, Any]]]) -> list[Call]:
    """Requests every server must refuse with a 4xx, each with its documented status
    (docs/bad-inputs.md, with the default limits): built on a valid body of the first
    model, and of a pose model where one is served."""
    models = sorted(bodies)
    body = bodies[models[0]][0]
    robot, task, target = body["robot"], body["task"], body["target"]

    def bad(
        name: str,
        content: bytes,
        status: int,
        path: str = "/smm",
        content_type: str = "application/json",
    ) -> Call:
        return Call("bad", name, path, content, content_type, status)

    batch = {"robot": robot, "task": task, "targets": [{"target": target}]}
    calls = [
        bad("not-json", b'{"robot": "' + robot.encode() + b'", "target": ', 422),
        bad("empty-body", b"", 422),
        bad("json-array-body", b"[1, 2]", 422),
        bad("unknown-robot", _json({**body, "robot": "ur10"}), 404),
        bad("unknown-task", _json({**body, "task": "no-such-task"}), 404),
        bad("position-one-value", _json({**body, "target": {"position": [0.5]}}), 422),
        bad("nan-position", _json({**body, "target": {"position": [math.nan, 0.0]}}), 422),
        bad("num-samples-zero", _json({**body, "num_samples": 0}), 422),
        bad("num-samples-over-limit", _json({**body, "num_samples": 10**9}), 413),
        bad("unknown-field", _json({**body, "num_sample": 10}), 422),
        bad("wrong-content-type", _json(body), 415, content_type="text/plain"),
        bad("oversized-body", _json({**body, "reference_configuration": [0.0] * 20_000}), 413),
        bad("batch-no-targets", _json({**batch, "targets": []}), 422, "/smm/batch"),
        bad(
            "batch-bad-target",
            _json({**batch, "targets": [{"target": target}, {"target": {"position": [0.5]}}]}),
            422,
            "/smm/batch",
        ),
        bad("batch-unknown-robot", _json({**batch, "robot": "ur10"}), 404, "/smm/batch"),
        bad(
            "batch-too-many-targets",
            _json({**batch, "targets": [{"target": target}] * 65}),
            413,
            "/smm/batch",
        ),
    ]
    pose = [m for m in models if "orientation" in bodies[m][0]["target"]]
    if pose:
        pose_body = bodies[pose[0]][0]
        far = {"w": 2.0, "x": 0.0, "y": 0.0, "z": 0.0}
        pose_target = {**pose_body["target"], "orientation": far}
        calls.append(bad("non-unit-quaternion", _json({**pose_body, "target": pose_target}), 422))
    return calls


@dataclass(frozen=True)
class Mix:
    singles: dict[str, list[Call]]
    scenes: list[Call]
    batches: dict[str, list[Call]]
    bad: list[Call]

    @classmethod
    def of(cls, bodies: dict[str, list[dict[str, Any]]], batch_targets: int) -> Mix:
        return cls(
            single_calls(bodies), scene_calls(), batch_calls(bodies, batch_targets),
            bad_calls(bodies),
        )  # fmt: skip

    def cycle(self, number: int, rng: random.Random) -> list[Call]:
        """Cycle `number`: one single request per model, one in a scene (in turn), one
        batch (of the models in turn), BAD_PER_CYCLE bad requests (in turn)."""
        models = sorted(self.singles)
        calls = [rng.choice(self.singles[model]) for model in models]
        calls.append(self.scenes[number % len(self.scenes)])
        calls.append(rng.choice(self.batches[models[number % len(models)]]))
        calls += [
            self.bad[(number * BAD_PER_CYCLE + i) % len(self.bad)] for i in range(BAD_PER_CYCLE)
        ]
        return calls


def _ms(value: float) -> float | None:
    return None if math.isnan(value) else round(value, 1)


def speed_probe_ms() -> float:
    """The least time, in ms, of PROBE_REPEATS runs of the same pure-Python work (about 2 ms
    each on a 2-core Intel Xeon): the least, so that a run cut short by a thread switch
    does not read as a slower machine."""
    times = []
    for _ in range(PROBE_REPEATS):
        start = time.perf_counter()
        total = 0
        for i in range(PROBE_LOOP):
            total += i * i
        times.append(time.perf_counter() - start)
    return round(min(times) * 1e3, 3)


def window_of(
    index: int,
    start_s: float,
    end_s: float,
    outcomes: list[Outcome],
    rss_bytes: int | None,
    probe_ms: float | None = None,
) -> Window:
    """The statistics of the outcomes of one window (those that finished in it)."""
    statuses: dict[str, Counter[str]] = {kind: Counter() for kind in KINDS}
    for o in outcomes:
        statuses[o.kind][str(o.status)] += 1
    single = [o.latency_s for o in outcomes if o.kind == "single" and o.status == 200]
    scene = [o.latency_s for o in outcomes if o.kind == "scene" and o.status == 200]
    batch = [o.latency_s for o in outcomes if o.kind == "batch" and o.status == 200]
    single_p50, _, single_p99 = percentiles_ms(single)
    scene_p50, _, scene_p99 = percentiles_ms(scene)
    batch_p50, _, batch_p99 = percentiles_ms(batch)
    return Window(
        index=index,
        start_s=start_s,
        end_s=end_s,
        rss_mib=None if rss_bytes is None else round(rss_bytes / 2**20, 1),
        requests=len(outcomes),
        statuses={kind: dict(sorted(counts.items())) for kind, counts in statuses.items()},
        errors=sum(is_error(o.kind, o.status) for o in outcomes),
        server_errors=sum(is_server_error(o.status) for o in outcomes),
        single_p50_ms=_ms(single_p50),
        single_p99_ms=_ms(single_p99),
        batch_p50_ms=_ms(batch_p50),
        batch_p99_ms=_ms(batch_p99),
        probe_ms=probe_ms,
        scene_p50_ms=_ms(scene_p50),
        scene_p99_ms=_ms(scene_p99),
        single_latencies_ms=[latency * 1e3 for latency in single],
    )


def _at_most_above(value: float, reference: float, goal: float) -> bool:
    """`value` at most `goal` (a fraction) above `reference`."""
    return value / reference - 1.0 <= goal + 1e-12


def span_p99_ms(windows: list[Window]) -> float | None:
    """p99 of the answered single requests of these windows together."""
    latencies = [latency for w in windows for latency in w.single_latencies_ms]
    return _ms(float(np.percentile(latencies, 99))) if latencies else None


def verdicts_of(windows: list[Window], settle_s: float, p99_span_s: float = 0.0) -> Verdicts:
    """The goals, from the windows: the settle window is the first that ends at or after
    `settle_s`; RSS is compared with its reading. The p99 is taken over the windows that
    end within `p99_span_s` before the settle window's end (it included), against the
    p99 over the windows that end within the same span of the last one's end: one
    window's p99 rests on its few slowest answers."""
    settle = next((w for w in windows if w.end_s >= settle_s - 1e-9), None)
    after = [] if settle is None else [w for w in windows if w.index > settle.index]
    rss_settle = None if settle is None else settle.rss_mib
    rss_after = [w.rss_mib for w in after if w.rss_mib is not None]
    rss_max = max(rss_after) if rss_after else None
    rss_min = min(rss_after) if rss_after else None
    rss_met = None
    if rss_settle is not None and rss_max is not None:
        rss_met = _at_most_above(rss_max, rss_settle, RSS_GOAL)

    def span_before(end: Window) -> list[Window]:
        return [
            w
            for w in windows
            if w.index == end.index or end.end_s - p99_span_s < w.end_s <= end.end_s
        ]

    p99_settle = None if settle is None else span_p99_ms(span_before(settle))
    last_span = (
        [w for w in span_before(after[-1]) if w.index > settle.index] if after and settle else []
    )
    p99_last = span_p99_ms(last_span)
    p99_met = None
    if p99_settle is not None and p99_last is not None:
        p99_met = _at_most_above(p99_last, p99_settle, P99_GOAL)
    probe_settle = None if settle is None else _median_probe_ms(span_before(settle))
    probe_last = _median_probe_ms(last_span)
    totals: dict[str, Counter[str]] = {kind: Counter() for kind in KINDS}
    for w in windows:
        for kind, counts in w.statuses.items():
            totals[kind].update(counts)
    server_errors = sum(w.server_errors for w in windows)

    def ratio(value: float | None, reference: float | None) -> float | None:
        return None if value is None or not reference else round(value / reference, 4)

    return Verdicts(
        settle_s=settle_s,
        settle_window=None if settle is None else settle.index,
        rss_at_settle_mib=rss_settle,
        rss_max_after_mib=rss_max,
        rss_min_after_mib=rss_min,
        rss_max_ratio=ratio(rss_max, rss_settle),
        rss_min_ratio=ratio(rss_min, rss_settle),
        rss_goal_met=rss_met,
        single_p99_at_settle_ms=p99_settle,
        single_p99_last_ms=p99_last,
        single_p99_ratio=ratio(p99_last, p99_settle),
        p99_goal_met=p99_met,
        probe_at_settle_ms=probe_settle,
        probe_last_ms=probe_last,
        probe_ratio=ratio(probe_last, probe_settle),
        server_errors=server_errors,
        server_errors_goal_met=server_errors == 0,
        errors=sum(w.errors for w in windows),
        requests=sum(w.requests for w in windows),
        statuses={kind: dict(sorted(counts.items())) for kind, counts in totals.items()},
    )


def net_p99_ratio(v: Verdicts) -> float | None:
    """The single p99's ratio over the speed probe's (no goal): the latency's drift with the
    machine's speed taken out; None where either is missing."""
    if not v.single_p99_ratio or not v.probe_ratio:
        return None
    return round(v.single_p99_ratio / v.probe_ratio, 4)


def _median_probe_ms(windows: list[Window]) -> float | None:
    """The median speed probe of the windows that took one; None if none did."""
    probes = [w.probe_ms for w in windows if w.probe_ms is not None]
    return round(float(np.median(probes)), 3) if probes else None


def _figure(value: float | None, unit: str, digits: int = 0) -> str:
    return "-" if value is None else f"{value:.{digits}f} {unit}"


def format_window(window: Window) -> str:
    def statuses(kind: str) -> str:
        counts = window.statuses.get(kind, {})
        return " ".join(f"{status}:{n}" for status, n in counts.items()) or "-"

    return (
        f"{window.end_s:6.0f} s  RSS {_figure(window.rss_mib, 'MiB', 1)}  "
        f"{window.requests} requests (single {statuses('single')}; scene {statuses('scene')}; "
        f"batch {statuses('batch')}; bad {statuses('bad')}; errors {window.errors})  "
        f"single p50 {_figure(window.single_p50_ms, 'ms')} "
        f"p99 {_figure(window.single_p99_ms, 'ms')}  "
        f"scene p50 {_figure(window.scene_p50_ms, 'ms')} p99 {_figure(window.scene_p99_ms, 'ms')}  "
        f"batch p50 {_figure(window.batch_p50_ms, 'ms')} p99 {_figure(window.batch_p99_ms, 'ms')}"
        f"  probe {_figure(window.probe_ms, 'ms', 2)}"
    )


def format_verdicts(v: Verdicts) -> str:
    def met(value: bool | None) -> str:
        return "not measured" if value is None else ("met" if value else "NOT met")

    def ratio(value: float | None) -> str:
        return "-" if value is None else f"x{value:.3f}"

    return "\n".join(
        [
            f"{v.requests} requests; statuses {v.statuses}; errors {v.errors}",
            f"RSS at {v.settle_s:.0f} s: {_figure(v.rss_at_settle_mib, 'MiB', 1)}; after it max "
            f"{_figure(v.rss_max_after_mib, 'MiB', 1)} ({ratio(v.rss_max_ratio)}), min "
            f"{_figure(v.rss_min_after_mib, 'MiB', 1)} ({ratio(v.rss_min_ratio)}); at most "
            f"{RSS_GOAL:.0%} above: {met(v.rss_goal_met)}",
            f"single p99: {_figure(v.single_p99_at_settle_ms, 'ms')} at {v.settle_s:.0f} s, "
            f"{_figure(v.single_p99_last_ms, 'ms')} in the last window "
            f"({ratio(v.single_p99_ratio)}); at most {P99_GOAL:.0%} above: "
            f"{met(v.p99_goal_met)}",
            f"speed probe (no goal): {_figure(v.probe_at_settle_ms, 'ms', 2)} at "
            f"{v.settle_s:.0f} s, {_figure(v.probe_last_ms, 'ms', 2)} in the last window "
            f"({ratio(v.probe_ratio)}); the single p99's ratio over it: "
            f"{ratio(net_p99_ratio(v))}",
            f"5xx other than 503: {v.server_errors}; none: {met(v.server_errors_goal_met)}",
        ]
    )


async def run_soak(
    url: str,
    mix: Mix,
    clients: int,
    duration_s: float,
    interval_s: float,
    rss: Callable[[], int] | None,
    backoff: bool = True,
    timeout_s: float = 60.0,
    headers: dict[str, str] | None = None,
    report: Callable[[Window], None] | None = None,
    probe: Callable[[], float] | None = speed_probe_ms,
) -> list[Window]:
    """`clients` concurrent loops over the mix for `duration_s` seconds; a window of
    statistics (and an RSS reading, with `rss`, and a speed reading, with `probe`) every
    `interval_s`, the last one when every client has finished. `report` is called with
    each window as it closes."""
    outcomes: list[Outcome] = []
    windows: list[Window] = []
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    async with httpx.AsyncClient(
        base_url=url, timeout=timeout_s, limits=limits, headers=headers
    ) as http:
        start = time.perf_counter()
        stop_at = start + duration_s
        closed = 0  # outcomes already in a window: appended in the order they finished

        def close(end_s: float, last: bool) -> None:
            nonlocal closed
            upto = closed
            while upto < len(outcomes) and (last or outcomes[upto].done_s <= end_s):
                upto += 1
            start_s = windows[-1].end_s if windows else 0.0
            window = window_of(
                len(windows),
                start_s,
                end_s,
                outcomes[closed:upto],
                rss() if rss else None,
                probe() if probe else None,
            )
            closed = upto
            windows.append(window)
            if report is not None:
                report(window)

        async def client(index: int) -> None:
            rng = random.Random(index)
            number = index
            while time.perf_counter() < stop_at:
                for call in mix.cycle(number, rng):
                    if time.perf_counter() >= stop_at:
                        break
                    sent = time.perf_counter()
                    try:
                        response = await http.post(
                            call.path, content=call.content, headers=call.headers
                        )
                        status = whole(call, response.status_code, response.content)
                        retry_after = response.headers.get("retry-after")
                    except httpx.HTTPError:
                        status, retry_after = 0, None
                    done = time.perf_counter()
                    outcomes.append(
                        Outcome(call.kind, call.name, status, done - sent, done - start)
                    )
                    if status == 503 and backoff and retry_after is not None:
                        await asyncio.sleep(min(float(retry_after), max(0.0, stop_at - done)))
                number += clients

        async def sampler() -> None:
            end_s = interval_s
            while end_s < duration_s - 1e-9:
                await asyncio.sleep(max(0.0, start + end_s - time.perf_counter()))
                close(end_s, last=False)
                end_s += interval_s

        await asyncio.gather(sampler(), *(client(i) for i in range(clients)))
        close(duration_s, last=True)
    return windows


def memory_environment(pid: int | None) -> dict[str, str]:
    """The MEMORY_ENVIRONMENT variables set for the server: from /proc/<pid>/environ when
    it can be read, else this process's (which a started server inherits)."""
    variables: dict[str, str] = dict(os.environ)
    if pid is not None:
        try:
            raw = Path(f"/proc/{pid}/environ").read_bytes()
        except OSError:
            pass
        else:
            pairs = (item.split(b"=", 1) for item in raw.split(b"\0") if b"=" in item)
            variables = {k.decode(errors="replace"): v.decode(errors="replace") for k, v in pairs}
    return {k: variables[k] for k in MEMORY_ENVIRONMENT if k in variables}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", help="a running server (loopback only); default: start one")
    parser.add_argument("--pid", type=int, help="with --url: the server's process, for its RSS")
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--duration-s", type=float, default=3600.0)
    parser.add_argument("--interval-s", type=float, default=60.0, help="one window each")
    parser.add_argument(
        "--settle-s", type=float, default=300.0, help="the window ending here is the reference"
    )
    parser.add_argument(
        "--p99-span-s",
        type=float,
        default=300.0,
        help="the p99 at settle and at the end is over the windows of this span",
    )
    parser.add_argument("--batch-targets", type=int, default=4, help="targets in each batch")
    add_client_arguments(parser)
    args = parser.parse_args(argv)
    if args.pid is not None and not args.url:
        parser.error("--pid goes with --url (a started server's pid is known)")
    if args.interval_s <= 0 or args.duration_s <= 0 or args.clients < 1:
        parser.error("--interval-s, --duration-s and --clients must be positive")
    if args.url:
        require_loopback(args.url)
    settings = dict(item.split("=", 1) for item in args.setting)
    record: dict[str, Any] = {
        "command": command_line("tools.soak", argv),
        "git_commit": git_commit(),
        "url": args.url,
        "settings": {
            "clients": args.clients,
            "duration_s": args.duration_s,
            "interval_s": args.interval_s,
            "settle_s": args.settle_s,
            "p99_span_s": args.p99_span_s,
            "batch_targets": args.batch_targets,
            "bad_per_cycle": BAD_PER_CYCLE,
            "scene_per_cycle": 1,
            "backoff": not args.no_backoff,
            "seed": args.seed,
            "server": settings,
        },
    }
    mix = Mix.of(request_bodies(args.seed), args.batch_targets)
    headers = {"X-API-Key": args.api_key} if args.api_key else None
    machine = Machine.now()
    print(f"machine: {machine_description()}", flush=True)
    print(
        f"{args.clients} clients for {args.duration_s:.0f} s; a cycle: {len(mix.singles)} single, "
        f"1 of {len(mix.scenes)} in a scene, 1 batch of {args.batch_targets}, "
        f"{BAD_PER_CYCLE} of {len(mix.bad)} bad requests",
        flush=True,
    )

    def soak(url: str, rss: Callable[[], int] | None) -> list[Window]:
        return asyncio.run(
            run_soak(
                url, mix, args.clients, args.duration_s, args.interval_s, rss,
                not args.no_backoff, args.timeout_s, headers,
                report=lambda window: print(format_window(window), flush=True),
            )
        )  # fmt: skip

    if args.url:
        pid = args.pid
        rss = None if pid is None else (lambda: resident_memory_bytes(pid))
        record["server_rss_at_start_mib"] = None if rss is None else round(rss() / 2**20, 1)
        record["server_environment"] = memory_environment(pid)
        windows = soak(args.url, rss)
    else:
        started = dict(settings, api_key=args.api_key) if args.api_key else settings
        with LocalServer(log_level="warning", **started) as server:
            record["server_rss_at_start_mib"] = round(server.rss_bytes() / 2**20, 1)
            record["server_environment"] = memory_environment(server.pid)
            print(
                f"server pid {server.pid}: RSS {record['server_rss_at_start_mib']} MiB", flush=True
            )
            windows = soak(server.url, server.rss_bytes)
    verdicts = verdicts_of(windows, args.settle_s, args.p99_span_s)
    print(format_verdicts(verdicts), flush=True)
    if args.json:
        record["machine"] = machine.ended().as_json()
        record["windows"] = [
            {k: v for k, v in asdict(window).items() if k != "single_latencies_ms"}
            for window in windows
        ]
        record["verdicts"] = asdict(verdicts)
        write_record(args.json, record)
    return 1 if verdicts.errors else 0


if __name__ == "__main__":
    sys.exit(main())
