""":class:`StallDump` under its earlier name; it lives in :mod:`ff_hwbridge.drive.realtime`."""
from ff_hwbridge.drive.realtime import StallDump

__all__ = ["StallDump"]
