"""Open FPGA flow for the exported Verilog: :class:`PinWrapper` and ``saarcor fpga``
(see ``saarcor/flows/fpga/flow.py`` and ``docs/fpga.md``)."""
from saarcor.flows.fpga.wrapper import PinWrapper, overhead, port_bits

__all__ = ["PinWrapper", "overhead", "port_bits"]
