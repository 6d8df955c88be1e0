"""One short-lived rclpy node for a command-line tool (``ff-ctl``, ``ff-record``).

The node spins on a background thread (a multi-threaded executor), so the tool's main thread can
block on futures; ROS settings come from :func:`ff_msgs_py.launch.client_ros_settings`
(loopback-only discovery unless the user set a range; the domain from the option or
``ROS_DOMAIN_ID``).
"""
from __future__ import annotations

import itertools
import os
import threading
import time
from typing import Any, Optional, Sequence

import rclpy
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ff_msgs_py.launch import client_ros_settings
from ff_msgs_py.spin import spin

_COUNT = itertools.count()


class CallFailed(RuntimeError):
    """A service, action or topic of the running system did not answer as expected (exit code 1)."""


class Session:
    """An rclpy context and a hidden node (name starts with ``_``) spinning on a thread; a context manager."""

    def __init__(self, domain_id: Optional[int] = None, name: str = "ff_ctl") -> None:
        self.domain_id, env = client_ros_settings(domain_id)
        os.environ.update(env)      # rmw reads the discovery range from the environment at init
        self.ctx = rclpy.Context()
        # no rclpy signal handler: the tools catch KeyboardInterrupt themselves (to cancel a goal)
        rclpy.init(context=self.ctx, domain_id=self.domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node(f"_{name}_{os.getpid()}_{next(_COUNT)}", context=self.ctx)
        self.executor = MultiThreadedExecutor(num_threads=2, context=self.ctx)
        self.executor.add_node(self.node)
        self._spin = threading.Thread(target=self._spin_forever, daemon=True)
        self._spin.start()

    def _spin_forever(self) -> None:
        try:
            spin(self.executor)
        except Exception:  # noqa: BLE001 - the context was shut down under the executor
            pass

    def close(self) -> None:
        """Stop the executor thread, destroy the node, shut the context down."""
        self.executor.shutdown(timeout_sec=5.0)
        self._spin.join(timeout=5.0)
        self.node.destroy_node()
        if self.ctx.ok():
            rclpy.shutdown(context=self.ctx)

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @staticmethod
    def wait(future: Any, timeout: float, what: str) -> Any:
        """The future's result, or CallFailed after ``timeout`` s."""
        end = time.monotonic() + timeout
        while not future.done() and time.monotonic() < end:
            time.sleep(0.005)
        if not future.done():
            raise CallFailed(f"{what}: no answer within {timeout:g} s")
        return future.result()

    def call(self, srv_type: Any, name: str, request: Any, timeout: float = 10.0) -> Any:
        """Call service ``name`` once; CallFailed if it is not offered or does not answer."""
        client = self.node.create_client(srv_type, name)
        try:
            if not client.wait_for_service(timeout_sec=timeout):
                raise CallFailed(f"service {name} is not available (is the node running, on this "
                                 f"ROS_DOMAIN_ID={self.domain_id}?)")
            return self.wait(client.call_async(request), timeout, name)
        finally:
            self.node.destroy_client(client)

    def settle_graph(self, timeout: float, quiet: float = 1.5, expect: Sequence[str] = ()) -> None:
        """Wait until discovery is steady: the graph (nodes, topics, endpoints) has not changed for
        ``quiet`` s and every node named in ``expect`` (e.g. "/ff_hwbridge") is in it; at most
        ``timeout`` s. (Fast DDS discovers a node's endpoints one by one, in 0.25-2 s on loopback;
        a busy process may join seconds after the others.)"""
        end = time.monotonic() + timeout
        last: object = None
        since = time.monotonic()
        while time.monotonic() < end:
            n = self.node
            now = (sorted(n.get_node_names_and_namespaces()), sorted(
                (t, len(n.get_publishers_info_by_topic(t)), len(n.get_subscriptions_info_by_topic(t)))
                for t, _ in n.get_topic_names_and_types()), sorted(s for s, _ in n.get_service_names_and_types()))
            if now != last:
                last, since = now, time.monotonic()
            elif now[0] and time.monotonic() - since >= quiet and all(
                    e in {ns.rstrip("/") + "/" + nm for nm, ns in now[0]} for e in expect):
                return
            time.sleep(0.1)
