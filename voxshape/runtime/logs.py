"""Structured logs: one line per event, `key=value` fields after the message (or JSON lines).

    log.info("published", extra=fields(topic="obs", step=12))

VOXSHAPE_LOG_LEVEL (default INFO) and VOXSHAPE_LOG_FORMAT (text|json) choose the output.
Logs go to stderr, so a service's stdout stays free for data (e.g. `voxshape listen --json`).
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from typing import Any

import zenoh

_FIELDS = "voxshape_fields"


def fields(**values: Any) -> dict[str, dict[str, Any]]:
    """`extra=` argument carrying structured fields of a log line."""
    return {_FIELDS: values}


def worth_logging(count: int) -> bool:
    """For a repeated event counted `count` times: log the first ten, then the 100th, 1000th,
    10,000th and every 100,000th, so a flood is visible without drowning the log."""
    return count <= 10 or count in (100, 1000, 10_000) or count % 100_000 == 0


class _TextFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        stamp = time.strftime("%H:%M:%S", time.localtime(record.created))
        line = f"{stamp}.{int(record.msecs):03d} {record.levelname:<5} {record.name}: "
        line += record.getMessage()
        for key, value in getattr(record, _FIELDS, {}).items():
            text = str(value)
            line += f" {key}={json.dumps(text) if (' ' in text or not text) else text}"
        if record.exc_info:
            line += "\n" + self.formatException(record.exc_info)
        return line


class _JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        entry = {
            "time": record.created,
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
            **getattr(record, _FIELDS, {}),
        }
        if record.exc_info:
            entry["exception"] = self.formatException(record.exc_info)
        return json.dumps(entry, default=str)


def configure_logging(level: str | None = None, fmt: str | None = None) -> None:
    level = (level or os.environ.get("VOXSHAPE_LOG_LEVEL") or "INFO").upper()
    fmt = (fmt or os.environ.get("VOXSHAPE_LOG_FORMAT") or "text").lower()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_JsonFormatter() if fmt == "json" else _TextFormatter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level if level in logging.getLevelNamesMapping() else "INFO")
    # zenoh's own errors (a transport closed for congestion, a lost link) are otherwise
    # invisible: they go to stderr in zenoh's format; RUST_LOG chooses more. A refused login
    # is reported by open_zenoh in one line, not by zenoh's retries.
    zenoh.init_log_from_env_or("error,zenoh_transport::unicast::establishment::open=off")
