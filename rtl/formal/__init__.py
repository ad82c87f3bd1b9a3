"""Formal checks of RTL units: Amaranth harnesses with ``Assert``/``Assume``/``Cover``, proved with
Yosys SMT-BMC (``rtl.formal.smtbmc``). Verification only, not part of the chip."""
