"""The small runtime every service stands on: bus configuration, the Node event loop, logs,
rate limits and the bus's audio format (16 kHz mono PCM).

No service logic lives here.
"""

from voxshape.runtime.config import (
    BusConfig,
    ConfigError,
    add_bus_arguments,
    bus_config,
    free_loopback_port,
)
from voxshape.runtime.logs import configure_logging, fields, worth_logging
from voxshape.runtime.node import BusError, Event, Input, Node, Output, Presence, Tick

__all__ = [
    "BusConfig",
    "BusError",
    "ConfigError",
    "Event",
    "Input",
    "Node",
    "Output",
    "Presence",
    "Tick",
    "add_bus_arguments",
    "bus_config",
    "configure_logging",
    "fields",
    "free_loopback_port",
    "worth_logging",
]
