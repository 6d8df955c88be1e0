"""``ff-can-hub [--port P] [--host 127.0.0.1]``: serve the loopback CAN hub until SIGINT/SIGTERM.

Prints ``CAN hub on ws://127.0.0.1:PORT/`` once serving and ``CAN hub stopped`` on the way out.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Optional, Sequence

from ff_hwbridge.drive.bus import LOOPBACK, CanConfigError
from ff_hwbridge.sim.can_hub import start_hub

__all__ = ["main"]


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Serve the hub until SIGINT/SIGTERM; exit code 2 on a setting that cannot be used."""
    ap = argparse.ArgumentParser(prog="ff-can-hub",
                                 description="One CAN bus shared by processes on this machine, "
                                             "on loopback only.")
    ap.add_argument("--port", type=int, default=54701, help="TCP port on 127.0.0.1 (0 = any free)")
    ap.add_argument("--host", default=LOOPBACK, help="loopback address to bind (default 127.0.0.1)")
    args = ap.parse_args(argv)
    try:
        hub = start_hub(args.port, args.host)
    except CanConfigError as exc:
        print(f"ff-can-hub: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(f"CAN hub on {hub.url}", flush=True)
    while not stop.wait(0.2):
        pass
    hub.close()
    print("CAN hub stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
