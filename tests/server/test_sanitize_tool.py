"""The kernels under AddressSanitizer (`python -m tools.sanitize`): the tests it is given run
on the sanitized builds of the compiled kernels, so a kernel writing past a buffer stops the
run with a report naming the kernel's function and line, and the exit status says so; tests
whose kernels stay inside their buffers pass, on the sanitized builds, whatever CPython
itself leaves unfreed at exit; and of a leak report, the leaks allocated through a kernel's
source are picked out (checked on a real report of a program that leaks one block from a
file at a kernel's path and one from elsewhere); its arguments reach pytest in their order,
the default tests added only where none names a test path."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tools import sanitize

REPO = Path(__file__).resolve().parents[2]

# A test module the tool runs: the first test calls the chaining kernel with the buffers its
# wrapper gives it, the second with an output buffer of one entry where it writes five.
CASES = """
import numpy as np
from service.pipeline import _native, native


def test_inside_its_buffers() -> None:
    rows, first, closed = native.chain_fronts(np.zeros((5, 7)), 3, np.array([0, 3]),
                                              np.array([3, -1, -1, 0, -1, -1]))
    assert len(first) == 3
    assert "smm-asan-" in _native.__file__  # the sanitized build, not the installed one


def test_past_a_buffer() -> None:
    q, seeds = np.zeros((5, 7)), 3
    by_front, partner = np.array([0, 3]), np.array([3, -1, -1, 0, -1, -1])
    scratch = [np.empty(7, np.int64), np.empty(2, np.int64), np.empty(3, np.uint8),
               np.empty(6, np.uint8), np.empty(5, np.int64), np.empty(5, np.int64)]
    rows = np.empty(1, np.int64)  # 5 rows are written here
    _native.chain_fronts(q, 5, 7, seeds, by_front, partner, *scratch, rows,
                         np.empty(4, np.int64), np.empty(3, np.uint8))
"""


# Two leaks: one block allocated in a file at a kernel's path, one in main.c.
KERNEL_C = """
#include <stdlib.h>
void *kernel_scratch(void) { return malloc(48); }
"""
MAIN_C = """
#include <stdlib.h>
void *kernel_scratch(void);
void *volatile kept;
static void drop(void) { kept = kernel_scratch(); kept = 0; kept = malloc(32); kept = 0; }
int main(void) { drop(); return 0; }
"""


def _run(tests: Path, *selection: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tools.sanitize", str(tests), "-q", *selection],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip


@pytest.fixture(scope="module")
def cases(tmp_path_factory: pytest.TempPathFactory) -> Path:
    try:
        sanitize.runtime_library(sanitize.compiler(), "libasan.so")
    except (SystemExit, OSError, subprocess.CalledProcessError):
        pytest.skip("the C compiler here has no AddressSanitizer runtime")
    path = tmp_path_factory.mktemp("sanitize") / "test_cases.py"
    path.write_text(CASES)
    return path


def test_a_write_past_a_buffer_stops_the_run_naming_the_kernel(cases: Path) -> None:
    ran = _run(cases)
    assert ran.returncode != 0
    assert "ERROR: AddressSanitizer: heap-buffer-overflow" in ran.stderr
    assert "native.c" in ran.stderr and "chain_fronts_of" in ran.stderr


def test_kernels_inside_their_buffers_pass_on_the_sanitized_builds(cases: Path) -> None:
    ran = _run(cases, "-k", "inside")
    assert ran.returncode == 0, ran.stdout[-2000:] + ran.stderr[-2000:]
    assert "1 passed" in ran.stdout


def test_of_a_leak_report_only_the_kernels_leaks_count(tmp_path: Path) -> None:
    try:
        cc = sanitize.compiler()
        sanitize.runtime_library(cc, "libasan.so")
    except (SystemExit, OSError, subprocess.CalledProcessError):
        pytest.skip("the C compiler here has no AddressSanitizer runtime")
    kernel = tmp_path / sanitize.KERNEL_SOURCES[0]
    kernel.parent.mkdir(parents=True)
    kernel.write_text(KERNEL_C)
    (tmp_path / "main.c").write_text(MAIN_C)
    flags = ["-fsanitize=address", "-fno-omit-frame-pointer", "-g", "-O0"]
    build = [cc, *flags, sanitize.KERNEL_SOURCES[0], "main.c", "-o", "leaks"]
    subprocess.run(build, cwd=tmp_path, check=True, capture_output=True)
    log = tmp_path / "asan"
    options = f"detect_leaks=1:exitcode=0:log_path={log}"
    ran = subprocess.run(
        [str(tmp_path / "leaks")], env={"ASAN_OPTIONS": options}, capture_output=True, timeout=60
    )
    assert ran.returncode == 0  # exitcode=0: the leak check leaves the status alone
    (report,) = tmp_path.glob("asan.*")
    text = report.read_text()
    assert sanitize.is_leak_report(text)
    assert len(sanitize.leak_blocks(text)) == 2
    (theirs,) = sanitize.kernel_leaks(text)
    assert theirs.startswith("Direct leak of 48 byte(s)") and "kernel_scratch" in theirs


def test_arguments_reach_pytest_in_order_with_the_default_tests_only_where_none_is_named() -> None:
    defaults = list(sanitize.DEFAULT_TESTS)
    assert sanitize.arguments_for_pytest([]) == defaults
    assert sanitize.arguments_for_pytest(["-q"]) == ["-q", *defaults]
    # An option's value is not a test path: it stays after its option.
    assert sanitize.arguments_for_pytest(["-p", "no:randomly", "-k", "chain"]) == [
        "-p", "no:randomly", "-k", "chain", *defaults,
    ]  # fmt: skip
    named = ["-p", "no:randomly", "tests/service/pipeline/test_native.py::test_x", "-q"]
    assert sanitize.arguments_for_pytest(named) == named
