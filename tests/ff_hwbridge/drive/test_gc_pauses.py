"""Collector pauses: a frozen heap is not scanned again, and every pause is recorded."""
from __future__ import annotations

import gc

from ff_hwbridge.drive.gc_pauses import FULL_HELD, GcPauses, IdleCollector, freeze_heap, hold_full_collections


def test_freeze_heap_takes_the_heap_out_of_later_collections():
    junk = [[i] for i in range(50_000)]      # long-lived objects a full collection would scan
    try:
        frozen = freeze_heap()
        assert frozen >= len(junk)
        # at least: another thread of this process may freeze its own heap meanwhile
        assert gc.get_freeze_count() >= frozen
        # what survived is frozen: a full collection finds no more of it to scan
        assert sum(len(gc.get_objects(g)) for g in range(3)) < frozen
    finally:
        gc.unfreeze()


def test_pauses_are_counted_and_timed_per_generation():
    p = GcPauses().install()
    try:
        gc.collect(0)
        gc.collect(2)
    finally:
        p.uninstall()
    assert p.count[0] >= 1 and p.count[2] >= 1
    assert p.max_ms[2] > 0.0 and p.total_ms >= p.max_ms[2]
    d = p.as_dict()
    assert d["gc.collections"].count("/") == 2 and "gc.max_pause_ms" in d
    before = list(p.count)
    gc.collect(2)                            # uninstalled: no longer counted
    assert p.count == before


def test_held_full_collections_wait_for_the_idle_collector():
    before = hold_full_collections()
    try:
        assert gc.get_threshold()[2] == FULL_HELD and before[2] != FULL_HELD
        p = GcPauses().install()
        junk = []
        for _ in range(100_000):           # many young collections, no automatic full one
            junk.append([])
        p.uninstall()
        assert p.count[0] > 0 and p.count[2] == 0, p.count
    finally:
        gc.set_threshold(*before)
    now = [0.0]
    busy = [True]
    idle = IdleCollector(lambda: not busy[0], idle_s=1.0, every_s=10.0, clock=lambda: now[0])
    assert idle.tick() is None                       # busy
    busy[0] = False
    assert idle.tick() is None                       # idle, not yet for 1 s
    now[0] = 1.5
    assert idle.tick() is not None and idle.collections == 1
    now[0] = 5.0
    assert idle.tick() is None                       # at most every 10 s
    busy[0] = True
    now[0] = 20.0
    assert idle.tick() is None                       # busy again: the idle time starts over
    busy[0] = False
    assert idle.tick() is None
    now[0] = 21.5
    assert idle.tick() is not None and idle.collections == 2
