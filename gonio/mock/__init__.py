"""Mock goniophotometer: the motion controller and photometer head on real protocol endpoints.

``gonio mock`` (:mod:`gonio.mock.cli`) and :class:`MockInstrument` (in-process) impersonate both
parts of the instrument described in docs/instrument.md: a Modbus server (TCP on loopback or RTU over
a pseudo-terminal pair) and the ASCII photometer head (on a pseudo-terminal or a loopback
socket), sharing one motion state so the counts follow the current geometry. The wire formats
come from :mod:`gonio.instrument` (register map, command table, framing), the same tables the
driver uses.

Modules: :mod:`~gonio.mock.samples` (virtual samples, the truth), :mod:`~gonio.mock.physics`
(forward counts model and reproducible noise), :mod:`~gonio.mock.motion` (axes and Modbus
front end), :mod:`~gonio.mock.head` (command interpreter), :mod:`~gonio.mock.faults` (fault
injection), :mod:`~gonio.mock.servers` (transports), :mod:`~gonio.mock.instrument`
(:class:`MockInstrument`), :mod:`~gonio.mock.cli` (``gonio mock``).
"""

from gonio.mock.faults import FAULT_KINDS, FaultSpecError, parse_faults
from gonio.mock.instrument import MockConfigError, MockInstrument
from gonio.mock.samples import WHITE_REFERENCE_BETA, SampleError, make_sample, reference_beta

__all__ = ["MockInstrument", "MockConfigError", "FAULT_KINDS", "FaultSpecError", "parse_faults",
           "WHITE_REFERENCE_BETA", "SampleError", "make_sample", "reference_beta"]
