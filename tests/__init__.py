"""The test suite. Naming rule: a unit that exists on both sides (``model/X.py`` and
``rtl/X.py``, e.g. traversal, list, intersection, rtc, cache, rgs, fp) has
``test_X_rtl.py`` (the RTL against the golden model, bit for bit and cycle by cycle) and, where the
golden model is also tested alone (against Embree, an exact reference or an oracle),
``test_X_model.py``; every other test file is named after the module or command it tests
(``test_sim.py``: ``saarcor sim``; ``test_kdtree.py``: ``model/kdtree.py``)."""
