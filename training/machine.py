"""The machine a measurement ran on, so that every time a report quotes names it.

Times are only comparable within one run on one machine (the CPU model differs between
sessions), and a run that shared its cores with other work is slower than the machine:
the load average over the run says so (above the core count, other work waited). A
virtual machine's model name can hide its generation ("AMD EPYC" for every one of
them), so the record also keeps the processor's family and model numbers and the widest
integer dot product its flags list, which decide the int8 network's speed.
"""

from __future__ import annotations

import os
import platform
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any


def _cpuinfo(key: str) -> str | None:
    """The first /proc/cpuinfo value of `key` ("model name", "flags"), None without one."""
    try:
        with open("/proc/cpuinfo") as handle:
            for line in handle:
                if line.startswith(key):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo), else what the platform module knows."""
    return _cpuinfo("model name") or platform.processor() or platform.machine() or "unknown"


def cpu_flags() -> frozenset[str]:
    """The processor's feature flags as Linux lists them (none elsewhere)."""
    return frozenset((_cpuinfo("flags") or "").split())


# /proc/cpuinfo's keys of the processor's generation; the tab tells "model" from "model name".
CPU_GENERATION_KEYS = (("family", "cpu family"), ("model", "model\t"), ("stepping", "stepping"))


def cpu_generation() -> str | None:
    """The processor's family, model and stepping numbers as /proc/cpuinfo lists them
    ("family 25 model 17 stepping 1"), None where it lists none (not Linux on x86)."""
    numbers = [(name, _cpuinfo(key)) for name, key in CPU_GENERATION_KEYS]
    if any(value is None for _, value in numbers):
        return None
    return " ".join(f"{name} {value}" for name, value in numbers)


# The processor's integer dot products, widest first, as its flags name them. What the
# service's int8 layers run on is the kernel int8_mlp picks (the benchmark records it).
DOT_PRODUCT_FLAGS = (
    ("amx_int8", "AMX-INT8"),
    ("avx512_vnni", "AVX-512 VNNI"),
    ("avx_vnni", "AVX-VNNI"),
    ("avx2", "AVX2"),
)


def widest_dot_product(flags: frozenset[str]) -> str | None:
    """The widest integer dot-product instruction set among `flags`, None without any."""
    return next((name for flag, name in DOT_PRODUCT_FLAGS if flag in flags), None)


def load_average_1min() -> float | None:
    """The 1-minute load average (runnable processes), None where the OS has none."""
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


@dataclass(frozen=True)
class Machine:
    cpu: str
    cores: int
    python: str
    load_1min_start: float | None
    load_1min_end: float | None = None
    generation: str | None = None  # "family 25 model 17 stepping 1"; None in older records
    dot_product: str | None = None  # "AVX-512 VNNI"; None in older records

    @classmethod
    def now(cls) -> Machine:
        return cls(
            cpu_model(), os.cpu_count() or 1, platform.python_version(), load_average_1min(),
            generation=cpu_generation(), dot_product=widest_dot_product(cpu_flags()),
        )  # fmt: skip

    def ended(self) -> Machine:
        """The same record with the load average at the end of the run."""
        return replace(self, load_1min_end=load_average_1min())

    def describe(self, own_load: str | None = None) -> str:
        """CPU, cores, Python and the load average at the start and the end. Above the core
        count the load is other work's, which inflates times, unless `own_load` says what
        of the run's own loads the cores (a soak's clients and server, by design)."""
        identity = ", ".join(x for x in (self.generation, self.dot_product) if x is not None)
        text = self.cpu + (f" ({identity})" if identity else "")
        text += f", {self.cores} cores, Python {self.python}"
        loads = [x for x in (self.load_1min_start, self.load_1min_end) if x is not None]
        if loads:
            text += f"; 1-min load average {' -> '.join(f'{x:g}' for x in loads)}"
            if own_load is not None:
                text += f" ({own_load})"
            elif max(loads) > self.cores + 0.5:
                text += " (above the core count: other work shared the cores, times inflated)"
        return text

    def as_json(self) -> dict[str, object]:
        return asdict(self)

    def processor(self) -> dict[str, object]:
        """What a model's weights depend on besides the command: the processor (model,
        generation, widest dot product) and its core count, without the load."""
        return {
            "cpu": self.cpu, "generation": self.generation, "dot_product": self.dot_product,
            "cores": self.cores,
        }  # fmt: skip

    @classmethod
    def from_json(cls, record: Mapping[str, Any]) -> Machine:
        return cls(**record)
