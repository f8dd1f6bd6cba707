"""Load, briefly: concurrent clients mixing every served model get answers, and no errors;
the record names its machine as every report does (the processor's generation too).

The CI version of `python -m tools.load` (same code): 6 clients for 10 s against a real
server with default settings. Every request gets 200 (or, at worst, a 503 with
Retry-After that the client honours); every model is answered; nothing else happens.
"""

from __future__ import annotations

import asyncio

from tests.support.bundled import bundled_model_ids
from tools.load import format_report, machine_description, request_bodies, run_load, summarise
from tools.local_server import LocalServer
from training.machine import cpu_flags, cpu_generation, cpu_model, widest_dot_product

CLIENTS = 6
DURATION_S = 10.0


def test_mixed_concurrent_load_has_no_errors() -> None:
    bodies = request_bodies(seed=0)
    with LocalServer() as server:
        outcomes = asyncio.run(
            run_load(server.url, bodies, CLIENTS, DURATION_S, backoff=True, timeout_s=60.0)
        )
    report = summarise(outcomes, CLIENTS, DURATION_S)
    print(format_report(report))
    assert report.errors == 0, report.statuses
    assert sorted(report.by_model) == bundled_model_ids()
    assert all(figures["answered"] > 0 for figures in report.by_model.values())
    assert all(o.retry_after is not None for o in outcomes if o.status == 503)


def test_the_machine_is_named_with_its_generation_and_dot_product() -> None:
    """A virtual machine's model name alone ("AMD EPYC") hides a generation whose int8
    speed differs several times over: the load and soak records name it, and the widest
    integer dot product, read from /proc/cpuinfo."""
    text = machine_description()
    assert text.startswith(cpu_model())
    for part in (cpu_generation(), widest_dot_product(cpu_flags())):
        if part is not None:
            assert part in text
    assert " cores, Python 3." in text and "load" not in text
