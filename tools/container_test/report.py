"""The run's figures and each check's outcome: printed, and written to docs/container.json
(what docs/deployment.md quotes, through tools/docs) when every check passed."""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path
from typing import Any

from tools.container_test.outcomes import Checks
from training.machine import Machine


def finish(
    checks: Checks,
    figures: dict[str, Any],
    timings: dict[str, float],
    started: float,
    path: Path,
) -> int:
    """Print the figures, write them to `path` when every check passed; the exit status."""
    timings["total_s"] = round(time.monotonic() - started, 1)
    record = {
        "measured_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": machine_words(Machine.now()),
        **figures,
        "timings": timings,
        "checks": [{"name": n, "ok": ok, "detail": d} for n, ok, d in checks.results],
    }
    mib = 1024 * 1024
    if "image_bytes" in figures:
        print(
            f"image: {figures['image_bytes'] / mib:.0f} MiB (base {figures['base_bytes'] / mib:.0f}"
            f" MiB + {figures['added_bytes'] / mib:.0f} MiB of ours)"
        )
    if "cold_start_s" in figures:
        print(
            f"cold start: {figures['cold_start_s']} s from process start to /readyz 200 "
            f"({figures['run_to_ready_s']} s from `buildah run`)"
        )
    print("timings: " + ", ".join(f"{k} {v}" for k, v in timings.items()))
    failed = checks.failed
    if failed:
        print(f"container test FAILED: {len(failed)} of {len(checks.results)} checks: {failed}")
        return 1
    path.write_text(json.dumps(record, indent=2) + "\n")
    print(f"container test passed: {len(checks.results)} checks; figures in {path}")
    return 0


def machine_words(machine: Machine) -> str:
    """The processor as every report names it (its generation and widest integer dot
    product: a VM's "AMD EPYC" is Zen 3, 4 or 5 alike), its cores and architecture."""
    identity = ", ".join(x for x in (machine.generation, machine.dot_product) if x is not None)
    cpu = machine.cpu + (f" ({identity})" if identity else "")
    return f"{cpu}, {machine.cores} cores, {platform.machine()}"
