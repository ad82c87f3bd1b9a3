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
      adds one to the depth, as a reflection does). The chip's RGS slaves make them with
      ``Config.refraction``.

    The chip's records do not carry a kind but the ray's id (``rtl.rgs.SlaveResult``:
    ``depth``; ``sub``, 0 an eye, reflection or refracted ray, 1 + l a shadow ray toward
    light l; with refraction ``path``, bit i set where the ray's ancestor of depth i + 1 is a
    refracted ray); the slave counts its rays into the RTC by kind
    (``rtl.rgs.slave.ray_counters``)."""

    EYE = 0
    SHADOW = 1
    REFLECTION = 2
    REFRACTION = 3

    @property
    def label(self) -> str:
        """The kind's name in tables and ``stats.json``: ``"eye"``, ``"shadow"``, ..."""
        return self.name.lower()

    @classmethod
    def made(cls, refraction: bool = False) -> tuple[RayKind, ...]:
        """The kinds the chip's rays can have: ``REFRACTION`` only with ``refraction``
        (``Config.refraction``)."""
        return (cls.EYE, cls.SHADOW, cls.REFLECTION) + ((cls.REFRACTION,) if refraction else ())
