"""Prometheus metrics of one app instance, in their own registry."""

from __future__ import annotations

import os

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    generate_latest,
)

__all__ = ["CONTENT_TYPE_LATEST", "Metrics"]

_LATENCY_BUCKETS_S = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0)


class Metrics:
    """Counters, gauges and histograms of the service.

    With ``--workers`` > 1 each process has its own registry unless ``PROMETHEUS_MULTIPROC_DIR``
    is set, in which case `render` aggregates every worker's files (prometheus-client's
    multiprocess mode).
    """

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        r = self.registry
        self.requests = Counter("lishield_http_requests_total", "HTTP requests by route and "
                                "outcome (ok or the error code).", ["route", "method", "outcome"],
                                registry=r)
        self.latency = Histogram("lishield_http_request_duration_seconds", "Request wall time.",
                                 ["route"], buckets=_LATENCY_BUCKETS_S, registry=r)
        self.bytes_received = Counter("lishield_http_received_bytes_total",
                                      "Request body bytes read.", ["route"], registry=r)
        self.verdicts = Counter("lishield_verdicts_total", "Screening verdicts by policy "
                                "('none' for clean images).", ["policy"], registry=r)
        self.in_flight = Gauge("lishield_http_requests_in_flight", "Requests being served.",
                               registry=r, multiprocess_mode="livesum")
        self.detections_in_flight = Gauge("lishield_detections_in_flight", "Detections admitted "
                                          "(running or queued).", registry=r,
                                          multiprocess_mode="livesum")
        self.rejected_overload = Counter("lishield_rejected_overload_total", "Requests refused "
                                         "with 503 because the detection queue was full.",
                                         registry=r)
        self.timeouts = Counter("lishield_detect_timeouts_total", "Detections that exceeded "
                                "DETECT_TIMEOUT_S.", registry=r)

    def render(self) -> bytes:
        """Text exposition format of every metric."""
        if os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
            from prometheus_client import multiprocess

            registry = CollectorRegistry()
            multiprocess.MultiProcessCollector(registry)
            return generate_latest(registry)
        return generate_latest(self.registry)
