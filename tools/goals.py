"""The speed goals and the benchmark's configuration names, without the benchmark's imports.

`tools.benchmark` measures against these and `tools.docs` writes the goals' pages from them,
so both read one definition (this module imports nothing heavy).
"""

from __future__ import annotations

# The configurations a benchmark report times, by the names its JSON keys them under.
SERVICE, PAPER, RESTART = "service", "paper (100 Euler, 3 DLS)", "random-restart DLS"
FLOAT32 = "service, float32 network"
BASE = "service, base flow"  # the reflowed sampler's base flow at the steps it replaced
CONFIGURATIONS = (SERVICE, FLOAT32, BASE, PAPER, RESTART)  # in the report's order

GOAL_NUM_SAMPLES = 1000  # the N of the speed goals
# The speed goals at N = 1000, in process, median: (model, at most ms, at least x faster
# than the paper's configuration in the same run or None). Each answer must also be no
# worse than the paper's configuration's in truth (the goals table's last column).
GOALS: tuple[tuple[str, float, float | None], ...] = (
    ("iiwa14-pose", 60.0, 20.0),
    ("iiwa14-position", 60.0, None),
    ("planar3r-position", 15.0, None),
)
# The batch's samples per target, and the speed goal for it: at least this many times
# faster than its targets sent one after another.
BATCH_NUM_SAMPLES = 1000
BATCH_GOAL_X = 3.0
