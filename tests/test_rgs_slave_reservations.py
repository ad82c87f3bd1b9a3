"""The RGS slave's pending-buffer reservations cannot deadlock (``rtl/rgs/slave.py``, module
docstring; ``docs/chip.md``, "Why nothing is lost and nothing deadlocks"), checked on an
abstract model of the slave's packets by an exhaustive search of its states.

The model: ``NB`` pending buffers, ``S`` RTC packet slots, ``K`` = lights + 1 (+ 1 with
refraction) buffers reserved by every packet that may spawn rays, depths 0 (eye packets) to
``D`` (``reflect_depth``). A packet that may spawn holds its K buffers while in flight; at
its commit, any of its hits' spawning children (a reflection packet and, with refraction, a
refracted packet, one level deeper, where they may spawn in turn: with lights, or above
depth D) take one of its buffers each and wait, and the rest come back (the shadow packets'
buffers as soon as they are sent: they need no reservation). A waiting packet starts when
K buffers are free and a slot is; its own buffer comes back once it is sent. Eye packets are
admitted only while no packet waits. The adversary picks every order and every hit's
children. A deadlock is a state with packets waiting, none in flight and none that may
start. (Shadow packets and packets that spawn nothing always start and are left out.)

With refraction a commit may leave two waiting packets that spawn: the slave then starts the
deepest first and lets at most ``B = (NB - K) // (D + 1)`` *branching* packets (that may
spawn, below depth D) be in flight; with ``NB >= K + D + 1`` (``Config.min_rgs_buffers``)
no state deadlocks. Without those two rules, the lights + 2 reservation alone deadlocks."""
import pytest

from model.config import Config


def deadlock(NB: int, L: int, D: int, S: int, eyes: int, refraction: bool,
             gate: bool, deepest: bool = True) -> tuple | None:
    """A reachable deadlock of the abstract slave (the module docstring) as its state
    ``(free buffers, waiting per depth, in flight per depth, eye packets left)``, or None.
    ``gate``: refraction's rules (the deepest first, at most B branching packets);
    ``deepest``: with ``gate``, the first of the two (without it only the bound applies)."""
    R = int(refraction)
    K = L + 1 + R
    B = max(1, (NB - K) // (D + 1)) if gate else NB

    def spawns(d):
        return L > 0 or d < D
    start = (NB, (0,) * (D + 1), (0,) * (D + 1), eyes)
    seen, stack = {start}, [start]
    while stack:
        st = stack.pop()
        free, wait, fly, left = st
        nxt, flying = [], sum(fly)
        branching = sum(fly[:D])
        if left and not sum(wait) and flying < S and free >= K and (D == 0 or branching < B):
            f = list(fly)
            f[0] += 1
            nxt.append((free - K, wait, tuple(f), left - 1))
        depths = [d for d in range(D + 1) if wait[d]]
        if gate and deepest and depths:
            depths = [max(depths)]
        for d in depths:
            if free >= K and flying < S and (d >= D or branching < B):
                w, f = list(wait), list(fly)
                w[d] -= 1
                f[d] += 1
                nxt.append((free - K + 1, tuple(w), tuple(f), left))
        for d in range(D + 1):
            if not fly[d]:
                continue
            f = list(fly)
            f[d] -= 1
            most = 1 + R if d < D and spawns(d + 1) else 0
            for k in range(most + 1):
                w = list(wait)
                if k:
                    w[d + 1] += k
                nxt.append((free + K - k, tuple(w), tuple(f), left))
        if not nxt and (sum(wait) or sum(fly)):
            return st
        for s in nxt:
            if s not in seen:
                seen.add(s)
                stack.append(s)
    return None


@pytest.mark.parametrize("lights", [0, 1, 3])
@pytest.mark.parametrize("depth", [1, 2, 3])
def test_refraction_reservations_never_deadlock(lights, depth):
    """With refraction, the configuration's fewest buffers and a few more: no deadlock, with
    the slave's rules (the deepest first, at most B branching packets in flight)."""
    cfg = Config(refraction=True, rgs_lights=lights, reflect_depth=depth)
    for NB in range(cfg.min_rgs_buffers, cfg.min_rgs_buffers + 3):
        assert deadlock(NB, lights, depth, S=NB + 2, eyes=NB + 2, refraction=True,
                        gate=True) is None


def test_refraction_without_the_rules_deadlocks():
    """The lights + 2 reservation alone is not enough: two waiting packets per commit fill
    the buffers (1 light, depth 2, the 2 (lights + 2) + 2 = 8 buffers; no light, depth 2,
    6 buffers)."""
    assert deadlock(8, 1, 2, S=4, eyes=4, refraction=True, gate=False) is not None
    assert deadlock(6, 0, 2, S=4, eyes=4, refraction=True, gate=False) is not None
    assert deadlock(8, 1, 2, S=4, eyes=4, refraction=True, gate=True) is None


@pytest.mark.parametrize("depth", [1, 2, 3, 5])
def test_reflections_without_lights_never_deadlock_under_the_rules(depth):
    """K = 1 (no light in use, no refraction): a commit's waiting reflection packet takes the
    buffer its parent reserved and returns none, so from depth 2 the lowest-first order alone
    deadlocks (every buffer held by a waiting packet); the slave bounds the branching packets
    there (``rtl/rgs/slave.py``, ``pb.gated``; one waiting packet a commit needs no
    deepest-first order), and from the configuration's fewest buffers (at least
    reflect_depth + 2) no state deadlocks.
    (More RTC slots than buffers, as in the chip: 2 x threads slots, threads + K buffers.)"""
    cfg = Config(rgs_lights=0, reflect_depth=depth)
    assert cfg.min_rgs_buffers == max(4, depth + 2)
    for NB in range(cfg.min_rgs_buffers, cfg.min_rgs_buffers + 3):
        assert deadlock(NB, 0, depth, S=NB + 2, eyes=NB + 2, refraction=False,
                        gate=True, deepest=False) is None
    if depth >= 2:
        NB = cfg.min_rgs_buffers
        assert deadlock(NB, 0, depth, S=NB + 2, eyes=NB + 2, refraction=False,
                        gate=False) is not None


@pytest.mark.parametrize("lights", [1, 3])
def test_reflections_alone_never_deadlock(lights):
    """Without refraction (one waiting packet per commit at most), the fewest buffers,
    2 (lights + 1) + 2, never deadlock with the lowest-first order."""
    cfg = Config(rgs_lights=lights)
    for depth in (1, 2, 3):
        NB = cfg.min_rgs_buffers
        assert deadlock(NB, lights, depth, S=NB + 2, eyes=NB + 2, refraction=False,
                        gate=False) is None
