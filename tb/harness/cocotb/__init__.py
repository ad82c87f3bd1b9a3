"""cocotb testbenches of the exported Verilog (``tb.harness.tops``) under Icarus and Verilator.

``runner.py`` exports and builds a top and runs a bench; ``streams.py`` holds the stream agents
every bench shares (they run inside the simulator); one module per unit as in ``tb/``.
``docs/cocotb.md`` says how to run them and what they cost.
"""
