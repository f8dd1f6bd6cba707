"""Stage 5 for r = 1: every curve of the fibre that a corrected sample lies on, traced
whole and cut by the joint limits (run.py says how). The phases, in order: seeds.py,
walk.py (fronts walk and meet), strands.py (chained into curves), cut.py (refined and
cut at the limits), densify.py (to the path spacing, every point on the fibre)."""

from service.pipeline.connect.trace.points import Trace, TracedPiece, TraceSettings
from service.pipeline.connect.trace.run import trace_fibre
from service.pipeline.connect.trace.strands import closest_strands_rad
from service.pipeline.connect.trace.walk import MEET_FACTOR

__all__ = [
    "MEET_FACTOR",
    "Trace",
    "TraceSettings",
    "TracedPiece",
    "closest_strands_rad",
    "trace_fibre",
]
