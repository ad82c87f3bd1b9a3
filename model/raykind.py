"""The kind of a ray: :class:`RayKind`, the one encoding of the golden model, the hardware, the
harness and the results (plain Python: no amaranth needed)."""
from __future__ import annotations

import enum

__all__ = ["RayKind"]


class RayKind(enum.IntEnum):
    """A ray's kind, as ``model.raygen.Rays.kind`` holds it (uint8) and as tables of rays by
    kind name it (:attr:`label`: ``stats.json``'s ``rays``, the results' columns).

    * ``EYE``: from the camera through a sample (the RGS slave's eye rays);
    * ``SHADOW``: from a hit toward a light (any hit ends it; one per light that faces the
      surface);
    * ``REFLECTION``: from a hit on a reflective surface, while the reflection depth allows;
    * ``REFRACTION``: from a hit on a material that transmits (``transmit > 0``), through the
      surface by Snell's law (``model/rgs/refract.py``; total internal reflection makes it a
      mirror ray, still of this kind), while the reflection depth allows (each refracted ray
      adds one to the depth, as a reflection does). The golden model makes them; the chip's
      RGS slaves do not (the chip harness refuses a scene whose materials transmit), so
      :meth:`made`, the kinds of the chip's rays, leaves it out.

    The chip's records do not carry a kind but the ray's id (``rtl.rgs.SlaveResult``:
    ``depth``, and ``sub``, 0 an eye or reflection ray, 1 + l a shadow ray toward light l);
    the slave counts its rays into the RTC by kind (``rtl.rgs.slave.RAY_COUNTERS``)."""

    EYE = 0
    SHADOW = 1
    REFLECTION = 2
    REFRACTION = 3

    @property
    def label(self) -> str:
        """The kind's name in tables and ``stats.json``: ``"eye"``, ``"shadow"``, ..."""
        return self.name.lower()

    @classmethod
    def made(cls) -> tuple[RayKind, ...]:
        """The kinds the chip's rays can have (not ``REFRACTION``: only the golden model makes
        refracted rays)."""
        return (cls.EYE, cls.SHADOW, cls.REFLECTION)
