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


def http_bound(entry: dict, most_ms: float) -> str | None:
    """What bounds an HTTP time goal not met, or None where it is met (at N = 1000 or at the
    served default: either meets it) or the report has no HTTP row at the bound's N.

    Read at `bound_num_samples`: the client's wall time is the server's own total (the
    pipeline, the in-process default request's work) and what lies outside it (the route's
    validation and JSON encoding, the exchange, the client's parsing into the typed
    answer); with the outside as it is, the goal needs the server's total within
    `most_ms` less the outside."""
    sizes = entry.get("sizes", {})
    over_http = [
        sizes[str(n)]["http"]["median_ms"]
        for n in (GOAL_NUM_SAMPLES, entry.get("default_num_samples"))
        if n is not None and "http" in sizes.get(str(n), {})
    ]
    if not over_http or min(over_http) <= most_ms:
        return None
    row = sizes.get(str(bound_num_samples(entry)), {})
    if "http" not in row:
        return None
    http = row["http"]
    took_ms, server_ms = http["median_ms"], http["server_median_ms"]
    outside_ms = took_ms - server_ms
    in_process_ms = timed_run(row)["median_ms"]
    need_ms = most_ms - outside_ms
    return (
        f"over HTTP at {bound_label(entry)}: {took_ms:.1f} ms against the goal's "
        f"{most_ms:g} ms ({took_ms / most_ms:.2f}x): the server's own total {server_ms:.1f} "
        f"ms (the default request in process {in_process_ms:.1f} ms), the other "
        f"{outside_ms:.1f} ms outside the pipeline (the route's validation and JSON "
        "encoding, the exchange, the client's parsing into the typed answer). With that as "
        f"it is, the goal needs the server's total within {max(need_ms, 0.0):.1f} ms, "
        f"{server_ms - need_ms:.1f} ms less than here."
    )
