"""mmap threshold: `fix_mmap_threshold` keeps glibc mapping large blocks on their own.

glibc maps a block of at least its threshold (128 KiB at start) on its own and unmaps it
when freed, but each such free raises the threshold to the freed block's size, so a
process that once freed a 1 MiB array then serves a 512 KiB one from its heap. Counted
from glibc's own mallinfo2 (hblks: blocks mapped on their own), in a fresh Python
process: after `fix_mmap_threshold(128 KiB)` the 512 KiB block is still mapped, without it
it is not (so the check can fail). `create_app` applies the setting, and 0 asks for
nothing.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from service.config import Settings
from service.main import create_app, fix_mmap_threshold

COUNT_MAPPED = """
import ctypes, sys
from service.main import fix_mmap_threshold
if sys.argv[1] != "0":
    assert fix_mmap_threshold(int(sys.argv[1]))
class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
        "uordblks", "fordblks", "keepcost")]
libc = ctypes.CDLL("libc.so.6")
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
libc.mallinfo2.restype = MallInfo2
before = libc.mallinfo2().hblks
libc.free(libc.malloc(1 << 20))  # a large block freed: glibc's own threshold rises past it
block = libc.malloc(1 << 19)
print(libc.mallinfo2().hblks - before)
libc.free(block)
"""


def mapped_blocks(threshold_bytes: int) -> int:
    result = subprocess.run(
        [sys.executable, "-c", COUNT_MAPPED, str(threshold_bytes)],
        capture_output=True,
        text=True,
        check=True,
    )
    return int(result.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc only")
def test_a_fixed_threshold_keeps_mapping_blocks_after_a_larger_one_is_freed() -> None:
    assert mapped_blocks(128 * 1024) == 1
    assert mapped_blocks(0) == 0


def test_zero_asks_for_nothing_and_create_app_applies_the_setting() -> None:
    assert fix_mmap_threshold(0) is False
    create_app(Settings(malloc_mmap_threshold_bytes=128 * 1024))
