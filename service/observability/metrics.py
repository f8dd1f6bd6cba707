"""Prometheus metrics of one app: requests, latencies, pipeline stages, capacity, models.

Each app has its own registry (several apps in one test process never clash). Label
values come only from the server's own vocabulary (route templates, served model ids,
status codes, stage names, fixed reasons), never from request text, so the number of
series stays bounded whatever clients send.
"""

from __future__ import annotations

from collections.abc import Callable

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    ProcessCollector,
    disable_created_metrics,
)
from prometheus_client.exposition import CONTENT_TYPE_PLAIN_0_0_4, choose_encoder, generate_latest

from service.pipeline.types import SampleCounts, StageTimings

LATENCY_BUCKETS_S = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0)
RATIO_BUCKETS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99, 1.0)
REJECTION_REASONS = ("queue_full", "queue_timeout", "open_requests", "deadline")
SAMPLE_OUTCOMES = (
    "accepted",
    "rejected_tolerance",
    "rejected_joint_limits",
    "rejected_collision",
)


# The `*_created` timestamp series only double the exposition; Prometheus does not need them.
disable_created_metrics()


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        ProcessCollector(registry=self.registry)  # process_resident_memory_bytes and friends
        r = self.registry
        self.requests = Counter(
            "smm_http_requests",
            "HTTP requests answered, by route template, method, model id and status.",
            ["route", "method", "model", "status"],
            registry=r,
        )
        self.request_duration = Histogram(
            "smm_http_request_duration_seconds",
            "Time from a request's arrival to its response, by route template and model id.",
            ["route", "model"],
            buckets=LATENCY_BUCKETS_S,
            registry=r,
        )
        self.requests_in_flight = Gauge(
            "smm_http_requests_in_flight", "HTTP requests being received or answered.", registry=r
        )
        self.rejected = Counter(
            "smm_requests_rejected",
            "Requests refused for capacity (503) or past their deadline (504), by reason.",
            ["reason"],
            registry=r,
        )
        for reason in REJECTION_REASONS:
            self.rejected.labels(reason)
        self.pipeline_in_flight = Gauge(
            "smm_pipeline_in_flight", "POST /smm computations running.", registry=r
        )
        self.pipeline_waiting = Gauge(
            "smm_pipeline_waiting", "POST /smm requests waiting for a computation slot.", registry=r
        )
        self.queue_wait = Histogram(
            "smm_queue_wait_seconds",
            "Time a POST /smm request waited for a computation slot (admitted ones).",
            buckets=LATENCY_BUCKETS_S,
            registry=r,
        )
        self.stage_duration = Histogram(
            "smm_pipeline_stage_duration_seconds",
            "Time of each pipeline stage (and the total), by model id.",
            ["model", "stage"],
            buckets=LATENCY_BUCKETS_S,
            registry=r,
        )
        self.samples = Counter(
            "smm_samples",
            "Flow samples drawn, by model id and outcome (accepted or why rejected).",
            ["model", "outcome"],
            registry=r,
        )
        self.accepted_ratio = Histogram(
            "smm_accepted_sample_ratio",
            "Per request: accepted samples / samples drawn, by model id.",
            ["model"],
            buckets=RATIO_BUCKETS,
            registry=r,
        )
        self.model_ready = Gauge(
            "smm_model_ready",
            "1 for a model loaded and verified, 0 for one that failed verification at start-up.",
            ["model"],
            registry=r,
        )

    def track_capacity(self, in_flight: Callable[[], float], waiting: Callable[[], float]) -> None:
        """Read the pipeline gauges from the admission control at scrape time."""
        self.pipeline_in_flight.set_function(in_flight)
        self.pipeline_waiting.set_function(waiting)

    def observe_request(
        self, route: str, method: str, model: str, status: int, duration_s: float
    ) -> None:
        self.requests.labels(route, method, model, str(status)).inc()
        self.request_duration.labels(route, model).observe(duration_s)

    def observe_pipeline(self, model: str, timings: StageTimings, counts: SampleCounts) -> None:
        """Stage timings (labelled by `TIMED_SPANS`) and sample outcomes of one answered query."""
        for span, ms in timings.as_dict().items():
            self.stage_duration.labels(model, span).observe(ms / 1e3)
        outcomes = {outcome: getattr(counts, outcome) for outcome in SAMPLE_OUTCOMES}
        for outcome, count in outcomes.items():
            self.samples.labels(model, outcome).inc(count)
        if counts.sampled:
            self.accepted_ratio.labels(model).observe(counts.accepted / counts.sampled)

    def exposition(self, accept_header: str | None) -> tuple[bytes, str]:
        """The registry in the text format the scraper asks for (Accept), and its content type."""
        try:
            encoder, content_type = choose_encoder(accept_header or "")
            return encoder(self.registry), content_type
        except ValueError:  # an unparseable version in Accept: the classic format
            return generate_latest(self.registry), CONTENT_TYPE_PLAIN_0_0_4
