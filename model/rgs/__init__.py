"""The RGS slave's arithmetic (golden model), as compiled numba kernels, bit for bit with the
hardware. Each file reads beside its RTL, ``rtl/rgs/`` (same names).

* ``eye.py``: eye rays and ray setup (``rtl/rgs/eye.py``); run by ``model/raygen.py``.
* ``secondary.py``: a hit's secondary rays, its shadow rays toward the lights and its colour
  contributions (``rtl/rgs/secondary.py``); run by ``model/shading.py``.
* ``refract.py``: a hit's refracted ray (``rtl/rgs/secondary.py``: ``SecondaryPipe``'s
  ``refract`` option); run by ``model/shading.py`` (``Shader.refraction_rays``).
* ``texture.py``: the texture unit (``rtl/rgs/texture.py``).
* ``slave.py``: what the slave computes from a set of hits, in one pass (``shade_batch``, the
  render's; ``rtl/rgs/slave.py``'s shading path). The slave's control (the ray tree, the
  secondary packets per source packet) is ``model/shading.py`` and ``model/render.py``.
* ``common.py``: the drivers' task size and the kernels' constants.

No ``master.py``: the RGS master (``rtl/rgs/master.py``) computes nothing a result depends on;
the model makes the packets in its order (``eye.eye_packets``) and ``model/timing.py`` models
its timing.

The public names of every file are re-exported here (``from model.rgs import eye_packets``).
"""
from .common import CHUNK
from .eye import (eye_packets, eye_ray, flushed_box, packet_count, ray_setup, sample_coord,
                  setup_one, setup_rays)
from .secondary import (FIX_BITS, FIX_FRAC, FIX_MAX, dot3, hit_colour, hit_colours, light_colour,
                        light_colours, secondary, secondary_rays, shadow_dir, shadow_rays,
                        spec_pow, to_fixed, to_fixed_array)
from .refract import refract_one, refraction_rays
from .slave import shade_batch
from .texture import (TEX_FRAC, TEX_ONE, TEX_SCALE, UV_FRAC, tex_coord, tex_pos, texture_kd,
                      wrap_coord)

__all__ = ["CHUNK", "eye_packets", "eye_ray", "flushed_box", "packet_count", "ray_setup",
           "sample_coord", "setup_one", "setup_rays", "FIX_BITS", "FIX_FRAC", "FIX_MAX", "dot3",
           "hit_colour", "hit_colours", "light_colour", "light_colours", "secondary",
           "secondary_rays", "shadow_dir", "shadow_rays", "spec_pow", "to_fixed",
           "to_fixed_array", "refract_one", "refraction_rays", "shade_batch", "TEX_FRAC",
           "TEX_ONE", "TEX_SCALE", "UV_FRAC", "tex_coord", "tex_pos", "texture_kd",
           "wrap_coord"]
