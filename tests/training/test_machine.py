"""training/machine.py: the CPU model, its family, model and stepping numbers are read from
/proc/cpuinfo where it exists (the same values the kernel lists); the widest integer dot
product is the first of AMX-INT8, AVX-512 VNNI, AVX-VNNI and AVX2 the flags hold; the load
average is the OS's own; a record round-trips through its JSON, and one written before the
generation was recorded still loads; the description names CPU, its generation, cores and
load, and says the times are inflated exactly when the load went above the core count (by
more than half a process)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from training.machine import (
    Machine,
    cpu_generation,
    cpu_model,
    load_average_1min,
    widest_dot_product,
)


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


def test_the_generation_is_the_kernel_listed_family_model_and_stepping() -> None:
    cpuinfo = Path("/proc/cpuinfo")
    fields: dict[str, str] = {}
    if cpuinfo.exists():
        for line in cpuinfo.read_text().split("\n\n")[0].splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    if not {"cpu family", "model", "stepping"} <= fields.keys():
        assert cpu_generation() is None
        return
    expected = (
        f"family {fields['cpu family']} model {fields['model']} stepping {fields['stepping']}"
    )
    assert cpu_generation() == expected


@pytest.mark.parametrize(
    ("flags", "widest"),
    [
        ({"sse2", "avx2", "avx512f", "avx512_vnni", "amx_tile", "amx_int8"}, "AMX-INT8"),
        ({"avx2", "avx_vnni", "avx512f", "avx512_vnni"}, "AVX-512 VNNI"),
        ({"avx2", "avx_vnni"}, "AVX-VNNI"),
        ({"sse4_2", "avx2", "fma"}, "AVX2"),
        ({"sse4_2", "neon"}, None),
    ],
)
def test_the_widest_dot_product_is_the_first_the_flags_hold(
    flags: set[str], widest: str | None
) -> None:
    assert widest_dot_product(frozenset(flags)) == widest


def test_the_description_names_the_generation_and_an_older_record_still_loads() -> None:
    machine = Machine(
        "AMD EPYC", 2, "3.11.9", 0.5, 1.0,
        generation="family 25 model 17 stepping 1", dot_product="AVX-512 VNNI",
    )  # fmt: skip
    text = machine.describe()
    assert text.startswith("AMD EPYC (family 25 model 17 stepping 1, AVX-512 VNNI), 2 cores")
    assert Machine.from_json(machine.as_json()) == machine
    older = {"cpu": "AMD EPYC", "cores": 2, "python": "3.11.9", "load_1min_start": 0.5,
             "load_1min_end": 1.0}  # fmt: skip
    assert Machine.from_json(older).describe().startswith("AMD EPYC, 2 cores")


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
