"""The RGS, the ray generation and shading unit (the paper's Figure 2): a master and one slave
per RTC, in hardware. Each file reads beside its golden model, ``model/rgs/`` (same names).

* ``master.py``: the RGS master, hands out the frame's packets (tiles) to the slaves (dynamic
  load balancing). No golden model (``model/rgs/__init__.py`` says why).
* ``slave.py``: the RGS slave's control around the datapaths: tiles in, the RTC packet slots,
  the ray store, every result to the host, the light loop, the pending buffers of secondary
  packets and their sender. Golden model: ``model/rgs/slave.py`` (what its shading path
  computes from a set of hits); the ray tree and packing are ``model/shading.py``.
* ``eye.py``: the slave's eye rays from the camera registers and ray setup (``EyeRays``,
  ``RaySetup`` and their bare datapaths).
* ``secondary.py``: a hit's secondary rays (``SecondaryPipe``), its shadow rays toward the
  lights and its colour (``LightPipe``), both on one pool of FP units (``ShadePool``), or with
  the eye rays and the ray setup too (``SlavePool``).
* ``texture.py``: the slave's texture unit (``Texture``).
* ``common.py``: the bare fixed-latency datapath the ``*Pipe`` s are built on.

The public names of every file are re-exported here (``from rtl.rgs import Slave``).
"""
from .eye import (COORD_BITS, PIXEL_BITS, EyeRay, EyeRayPipe, EyeRays, EyeRequest, RaySetup,
                  RaySetupIn, RaySetupPipe, div_const, div_const_params, sample_converter)
from .master import RGSMaster
from .secondary import LightPipe, SecondaryPipe, ShadePool, SlavePool, to_fixed
from .slave import (DEPTH_BITS, POOL_COUNTERS, RAY_COUNTERS, SUB_BITS, Slave, SlaveResult,
                    pool_entries, shade_cache_geometry, slave_buffers, tex_cache_geometry)
from .texture import (TEX_INDEX_BITS, TEX_SIZE_BITS, TexCoordPipe, TexFilterPipe, TexIn, TexOut,
                      Texture, tex_pos, wrap_coord)

__all__ = ["COORD_BITS", "PIXEL_BITS", "EyeRay", "EyeRayPipe", "EyeRays", "EyeRequest",
           "RaySetup", "RaySetupIn", "RaySetupPipe", "div_const", "div_const_params",
           "sample_converter", "RGSMaster", "LightPipe", "SecondaryPipe", "ShadePool", "SlavePool",
           "to_fixed",
           "DEPTH_BITS", "POOL_COUNTERS", "RAY_COUNTERS", "SUB_BITS", "pool_entries", "Slave",
           "SlaveResult", "shade_cache_geometry",
           "slave_buffers", "tex_cache_geometry", "TEX_INDEX_BITS", "TEX_SIZE_BITS",
           "TexCoordPipe", "TexFilterPipe", "TexIn", "TexOut", "Texture", "tex_pos",
           "wrap_coord"]
