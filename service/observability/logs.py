"""Structured logs: one JSON object per line on stderr, each with the current request id.

The request id lives in a context variable set per request by `service.http.request_context`;
it follows the request into the worker thread that runs the pipeline, so every line a
request causes carries its id.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from contextvars import ContextVar
from typing import Any, Literal

LogLevel = Literal["critical", "error", "warning", "info", "debug", "trace"]

REQUEST_ID: ContextVar[str] = ContextVar("request_id", default="-")
LOGGER_NAME = "smm"


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        entry: dict[str, Any] = {
            "time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
            + f".{int(record.msecs):03d}Z",
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
            "request_id": REQUEST_ID.get(),
        }
        entry.update(getattr(record, "fields", {}))
        if record.exc_info:
            entry["exception"] = self.formatException(record.exc_info)
        return json.dumps(entry, default=str)


def configure_logging(level: LogLevel) -> logging.Logger:
    """The service's logger, writing JSON lines to stderr (idempotent)."""
    logger = logging.getLogger(LOGGER_NAME)
    if not any(isinstance(h.formatter, JsonFormatter) for h in logger.handlers):
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(JsonFormatter())
        logger.addHandler(handler)
    logger.setLevel(logging.DEBUG if level == "trace" else level.upper())
    logger.propagate = False
    return logger


def log_event(logger: logging.Logger, level: int, message: str, **fields: Any) -> None:
    """Log `message` with `fields` as top-level JSON keys."""
    logger.log(level, message, extra={"fields": fields})
