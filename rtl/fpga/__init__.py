"""Open FPGA flow for the exported Verilog: :class:`PinWrapper` and ``python -m rtl.fpga``
(see ``rtl/fpga/flow.py`` and ``docs/fpga.md``)."""
from .wrapper import PinWrapper, overhead, port_bits

__all__ = ["PinWrapper", "overhead", "port_bits"]
