"""Soak: resident memory after many requests stays within a stated bound of where it started.

A real server is warmed up (every model, every request size once), its resident set
size read from /proc, then sent 150 more requests from 4 concurrent clients: answers for
every model at sizes up to 1000 samples, unreachable targets, malformed bodies, unknown
models, oversized bodies. Its RSS afterwards must be within SOAK_BOUND_BYTES of the
warmed-up figure (the figures are printed), and the server must still be ready.
"""

from __future__ import annotations

import asyncio
import itertools
from typing import Any

import httpx

from tests.support.bodies import PLANAR, POSE, POSITION
from tools.local_server import LocalServer

SOAK_BOUND_BYTES = 48 * 2**20  # 48 MiB over the warmed-up RSS
REQUESTS = 150
CLIENTS = 4
SIZES = (50, 300, 1000)


def requests() -> list[tuple[str, Any]]:
    """One cycle of (kind, body): every model at every size, and the bad ones."""
    cycle: list[tuple[str, Any]] = []
    for body, size in itertools.product((PLANAR, POSE, POSITION), SIZES):
        cycle.append(("json", {**body, "num_samples": size, "seed": size}))
    cycle += [
        ("json", {**PLANAR, "target": {"position": [5.0, 0.0]}}),  # no_solution
        ("json", {**PLANAR, "target": {"position": [0.5]}}),  # 422
        ("json", {**PLANAR, "robot": "ur10"}),  # 404
        ("raw", b'{"robot": "planar3r", "target": '),  # 422, not JSON
        ("json", {**PLANAR, "reference_configuration": [0.0] * 20000}),  # 413
    ]
    return cycle


async def send_all(url: str, count: int, seed: int) -> list[int]:
    cycle = requests()
    work = [cycle[(seed + i) % len(cycle)] for i in range(count)]
    statuses: list[int] = []
    async with httpx.AsyncClient(base_url=url, timeout=120) as client:

        async def worker(index: int) -> None:
            for kind, body in work[index::CLIENTS]:
                if kind == "json":
                    response = await client.post("/smm", json=body)
                else:
                    response = await client.post(
                        "/smm", content=body, headers={"content-type": "application/json"}
                    )
                statuses.append(response.status_code)

        await asyncio.gather(*(worker(i) for i in range(CLIENTS)))
    return statuses


def test_resident_memory_stays_bounded_over_many_requests() -> None:
    with LocalServer() as server:
        warm = asyncio.run(send_all(server.url, len(requests()), seed=0))
        assert set(warm) == {200, 404, 413, 422}
        rss_before = server.rss_bytes()
        statuses = asyncio.run(send_all(server.url, REQUESTS, seed=1))
        rss_after = server.rss_bytes()
        assert httpx.get(f"{server.url}/readyz").status_code == 200
    print(
        f"soak: {len(statuses)} requests; RSS {rss_before / 2**20:.1f} MiB after warm-up, "
        f"{rss_after / 2**20:.1f} MiB after ({(rss_after - rss_before) / 2**20:+.1f} MiB; "
        f"bound +{SOAK_BOUND_BYTES / 2**20:.0f} MiB)"
    )
    assert set(statuses) <= {200, 404, 413, 422}
    assert rss_after - rss_before <= SOAK_BOUND_BYTES
