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
    * ``REFRACTION``: named so the encoding has room for it, but no ray of this kind is made:
      refraction is future work (the materials carry ``transmit`` and ``ior``; neither the
      model nor the hardware makes refracted rays). :meth:`made` leaves it out.

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
        """The kinds a frame's rays can have (not ``REFRACTION``)."""
        return (cls.EYE, cls.SHADOW, cls.REFLECTION)
