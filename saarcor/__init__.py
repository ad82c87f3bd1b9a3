"""The ``saarcor`` command line: one entry point for the golden model, the RTL and the benches
(see :mod:`saarcor.cli`)."""
