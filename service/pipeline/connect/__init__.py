"""Stage 5, connect: the accepted samples grouped into the fibre's components, decided on
the fibre itself (stage.py says how). r = 1: the curves are traced whole (trace/) and
cut by the limits (curves.py, splicing.py); r > 1: a roadmap (roadmap.py) whose edges the
projected local planner (local_planner.py) and the steer (steering.py) check, with nodes
on the chain's coaxial sets (coaxial.py). settings.py makes every walker's settings from
the model's `ConnectivitySpec`.

Code outside this package imports only the names below.
"""

from service.pipeline.connect.coaxial import find_coaxial_sets
from service.pipeline.connect.curves import (
    Extension,
    TracedCurves,
    extend_curves,
    on_curves,
    trace_curves,
)
from service.pipeline.connect.local_planner import PlannerSettings, edges_on_fibre, walk_on_fibre
from service.pipeline.connect.roadmap import (
    RoadmapComponents,
    RoadmapSettings,
    roadmap_components,
)
from service.pipeline.connect.settings import (
    planner_settings,
    roadmap_settings,
    splice_settings,
    trace_settings,
)
from service.pipeline.connect.splicing import SpliceSettings
from service.pipeline.connect.stage import Connection, connect
from service.pipeline.connect.steering import SteerSettings, steer
from service.pipeline.connect.trace import TraceSettings, trace_fibre

__all__ = [
    "Connection",
    "Extension",
    "PlannerSettings",
    "RoadmapComponents",
    "RoadmapSettings",
    "SpliceSettings",
    "SteerSettings",
    "TraceSettings",
    "TracedCurves",
    "connect",
    "edges_on_fibre",
    "extend_curves",
    "find_coaxial_sets",
    "on_curves",
    "planner_settings",
    "roadmap_components",
    "roadmap_settings",
    "splice_settings",
    "steer",
    "trace_curves",
    "trace_fibre",
    "trace_settings",
    "walk_on_fibre",
]
