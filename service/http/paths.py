"""The served paths, named once: the middlewares, the metrics and the tests take them from here."""

from __future__ import annotations

# Probes and metrics: open without an API key and exempt from the open-request limit, so
# an operator still sees a saturated or locked-down server.
OPEN_PATHS = frozenset({"/healthz", "/readyz", "/metrics"})
# Every documented path: metric labels for requests refused before routing (a test checks
# the set against the OpenAPI document).
API_PATHS = frozenset({"/smm", "/smm/batch", "/smm/self-motion", "/robots"}) | OPEN_PATHS
# (method, path) of every route that reads a JSON body: the body limit and the content
# type apply to these (a test checks the set against the OpenAPI document).
JSON_BODY_ROUTES = frozenset(
    {("POST", "/smm"), ("POST", "/smm/batch"), ("POST", "/smm/self-motion")}
)
