"""A drive owner in a process of its own (killed by the ownership test): claims the bridge's drive
with the lease given on the command line, prints ``claimed <lease>``, renews it until killed."""
from __future__ import annotations

import sys
import threading

import rclpy
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node

from ff_msgs_py.claims import DriveClaim
from ff_msgs_py.spin import spin


def main() -> None:
    lease = float(sys.argv[1])
    rclpy.init()
    node = Node("doomed_owner")
    ex = MultiThreadedExecutor(num_threads=2)
    ex.add_node(node)
    threading.Thread(target=spin, args=(ex,), daemon=True).start()
    claim = DriveClaim(node, "/ff_hwbridge", lease=lease, timeout=30.0)
    print(f"claimed {claim.lease}", flush=True)
    threading.Event().wait()


if __name__ == "__main__":
    main()
