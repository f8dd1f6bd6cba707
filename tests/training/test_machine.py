"""training/machine.py: the CPU model is read from /proc/cpuinfo where it exists (the same
name the kernel lists); the load average is the OS's own; a record round-trips through its
JSON; the description names CPU, cores and load, and says the times are inflated exactly
when the load went above the core count (by more than half a process)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from training.machine import Machine, cpu_model, load_average_1min


def test_the_cpu_model_and_load_are_the_os_own() -> None:
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        names = [line for line in cpuinfo.read_text().splitlines() if line.startswith("model name")]
        if names:
            assert cpu_model() == names[0].split(":", 1)[1].strip()
    before = os.getloadavg()[0]
    measured = load_average_1min()
    after = os.getloadavg()[0]
    assert measured is not None
    assert min(before, after) - 0.01 <= measured <= max(before, after) + 0.01


@pytest.mark.parametrize(
    ("start", "end", "inflated"),
    [(0.4, 1.9, False), (1.0, 2.5, False), (2.6, 1.0, True), (0.5, 4.0, True)],
)
def test_the_description_flags_a_load_above_the_cores(
    start: float, end: float, inflated: bool
) -> None:
    machine = Machine("Test CPU", 2, "3.11.9", start, end)
    text = machine.describe()
    assert text.startswith(f"Test CPU, 2 cores, Python 3.11.9; 1-min load average {start:g} -> ")
    assert ("times inflated" in text) is inflated
    assert Machine.from_json(machine.as_json()) == machine


def test_a_run_that_loads_the_cores_itself_says_so_instead() -> None:
    """A soak's or a load test's own clients and server load the cores by design."""
    text = Machine("Test CPU", 2, "3.11.9", 2.8, 3.1).describe("its own clients")
    assert text.endswith("1-min load average 2.8 -> 3.1 (its own clients)")


def test_a_run_records_its_start_and_end() -> None:
    started = Machine.now()
    assert started.cores == os.cpu_count() and started.load_1min_end is None
    ended = started.ended()
    assert ended.load_1min_start == started.load_1min_start
    assert ended.load_1min_end is not None
    assert "load average" in ended.describe()
