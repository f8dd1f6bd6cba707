"""The compiled kernels under AddressSanitizer: a write past a buffer stops the run there.

    python -m tools.sanitize                                # tests/service/pipeline
    python -m tools.sanitize tests/service/pipeline/connect -q -k chain

The kernels (service/pipeline/native.c, service/models/int8_mlp.c) trust the sizes of the
buffers their Python wrappers give them, and a write past one corrupts the heap silently
until something frees the block beside it, far from the kernel, or never. Built with
`-fsanitize=address`, every read or write outside a buffer aborts at once with the
kernel's file and line. This builds both with setup.py (its sources and flags) plus
the sanitizer into a temporary directory, and runs pytest on the given arguments with
libasan preloaded (and libstdc++, whose exceptions the sanitizer intercepts for the C++
extensions the tests load); this module, given to pytest as a plugin (`-p tools.sanitize`), puts the
sanitized builds in place of the installed ones before anything imports them.

Leaks are checked when each process exits (LeakSanitizer): memory allocated and no longer
reachable from anything. CPython leaves some of its own allocations so at the end of every
process, so a leak counts only where its allocation's stack passes through a kernel's
source (`KERNEL_SOURCES`): a kernel that drops a block it allocated, or a wrapper that
keeps a reference too many to an array it made. The others are counted and left out.

Each report (the access, the kernel's stack, the buffer's allocation; or the kernels'
leaks) is printed after pytest ends, since pytest captures what the process writes; the
exit status is pytest's, or 1 where an error or a kernel's leak was reported.

Needs the C compiler the install uses and its AddressSanitizer runtime (with GCC:
libasan, part of its standard install).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import sysconfig
import tempfile
from importlib.machinery import ExtensionFileLoader
from importlib.util import module_from_spec, spec_from_loader
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SANITIZE = "-fsanitize=address -fno-omit-frame-pointer -g"
# Where the plugin finds the sanitized builds (set by `main` for the pytest it runs).
BUILDS_ENV = "SMM_SANITIZED_KERNELS"
DEFAULT_TESTS = ("tests/service/pipeline", "tests/service/models")
# The kernels' sources, every C file under service/ (what setup.py builds, and the header
# they share): a leak whose allocation passes through one is theirs.
KERNEL_SOURCES = tuple(sorted(str(p.relative_to(REPO)) for p in (REPO / "service").rglob("*.[ch]")))
LEAK_REPORT = "ERROR: LeakSanitizer: detected memory leaks"


def compiler() -> str:
    """The C compiler CPython was built with (what setuptools uses), `cc` without one."""
    return str(sysconfig.get_config_var("CC") or "cc").split()[0]


def runtime_library(cc: str, name: str) -> Path:
    """A runtime library the compiler ships (`libasan.so`, `libstdc++.so`)."""
    found = subprocess.run(
        [cc, f"-print-file-name={name}"], capture_output=True, text=True, check=True
    ).stdout.strip()
    path = Path(found)
    if not path.is_absolute() or not path.exists():
        raise SystemExit(f"{cc} has no {name}: install its AddressSanitizer runtime")
    return path.resolve()


def build(out_dir: Path) -> None:
    """setup.py's extensions, its sources and flags, built with the sanitizer into
    `out_dir` (under their packages' paths)."""
    env = {**os.environ, "CFLAGS": SANITIZE, "LDFLAGS": "-fsanitize=address"}
    command = [
        sys.executable, "setup.py", "-q", "build_ext",
        "--build-lib", str(out_dir / "lib"), "--build-temp", str(out_dir / "temp"),
    ]  # fmt: skip
    subprocess.run(command, cwd=REPO, env=env, check=True, stdout=subprocess.DEVNULL)


def install_sanitized(builds_dir: Path) -> None:
    """Load every sanitized build under its module's name (sys.modules), so the packages'
    `from service.pipeline import _native` takes it."""
    lib = builds_dir / "lib"
    suffix = sysconfig.get_config_var("EXT_SUFFIX")
    for path in sorted(lib.rglob(f"*{suffix}")):
        module = ".".join(path.relative_to(lib).parts)[: -len(suffix)]
        loader = ExtensionFileLoader(module, str(path))
        spec = spec_from_loader(module, loader)
        assert spec is not None
        extension = module_from_spec(spec)
        loader.exec_module(extension)
        sys.modules[module] = extension


def arguments_for_pytest(argv: list[str]) -> list[str]:
    """`argv` as pytest takes it, in its order, and DEFAULT_TESTS after it when none of its
    arguments names a test path (a file or directory here, with or without a ::node):
    `-q` runs the default tests quietly, `-p no:randomly tests/x` passes through as is."""
    names_a_path = any(
        not arg.startswith("-") and (REPO / arg.split("::")[0]).exists() for arg in argv
    )
    return list(argv) if names_a_path else [*argv, *DEFAULT_TESTS]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "-h" in argv or "--help" in argv:
        print(f"{__doc__}\nDefault tests: {' '.join(DEFAULT_TESTS)}; other arguments go to pytest.")
        return 0
    cc = compiler()
    preload = [runtime_library(cc, "libasan.so"), runtime_library(cc, "libstdc++.so")]
    with tempfile.TemporaryDirectory(prefix="smm-asan-") as tmp:
        build(Path(tmp))
        log = Path(tmp) / "asan"  # the reports, one file a process (pytest captures fd 2)
        env = {
            **os.environ,
            BUILDS_ENV: tmp,
            "LD_PRELOAD": " ".join(str(p) for p in preload),
            # new_delete_type_mismatch=0: eaik (the tests' analytic IK, C++) frees its
            # Robot through a type of another size, which the sanitizer reports and aborts
            # on; the project's kernels are C, with no new or delete for it to concern.
            # exitcode=0: a leak found at exit is written to the report and leaves the
            # process's exit status alone (pytest's); an error still aborts the process.
            "ASAN_OPTIONS": (
                "detect_leaks=1:exitcode=0:new_delete_type_mismatch=0:abort_on_error=1:"
                f"log_path={log}"
            ),
        }
        command = [sys.executable, "-m", "pytest", "-p", "tools.sanitize", "-p", "no:cacheprovider"]
        command += arguments_for_pytest(argv)
        status = subprocess.run(command, cwd=REPO, env=env).returncode
        found = False
        others = 0
        for report in sorted(Path(tmp).glob("asan.*")):
            text = report.read_text()
            if not is_leak_report(text):  # an error: the process stopped there
                sys.stderr.write(text)
                found = True
                continue
            theirs = kernel_leaks(text)
            others += len(leak_blocks(text)) - len(theirs)
            if theirs:
                sys.stderr.write(f"{LEAK_REPORT} by the kernels ({report.name}):\n\n")
                sys.stderr.write("\n".join(theirs))
                found = True
        sys.stderr.write(
            f"tools.sanitize: {others} leaks at exit allocated outside the kernels, left out\n"
        )
        return status or (1 if found else 0)


def is_leak_report(text: str) -> bool:
    """A report of leaks at exit only, no error (an error aborts before the leak check)."""
    return LEAK_REPORT in text and "ERROR: AddressSanitizer" not in text


def leak_blocks(text: str) -> list[str]:
    """A leak report's leaks, each its header line and allocation stack."""
    blocks = re.split(r"\n(?=(?:Direct|Indirect) leak of )", text)
    return [
        block.split("\n\n")[0]
        for block in blocks
        if re.match(r"(?:Direct|Indirect) leak of ", block)
    ]


def kernel_leaks(text: str, sources: tuple[str, ...] = KERNEL_SOURCES) -> list[str]:
    """The leaks of a report whose allocation stack has a frame in one of `sources`
    (a frame names its file by the path it was compiled from, `service/pipeline/native.c:LINE`,
    or by an absolute one ending so)."""
    paths = "|".join(re.escape(source) for source in sources)
    frames = re.compile(rf"(?:\s|/)(?:{paths}):\d")
    return [block for block in leak_blocks(text) if frames.search(block)]


# Imported by pytest as a plugin (`-p tools.sanitize`, before the conftest files and the
# tests import the kernels): the sanitized builds take the extensions' place.
if os.environ.get(BUILDS_ENV):
    install_sanitized(Path(os.environ[BUILDS_ENV]))

if __name__ == "__main__":
    raise SystemExit(main())
