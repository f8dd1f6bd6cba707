"""Changing an exported model directory all at once: on a hidden copy, swapped in whole.

The registry skips hidden directories, so a server starting meanwhile never reads a
half-changed model; a change that fails leaves the directory as it was.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def staged_copy(model_dir: Path) -> Iterator[Path]:
    """Yield a hidden copy of `model_dir` to change; when the block ends without an error
    the copy replaces `model_dir`, otherwise it is removed and the error goes on."""
    staging = model_dir.with_name(f".{model_dir.name}.staging")
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copytree(model_dir, staging)
    try:
        yield staging
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    retired = model_dir.with_name(f".{model_dir.name}.retired")
    shutil.rmtree(retired, ignore_errors=True)
    model_dir.rename(retired)
    staging.rename(model_dir)
    shutil.rmtree(retired)
