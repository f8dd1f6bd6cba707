"""Structured logs and Prometheus metrics: what an operator sees of the service."""
