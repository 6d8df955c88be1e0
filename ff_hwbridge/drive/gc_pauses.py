"""The garbage-collector helpers under their earlier name; they live in
:mod:`ff_hwbridge.drive.realtime` with the other real-time set-up."""
from ff_hwbridge.drive.realtime import (FULL_HELD, GcPauses, IdleCollector, freeze_heap, hold_full_collections,
                                        pauses)

__all__ = ["FULL_HELD", "GcPauses", "IdleCollector", "freeze_heap", "hold_full_collections", "pauses"]
