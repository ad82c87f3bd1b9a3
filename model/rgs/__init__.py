"""The RGS slave's arithmetic (golden model)."""
from .eye import *                                                  # noqa: F401,F403
from .eye import (CHUNK, FIX_MAX, TEX_ONE, TEX_SCALE, flushed_box, setup_one,  # noqa: F401
                  shade_batch)
