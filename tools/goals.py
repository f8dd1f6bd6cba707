"""The speed goals and the benchmark's configuration names, without the benchmark's imports.

`tools.benchmark` measures against these and `tools.docs` writes the goals' pages from them,
so both read one definition (this module imports nothing heavy).
"""

from __future__ import annotations

# The configurations a benchmark report times, by the names its JSON keys them under.
SERVICE, PAPER, RESTART = "service", "paper (100 Euler, 3 DLS)", "random-restart DLS"
FLOAT32 = "service, float32 network"
BASE = "service, base flow"  # the reflowed sampler's base flow at the steps it replaced
SSIK = "ssik charts (closed form)"  # full pose of the arms ssik covers, when it is installed
# The service asked as a client asks without options: self-collision checked (on a model
# with collision geometry), as over HTTP. SERVICE asks for the kinematic fibre, the
# question the paper's configuration, restart DLS, ssik and the exact truth answer.
DEFAULT_REQUEST = "service, default request"
CONFIGURATIONS = (SERVICE, DEFAULT_REQUEST, FLOAT32, BASE, PAPER, RESTART, SSIK)  # report order

GOAL_NUM_SAMPLES = 1000  # the N of the speed goals
# The speed goals at N = 1000, in process, median: (model, at most ms, at least x faster
# than the paper's configuration in the same run or None). The time is the default
# request's (`timed_run`), what a client waits for; the ratio to the paper's
# configuration and the truth compare the kinematic answers, the one question both
# answer. Each answer must also be no worse than the paper's configuration's in truth
# (the goals table's last column).
GOALS: tuple[tuple[str, float, float | None], ...] = (
    ("iiwa14-pose", 15.0, 20.0),
    ("panda-pose", 15.0, None),
    ("iiwa14-position", 40.0, None),
    ("panda-position", 40.0, None),
    ("planar3r-position", 5.0, None),
)
# Over HTTP (smm-serve on 127.0.0.1, one request at a time, the client's wall time),
# median at N = 1000: (model, at most ms).
HTTP_GOALS: tuple[tuple[str, float], ...] = (("iiwa14-pose", 20.0), ("panda-pose", 20.0))
# The batch's samples per target (None: the model's served default, what a client gets
# without asking, the goals' "adaptive default"), and the speed goal for it: at least
# this many times faster than its targets sent one after another.
BATCH_NUM_SAMPLES: int | None = None
BATCH_GOAL_X = 3.0


def bound_num_samples(entry: dict) -> int:
    """The N at which a report bounds a model's time goal not met: the goals read both
    N = 1000 and the model's served default (the "adaptive default"), and a goal is met at
    either, so what stands between the model and its goal is read at the fewer of the two,
    the one a client asking without options gets where it is fewer. N = 1000 for a report
    that did not measure the served default (older ones)."""
    n = entry.get("default_num_samples")
    if n is None or n >= GOAL_NUM_SAMPLES or str(n) not in entry.get("sizes", {}):
        return GOAL_NUM_SAMPLES
    return int(n)


def bound_label(entry: dict) -> str:
    """`bound_num_samples` as the reports write it: "N = 1000", or "N = 300, the served
    default"."""
    n = bound_num_samples(entry)
    return f"N = {n}" + ("" if n == GOAL_NUM_SAMPLES else ", the served default")


def timed_run(row: dict) -> dict:
    """The run of a benchmark row that the time goals read: the default request's, or the
    kinematic service's in a report from before it timed the default request."""
    return row.get(DEFAULT_REQUEST) or row[SERVICE]
