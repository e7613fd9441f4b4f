"""The instrument: its two protocols as tables, the transports, and the two devices built on them.

One concept per module; dependencies point down (devices know nothing of acquisition):

``gonio.instrument.modbus_map``
    the motion controller's register map (one row per register), bit fields, codes, axes and
    word packing;
``gonio.instrument.head_commands``
    the photometer head's command table, constants, typed replies and errors;
``gonio.instrument.head_framing``
    the head's line framing (``*HH`` checksum) and the response parser;
``gonio.instrument.links``
    serial settings of both buses (Modbus RTU, the head's RS-232);
``gonio.instrument.transport``
    the typed transport protocols and their serial / Modbus implementations;
``gonio.instrument.retry``
    the one :class:`RetryPolicy` both devices use;
``gonio.instrument.registers``
    descriptors for coils, holding and input registers over the register map;
``gonio.instrument.motion``, ``gonio.instrument.head``
    the two devices, declared from the tables;
``gonio.instrument.errors``
    what the devices raise;
``gonio.instrument.docs``
    the protocol document's tables, generated from the tables (``docs/instrument.md``).

The mock instrument (:mod:`gonio.mock`) reads the same tables, so driver and mock cannot drift
apart. This package re-exports the names of the tables, the framing and the devices.
"""

from gonio.instrument import head_commands, head_framing, links, modbus_map
from gonio.instrument.errors import AxisFaultError, DeviceError, InstrumentTaken
from gonio.instrument.head import Measurement, PhotometerHead, Setting
from gonio.instrument.head_commands import *  # noqa: F401,F403 - the table's names, re-exported
from gonio.instrument.head_framing import *  # noqa: F401,F403
from gonio.instrument.links import *  # noqa: F401,F403
from gonio.instrument.modbus_map import *  # noqa: F401,F403
from gonio.instrument.motion import RECOVERABLE_FAULTS, AxisState, MotionController
from gonio.instrument.retry import RETRY_KINDS, Failure, RetryPolicy

__all__ = [
    *modbus_map.__all__, *links.__all__, *head_commands.__all__, *head_framing.__all__,
    "DeviceError", "AxisFaultError", "InstrumentTaken", "RetryPolicy", "Failure", "RETRY_KINDS",
    "PhotometerHead", "Setting", "Measurement", "MotionController", "AxisState", "RECOVERABLE_FAULTS",
]
