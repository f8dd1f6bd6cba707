"""admission: at most N computations, a bounded wait, prompt refusals, full recovery after."""

from __future__ import annotations

import asyncio
import time

import pytest

from service.errors import OverloadedError
from service.http.admission import Admission


async def hold(admission: Admission, release: asyncio.Event, entered: list[int], i: int) -> None:
    async with admission.slot(remaining_s=60.0):
        entered.append(i)
        await release.wait()


def test_capacity_queue_and_refusals() -> None:
    async def scenario() -> None:
        admission = Admission(max_in_flight=2, max_queued=1, max_wait_s=5.0, retry_after_s=3)
        release = asyncio.Event()
        entered: list[int] = []
        holders = [asyncio.create_task(hold(admission, release, entered, i)) for i in range(3)]
        await asyncio.sleep(0.05)
        assert sorted(entered) == [0, 1]  # two computing, the third waits
        assert (admission.in_flight, admission.waiting) == (2, 1)

        start = time.perf_counter()
        with pytest.raises(OverloadedError) as refused:
            async with admission.slot(remaining_s=60.0):
                pass
        assert time.perf_counter() - start < 0.05  # at once, not after a wait
        assert refused.value.reason == "queue_full" and refused.value.retry_after_s == 3
        assert "SMM_MAX_IN_FLIGHT=2" in str(refused.value)
        assert "2 requests computing and 1 waiting" in str(refused.value)

        release.set()
        await asyncio.gather(*holders)
        assert sorted(entered) == [0, 1, 2]  # the waiting one ran once a slot freed
        assert (admission.in_flight, admission.waiting) == (0, 0)

    asyncio.run(scenario())


def test_a_wait_is_bounded_by_the_setting_and_by_the_deadline() -> None:
    async def scenario() -> None:
        admission = Admission(max_in_flight=1, max_queued=4, max_wait_s=0.2, retry_after_s=1)
        release = asyncio.Event()
        holder = asyncio.create_task(hold(admission, release, [], 0))
        await asyncio.sleep(0.02)
        for remaining_s, expected_s in ((60.0, 0.2), (0.05, 0.05)):
            start = time.perf_counter()
            with pytest.raises(OverloadedError) as refused:
                async with admission.slot(remaining_s=remaining_s):
                    pass
            waited = time.perf_counter() - start
            assert expected_s <= waited < expected_s + 0.5
            assert refused.value.reason == "queue_timeout"
        assert admission.waiting == 0
        release.set()
        await holder

    asyncio.run(scenario())


def test_capacity_recovers_after_a_burst_of_refusals_and_timeouts() -> None:
    async def scenario() -> None:
        admission = Admission(max_in_flight=2, max_queued=3, max_wait_s=0.05, retry_after_s=1)

        async def request() -> str:
            try:
                async with admission.slot(remaining_s=60.0):
                    await asyncio.sleep(0.03)
                return "ok"
            except OverloadedError as error:
                return error.reason

        outcomes = await asyncio.gather(*(request() for _ in range(50)))
        assert outcomes.count("ok") >= 2
        assert {"queue_full"} <= set(outcomes) <= {"ok", "queue_full", "queue_timeout"}
        # Nothing leaked: every slot is free again, and two can be held at once.
        assert (admission.in_flight, admission.waiting) == (0, 0)
        release = asyncio.Event()
        entered: list[int] = []
        holders = [asyncio.create_task(hold(admission, release, entered, i)) for i in range(2)]
        await asyncio.sleep(0.02)
        assert sorted(entered) == [0, 1]
        release.set()
        await asyncio.gather(*holders)

    asyncio.run(scenario())
