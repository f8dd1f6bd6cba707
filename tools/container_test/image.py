"""What the image holds: no torch, pip, compiler or download cache, and the repository's
models in /app; the size of its root file system."""

from __future__ import annotations

import os
import re
from pathlib import Path

from tools.container_test import ROOT
from tools.container_test.outcomes import Checks


def scan_image(root: Path) -> dict[str, list[str]]:
    """What the image must not hold, found by walking its root file system."""
    found: dict[str, list[str]] = {"torch": [], "pip": [], "compilers": [], "caches": []}
    for directory, subdirs, files in os.walk(root):
        relative = "/" + str(Path(directory).relative_to(root)).lstrip(".")
        packages = relative.endswith(("/site-packages", "/dist-packages"))
        for name in subdirs + files:
            # A distribution, not a vendored shim such as scipy's array_api_compat/torch.
            if re.fullmatch(r"(torch|pytorch_kinematics)(-.*\.dist-info)?", name) and packages:
                found["torch"].append(f"{relative}/{name}")
        if relative.startswith("/opt/venv") and ("pip" in subdirs or "pip" in files):
            found["pip"].append(f"{relative}/pip")
        if relative.endswith("/.cache") and (subdirs or files):
            found["caches"].append(relative)
    for compiler in ("gcc", "cc", "g++", "c++", "clang", "make"):
        for bin_dir in ("usr/bin", "usr/local/bin", "opt/venv/bin"):
            if (root / bin_dir / compiler).exists():
                found["compilers"].append(f"/{bin_dir}/{compiler}")
    for cache in ("root/.cache/pip", "var/cache/apt/archives/partial"):
        if (root / cache).is_dir() and any((root / cache).iterdir()):
            found["caches"].append(f"/{cache}")
    return found


def baked_model_differences(baked: Path) -> list[str]:
    """Files of the repository's models/ missing from `baked` or different there."""
    differing = []
    for path in sorted((ROOT / "models").rglob("*")):
        # What .dockerignore keeps out of the build context is not expected in the image.
        ignored = "__pycache__" in path.parts or path.suffix in (".pyc", ".pt", ".npz")
        if path.is_file() and not ignored:
            copy = baked / path.relative_to(ROOT / "models")
            if not copy.is_file() or copy.read_bytes() != path.read_bytes():
                differing.append(str(path.relative_to(ROOT)))
    return differing


def tree_bytes(root: Path) -> int:
    """Bytes of the regular files under `root` (each counted once)."""
    seen: set[tuple[int, int]] = set()
    total = 0
    for directory, _, files in os.walk(root):
        for name in files:
            info = os.lstat(os.path.join(directory, name))
            if (info.st_dev, info.st_ino) not in seen:
                seen.add((info.st_dev, info.st_ino))
                total += info.st_size
    return total


def check_image_contents(root: Path, checks: Checks) -> None:
    """The hardening check of a mounted image's root file system `root`."""
    with checks.check(
        "image holds no torch, pip, compiler or cache; /app holds the repo's models only"
    ) as note:
        found = scan_image(root)
        assert not any(found.values()), found
        app = sorted(p.name for p in (root / "app").iterdir())
        assert app == ["models"], f"/app holds {app}"
        differing = baked_model_differences(root / "app" / "models")
        assert not differing, f"/app/models differs from models/: {differing}"
        note["detail"] = f"{sum(1 for _ in root.rglob('*'))} files scanned"
