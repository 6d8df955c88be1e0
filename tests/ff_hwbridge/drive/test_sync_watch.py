"""SyncWatch (what the master sees of SYNC) with made-up bus timestamps, and the new bridge
settings of synchronous setpoints; no bus, no threads."""
from __future__ import annotations

import pytest

from ff_hwbridge.drive.config import ConfigError
from ff_hwbridge.drive.sync_watch import SyncWatch
from tests.support.canopen_helpers import mini_config

P = 0.001          # s
T0 = 1_700_000_000.0   # s, wall clock; bus timestamps are float s (~0.24 µs resolution here)


def _feed(w: SyncWatch, lateness_us: list[float], slots: list[int] | None = None) -> None:
    for i, late in enumerate(lateness_us):
        n = i if slots is None else slots[i]
        w.observe(T0 + n * P + late * 1e-6, (n,))


def test_interval_jitter_and_missing_syncs_are_counted():
    w = SyncWatch(P)
    _feed(w, [0, 10, 0, 0, 30], slots=[0, 1, 2, 5, 6])    # slots 3 and 4 missing
    st = w.stats()
    assert st.count == 5 and st.missing == 2
    # intervals 1010, 990, (3000: a gap, not jitter), 1030 µs
    assert st.jitter_max_us == pytest.approx(30.0, abs=0.5)
    assert st.jitter_p50_us == pytest.approx(10.0, abs=0.5)
    ev = w.latest()
    assert ev is not None and ev.count == 5 and ev.echoes == (6,)
    assert [e.count for e in w.since(3)] == [4, 5]


def test_grid_takes_out_the_lateness_of_the_latest_sync():
    w = SyncWatch(P)
    _feed(w, [5, 0, 12, 3, 250])                 # the latest SYNC came 250 µs late
    ev, nominal = w.grid()
    assert ev.count == 5
    # nominal instant of the latest slot = its bus instant less (250 - 0) µs
    assert nominal == pytest.approx(ev.bus_ns - 250_000, abs=500)
    assert abs(nominal - round((T0 + 4 * P) * 1e9)) < 500


def test_listeners_see_every_sync_and_no_sync_means_no_grid():
    w = SyncWatch(P)
    assert w.grid() is None and w.latest() is None and w.age_s() is None
    seen = []
    w.add_listener(lambda ev: seen.append(ev.count))
    _feed(w, [0, 0, 0])
    assert seen == [1, 2, 3]
    w.reset_stats()
    assert w.stats().missing == 0 and w.stats().count == 3


def test_sync_settings_defaults_and_checks():
    cfg = mini_config("unused")
    assert cfg.setpoint_timing == "sync" and cfg.synchronous and cfg.sync_producer == "master"
    assert cfg.missed_cycle_tolerance == 1
    assert cfg.sync_timeout == pytest.approx(max(cfg.heartbeat_timeout, 20 * cfg.sync_period))
    assert not mini_config("unused", setpoint_timing="ON_RECEIPT").synchronous
    assert mini_config("unused", sync_producer="external").sync_producer == "external"
    for bad, key in (({"setpoint_timing": "later"}, "setpoint_timing"),
                     ({"sync_producer": "plc"}, "sync_producer"),
                     ({"missed_cycle_tolerance": -1}, "missed_cycle_tolerance"),
                     ({"sync_timeout": -0.1}, "sync_timeout"),
                     ({"scheduler_rt_priority": -2}, "scheduler_rt_priority")):
        with pytest.raises(ConfigError, match=key):
            mini_config("unused", **bad)
