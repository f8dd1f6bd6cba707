"""Load test: many concurrent clients mixing every served model, for a bounded time.

    python -m tools.load --clients 16 --duration-s 60
    python -m tools.load --clients 16 4 --duration-s 60 --json docs/benchmark/load.json

starts a server on 127.0.0.1 (tools.local_server) unless `--url` names a running one
(loopback only), then runs `--clients` concurrent clients for `--duration-s` seconds;
with several client counts, one run after another, each against a server of its own.
Each client loops: pick a served model in turn, POST /smm for a reachable target of it
(the FK of a random configuration within the limits, computed with the model's own
exported kinematics), wait for the answer. A 503 is honoured as a well-behaved client
would, by sleeping its Retry-After (unless `--no-backoff`). The report: requests,
throughput, p50/p95/p99 latency (all answers and per model), statuses, and errors
(anything but 200 and 503, transport failures included). Exit code 1 when errors > 0.
`--json` writes every run's report, with the command, the commit and the machine (its load
average at the start and the end), to one file: docs/benchmark/load.json is the committed
one that the docs' load table is written from.
"""

from __future__ import annotations

import argparse
import asyncio
import ipaddress
import os
import random
import sys
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, replace
from typing import Any
from urllib.parse import urlparse

import httpx
import numpy as np

from service.manifest import KINEMATICS_FILE, MANIFEST_FILE, REPO_MODELS_DIR, Manifest
from service.models.sessions import OnnxKinematics, open_session
from service.pipeline.joint_space import JointLimits
from service.pipeline.targets import fields_reached
from tools.local_server import LocalServer
from tools.records import command_line, write_record
from training.checkout import git_commit
from training.machine import Machine

TARGETS_PER_MODEL = 64


def require_loopback(url: str) -> None:
    """Refuse to send load anywhere but this machine's loopback."""
    host = urlparse(url).hostname or ""
    if host == "localhost":
        return
    try:
        if ipaddress.ip_address(host).is_loopback:
            return
    except ValueError:
        pass
    raise SystemExit(f"--url must be on the loopback (127.0.0.0/8, ::1, localhost), got {host!r}")


def reachable_targets(manifest: Manifest, count: int, seed: int) -> list[dict[str, Any]]:
    """`count` targets of a model: the FK of configurations uniform within its limits."""
    limits = JointLimits.of(manifest.joints)
    rng = np.random.default_rng(seed)
    q = rng.uniform(limits.lower_rad, limits.upper_rad, size=(count, manifest.joints.count))
    kinematics = OnnxKinematics(
        open_session(REPO_MODELS_DIR / manifest.model_id / KINEMATICS_FILE, threads=1)
    )
    fk = kinematics(q)
    return [
        fields_reached(manifest.task, fk.position_m[i], fk.rotation[i]).wire() for i in range(count)
    ]


def request_bodies(seed: int) -> dict[str, list[dict[str, Any]]]:
    """Per model id, POST /smm bodies for the bundled models."""
    bodies = {}
    for manifest_path in sorted(REPO_MODELS_DIR.glob(f"*/{MANIFEST_FILE}")):
        manifest = Manifest.model_validate_json(manifest_path.read_bytes())
        bodies[manifest.model_id] = [
            {
                "robot": manifest.robot,
                "task": manifest.task.name,
                "target": target,
                "seed": i,
                "max_configurations_per_component": 5,
            }
            for i, target in enumerate(reachable_targets(manifest, TARGETS_PER_MODEL, seed))
        ]
    return bodies


@dataclass
class Outcome:
    model: str
    status: int  # 0 for a transport failure
    latency_s: float
    started_s: float
    retry_after: str | None = None


@dataclass
class Report:
    clients: int
    duration_s: float
    requests: int
    throughput_rps: float
    statuses: dict[str, int]
    errors: int
    rejected_503: int
    p50_ms: float
    p95_ms: float
    p99_ms: float
    by_model: dict[str, dict[str, float]] = field(default_factory=dict)
    machine: str = ""
    server_rss_mib: dict[str, float] = field(default_factory=dict)  # when started here


def percentiles_ms(latencies_s: list[float]) -> tuple[float, float, float]:
    if not latencies_s:
        return (float("nan"),) * 3
    p50, p95, p99 = np.percentile(np.asarray(latencies_s) * 1e3, [50, 95, 99])
    return float(p50), float(p95), float(p99)


def summarise(outcomes: list[Outcome], clients: int, duration_s: float) -> Report:
    statuses = Counter(str(o.status) for o in outcomes)
    answered = [o for o in outcomes if o.status == 200]
    p50, p95, p99 = percentiles_ms([o.latency_s for o in answered])
    by_model = {}
    for model in sorted({o.model for o in outcomes}):
        mine = [o.latency_s for o in answered if o.model == model]
        m50, m95, m99 = percentiles_ms(mine)
        by_model[model] = {"answered": len(mine), "p50_ms": m50, "p95_ms": m95, "p99_ms": m99}
    return Report(
        clients=clients,
        duration_s=duration_s,
        requests=len(outcomes),
        throughput_rps=len(answered) / duration_s,
        statuses=dict(sorted(statuses.items())),
        errors=sum(n for s, n in statuses.items() if s not in ("200", "503")),
        rejected_503=statuses.get("503", 0),
        p50_ms=p50,
        p95_ms=p95,
        p99_ms=p99,
        by_model=by_model,
        machine=machine_description(),
    )


