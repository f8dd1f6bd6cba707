"""`python -m tools.container_test`: the command line, and the steps in order (the base
image, the build, the run as built, the read-only run, the clean-up, the report)."""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import tools.container_test
from tools.container_test import FIGURES, ROOT
from tools.container_test.buildah import (
    BASE_IMAGE,
    DEBIAN_SUITE,
    HOST_CA_BUNDLE,
    IMAGE,
    STANDIN_PACKAGES,
    Buildah,
    buildah_version,
    image_size_bytes,
    import_standin,
    registry_reachable,
    remove_tree,
    standin_tarball,
)
from tools.container_test.outcomes import Checks
from tools.container_test.read_only import run_read_only_checks
from tools.container_test.report import finish
from tools.container_test.server_checks import run_container_checks


def parse_arguments(argv: list[str] | None) -> argparse.Namespace:
    doc = tools.container_test.__doc__ or ""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument(
        "--base",
        choices=("auto", "registry", "standin"),
        default="auto",
        help="the python:3.11-slim to build on: pulled (registry), the debootstrap stand-in, "
        "or the first that works (auto, the default)",
    )
    parser.add_argument(
        "--figures", type=Path, default=FIGURES, help="where to write the measured figures"
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_arguments(argv)
    if shutil.which("buildah") is None:
        print("container test: buildah is not installed (apt-get install buildah)")
        return 2
    if os.geteuid() != 0:
        print("container test: needs root (buildah with the vfs driver and chroot isolation)")
        return 2

    checks = Checks()
    figures: dict[str, Any] = {"buildah": buildah_version()}
    timings: dict[str, float] = {}
    started = time.monotonic()
    store = Path(tempfile.mkdtemp(prefix="smm-buildah-"))
    buildah = Buildah(store)
    try:
        prepare_base(buildah, args.base, figures, timings)
        build_image(buildah, store, checks, timings)
        if not checks.failed:
            figures["image_bytes"] = image_size_bytes(buildah, IMAGE)
            figures["base_bytes"] = image_size_bytes(buildah, BASE_IMAGE)
            figures["added_bytes"] = figures["image_bytes"] - figures["base_bytes"]
            step = time.monotonic()
            figures.update(run_container_checks(buildah, store, checks))
            timings["run_and_checks_s"] = round(time.monotonic() - step, 1)
            step = time.monotonic()
            figures.update(run_read_only_checks(buildah, store, checks))
            timings["read_only_run_s"] = round(time.monotonic() - step, 1)
    except Exception as error:  # a step that is not a check: the test fails, cleanly
        checks.results.append(("container test ran to the end", False, str(error)))
        print(f"FAIL {error}", flush=True)
    finally:
        step = time.monotonic()
        buildah.status("rm", "--all")
        buildah.status("rmi", "--all", "--force", timeout_s=300)
        remove_tree(store)
        timings["cleanup_s"] = round(time.monotonic() - step, 1)
    return finish(checks, figures, timings, started, args.figures)


def prepare_base(
    buildah: Buildah, base: str, figures: dict[str, Any], timings: dict[str, float]
) -> None:
    """python:3.11-slim in the private store: pulled, or the debootstrap stand-in."""
    step = time.monotonic()
    use_registry = base == "registry" or (base == "auto" and registry_reachable())
    if use_registry:
        buildah("pull", BASE_IMAGE, timeout_s=600)
        figures["base"] = f"{BASE_IMAGE} (pulled)"
    else:
        tarball, cached = standin_tarball()
        timings["debootstrap_s" if not cached else "standin_cached_s"] = round(
            time.monotonic() - step, 1
        )
        import_standin(buildah, tarball)
        figures["base"] = (
            f"stand-in for python:3.11-slim: debootstrap --variant=minbase {DEBIAN_SUITE} "
            f"+ {', '.join(STANDIN_PACKAGES)} (no registry reachable)"
        )
    timings["base_s"] = round(time.monotonic() - step, 1)
    print(f"base: {figures['base']} ({timings['base_s']} s)", flush=True)


def build_image(buildah: Buildah, store: Path, checks: Checks, timings: dict[str, float]) -> None:
    """The check that the Dockerfile builds, tagged IMAGE."""
    step = time.monotonic()
    build_args = ["bud", "--isolation", "chroot", "--pull=never", "--format", "docker"]
    if HOST_CA_BUNDLE.is_file():  # RUN steps reach PyPI through the host's trust store
        build_args += ["--volume", f"{HOST_CA_BUNDLE}:{HOST_CA_BUNDLE}:ro"]
    build_log = store / "build.log"
    with checks.check("Dockerfile builds") as note:
        buildah(
            *build_args,
            "--tag",
            IMAGE,
            "--file",
            str(ROOT / "Dockerfile"),
            str(ROOT),
            timeout_s=900,
            log=build_log,
        )
        note["detail"] = f"{time.monotonic() - step:.0f} s"
    timings["build_s"] = round(time.monotonic() - step, 1)


if __name__ == "__main__":
    sys.exit(main())
