"""``saarcor bench simspeed``'s profile: perf's report split by Verilated unit."""
from saarcor.bench.simspeed import perf_shares

REPORT = """\
# Overhead  Symbol
# ........  ......
#
    10.00%  [.] Vslave___024root___ico_sequent__TOP__0
     5.50%  [.] Vslave___024root___nba_sequent__TOP__5
     4.00%  [.] Vrtc___024root___nba_sequent__TOP__0
     2.25%  [.] VL_SET_SVLV_W
     1.00%  [.] Vframe___024root____Vdpiimwrap_frame__DOT__run__DOT__chip__DOT__slave0__DOT__unit__DOT__slave_protectlib_combo_update_TOP
     0.75%  [.] slave_protectlib_combo_update
     0.50%  [.] Vframe___024root___nba_sequent__TOP__1
     0.25%  [.] pthread_mutex_trylock@@GLIBC_2.34
     0.20%  [.] Vshade_cache___024root___eval
"""


def test_profile_by_unit():
    p = perf_shares(REPORT)
    assert p["by_unit_percent"] == {"slave": 15.5, "rtc": 4.0, "runtime": 2.5, "boundary": 1.75,
                                    "frame": 0.5, "shade_cache": 0.2}
    assert p["hottest"][0] == ["Vslave___024root___ico_sequent__TOP__0", 10.0]
    assert len(p["hottest"]) == 9