def machine_description() -> str:
    """The CPU with its generation and widest integer dot product, the cores and Python, as
    every report names its machine (`training.machine.Machine.describe`), without a load."""
    return replace(Machine.now(), load_1min_start=None).describe()


async def run_load(
    url: str,
    bodies: dict[str, list[dict[str, Any]]],
    clients: int,
    duration_s: float,
    backoff: bool,
    timeout_s: float,
    headers: dict[str, str] | None = None,
) -> list[Outcome]:
    """`clients` concurrent loops of POST /smm for `duration_s` seconds; every outcome."""
    outcomes: list[Outcome] = []
    models = sorted(bodies)
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    async with httpx.AsyncClient(
        base_url=url, timeout=timeout_s, limits=limits, headers=headers
    ) as http:
        start = time.perf_counter()
        stop_at = start + duration_s

        async def client(index: int) -> None:
            rng = random.Random(index)
            turn = index
            while time.perf_counter() < stop_at:
                model = models[turn % len(models)]
                turn += 1
                body = rng.choice(bodies[model])
                sent = time.perf_counter()
                try:
                    response = await http.post("/smm", json=body)
                    status, retry_after = response.status_code, response.headers.get("retry-after")
                except httpx.HTTPError:
                    status, retry_after = 0, None
                done = time.perf_counter()
                outcomes.append(Outcome(model, status, done - sent, sent - start, retry_after))
                if status == 503 and backoff and retry_after is not None:
                    await asyncio.sleep(min(float(retry_after), max(0.0, stop_at - done)))

        await asyncio.gather(*(client(i) for i in range(clients)))
    return outcomes


def format_report(report: Report) -> str:
    lines = [
        f"machine: {report.machine}",
        f"clients {report.clients}, duration {report.duration_s:.0f} s: {report.requests} "
        f"requests, {report.throughput_rps:.2f} answers/s",
        f"latency of 200s: p50 {report.p50_ms:.0f} ms, p95 {report.p95_ms:.0f} ms, "
        f"p99 {report.p99_ms:.0f} ms",
        f"statuses: {report.statuses}; errors: {report.errors}; 503s: {report.rejected_503}",
    ]
    if report.server_rss_mib:
        lines.append(
            "server resident memory: "
            + ", ".join(f"{k} {v:.0f} MiB" for k, v in report.server_rss_mib.items())
        )
    for model, figures in report.by_model.items():
        lines.append(
            f"  {model}: {figures['answered']:.0f} answered, p50 {figures['p50_ms']:.0f} ms, "
            f"p95 {figures['p95_ms']:.0f} ms, p99 {figures['p99_ms']:.0f} ms"
        )
    return "\n".join(lines)


def add_client_arguments(parser: argparse.ArgumentParser) -> None:
    """The options a load client shares with the soak (tools/soak.py): per-request timeout,
    seed, backoff, API key, the JSON record, and the started server's settings."""
    parser.add_argument("--timeout-s", type=float, default=60.0, help="per-request timeout")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-backoff", action="store_true", help="ignore Retry-After")
    parser.add_argument("--api-key", default=os.environ.get("SMM_API_KEY"))
    parser.add_argument("--json", help="also write the record here (JSON)")
    parser.add_argument(
        "--setting",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a Settings field for the started server, e.g. max_in_flight=2 (repeatable)",
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", help="a running server (loopback only); default: start one")
    parser.add_argument(
        "--clients", type=int, nargs="+", default=[16], help="one run per count, in turn"
    )
    parser.add_argument("--duration-s", type=float, default=60.0)
    add_client_arguments(parser)
    args = parser.parse_args(argv)
    bodies = request_bodies(args.seed)
    headers = {"X-API-Key": args.api_key} if args.api_key else None
    settings = dict(item.split("=", 1) for item in args.setting)
    if args.url:
        require_loopback(args.url)
    record: dict[str, Any] = {
        "command": command_line("tools.load", argv),
        "url": args.url,
        "settings": settings,
    }
    if args.json:
        record["git_commit"] = git_commit()
    machine = Machine.now()

    def load(url: str, clients: int) -> Report:
        outcomes = asyncio.run(
            run_load(
                url, bodies, clients, args.duration_s, not args.no_backoff, args.timeout_s,
                headers,
            )
        )  # fmt: skip
        return summarise(outcomes, clients, args.duration_s)

    reports = []
    for clients in args.clients:
        if args.url:
            report = load(args.url, clients)
        else:
            started = dict(settings, api_key=args.api_key) if args.api_key else settings
            with LocalServer(log_level="warning", **started) as server:
                rss_start = server.rss_bytes()
                report = load(server.url, clients)
                report.server_rss_mib = {
                    "at start": rss_start / 2**20,
                    "after the run": server.rss_bytes() / 2**20,
                }
        print(format_report(report), flush=True)
        reports.append(report)
    if args.json:
        record["machine"] = machine.ended().as_json()
        record["runs"] = [asdict(report) for report in reports]
        write_record(args.json, record)
    return 1 if any(report.errors for report in reports) else 0


if __name__ == "__main__":
    sys.exit(main())
