"""Formal checks of RTL units: Amaranth harnesses with ``Assert``/``Assume``/``Cover``, proved with
Yosys SMT-BMC (``saarcor.flows.formal.smtbmc``). Verification only, not part of the chip."""
