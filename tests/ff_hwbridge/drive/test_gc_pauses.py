"""Collector pauses: a frozen heap is not scanned again, and every pause is recorded."""
from __future__ import annotations

import gc

from ff_hwbridge.drive.gc_pauses import GcPauses, freeze_heap


def test_freeze_heap_takes_the_heap_out_of_later_collections():
    junk = [[i] for i in range(50_000)]      # long-lived objects a full collection would scan
    try:
        frozen = freeze_heap()
        assert frozen >= len(junk)
        assert gc.get_freeze_count() == frozen
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
