"""The RGS (ray generation and shading) hardware."""
from .eye import *          # noqa: F401,F403
from .slave import *        # noqa: F401,F403
