"""malloc arenas: `limit_malloc_arenas` caps the arenas glibc gives a process's threads.

In a fresh Python process, 8 threads that each allocate and hold a few hundred small
blocks at once make glibc open arenas (counted from its own malloc_info report, one
<heap nr=...> per arena); after `limit_malloc_arenas(2)` it opens at most 2, without it
more than 2 (so the check can fail). `create_app` sets the cap from its settings, and 0
asks for nothing.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from service.config import Settings
from service.main import create_app, limit_malloc_arenas

COUNT_ARENAS = """
import ctypes, os, sys, tempfile, threading
from service.main import limit_malloc_arenas
if sys.argv[1] != "0":
    assert limit_malloc_arenas(int(sys.argv[1]))
libc = ctypes.CDLL("libc.so.6")
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]
libc.fdopen.restype = ctypes.c_void_p
libc.malloc_info.argtypes = [ctypes.c_int, ctypes.c_void_p]
libc.fclose.argtypes = [ctypes.c_void_p]
barrier = threading.Barrier(8)
def work():
    blocks = [libc.malloc(4096) for _ in range(200)]
    barrier.wait()  # every thread holds its blocks at once
    for block in blocks:
        libc.free(block)
threads = [threading.Thread(target=work) for _ in range(8)]
for t in threads: t.start()
for t in threads: t.join()
with tempfile.TemporaryFile() as report:
    stream = libc.fdopen(os.dup(report.fileno()), b"w")
    libc.malloc_info(0, stream)
    libc.fclose(stream)
    report.seek(0)
    print(report.read().decode().count("<heap nr="))
"""


def arenas(limit: int) -> int:
    result = subprocess.run(
        [sys.executable, "-c", COUNT_ARENAS, str(limit)], capture_output=True, text=True, check=True
    )
    return int(result.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc only")
def test_the_cap_holds_the_threads_to_two_arenas() -> None:
    assert arenas(2) <= 2
    assert arenas(0) > 2


def test_zero_asks_for_nothing_and_create_app_applies_the_setting() -> None:
    assert limit_malloc_arenas(0) is False
    create_app(Settings(malloc_arenas=2))  # sets the cap; the app builds as before
