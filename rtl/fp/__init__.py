"""Floating-point pipeline units, bit-exact with ``model/fp.py`` (see docs/fp.md)."""
from .add import FPAdd
from .cmp import CompareLayout, FPCompare, FPMinMax
from .conv import FPFromInt
from .div import FPDiv
from .mul import FPMul
from .pipe import Stager, placement
from .sqrt import FPSqrt

__all__ = ["FPAdd", "FPMul", "FPDiv", "FPCompare", "FPMinMax", "FPFromInt", "FPSqrt", "CompareLayout",
           "Stager", "placement"]
