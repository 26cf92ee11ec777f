"""Hardware-facing data sources: the accelerometer DAQ over serial and CAN vehicle data.

Sources are chosen by URL, as python-can chooses interfaces (see :mod:`drivers.base`)::

    from drivers import open_source
    src = open_source("serial:///dev/ttyUSB0?baud=921600")

=====================================  ===============================================
``serial://PORT?baud=921600``           fielddiag DAQ, binary protocol (PROTOCOL.md)
``serial+ascii://PORT?baud=115200``     text streamer, ``t_us,ch0,ch1,...`` per line
``can://INTERFACE/CHANNEL?dbc=FILE``    any python-can interface, signals from a DBC
``canlog://FILE?dbc=FILE``              a CAN log python-can reads (.asc .blf .log .trc ...)
=====================================  ===============================================
"""

from drivers.base import (
    SOURCE_SCHEMES,
    Block,
    ChannelSpec,
    ClockSync,
    SessionClock,
    SignalSpec,
    Source,
    SourceURL,
    open_source,
    parse_source_url,
    register_source,
    source_class,
)

__all__ = [
    "SOURCE_SCHEMES",
    "Block",
    "ChannelSpec",
    "ClockSync",
    "SessionClock",
    "SignalSpec",
    "Source",
    "SourceURL",
    "open_source",
    "parse_source_url",
    "register_source",
    "source_class",
]
