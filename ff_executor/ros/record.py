"""``ff-record`` (also ``ff-ctl record``): the suite's topics into a rosbag2 folder, MCAP storage.

    ff-record -o run_bag                          # every suite topic, joined as they appear; Ctrl-C stops
    ff-record -o run_bag --duration 10 --topics /ff_hwbridge/joint_states /diagnostics

``ros2 bag`` is not on PyPI; the bag is written with the ``rosbags`` package (the [record] extra)
in rosbag2 format version 9 with MCAP storage, so ``ros2 bag``, Foxglove and the ``mcap`` readers
open it. Messages are stored as received (serialized CDR, subscriptions with ``raw=True``), stamped
with the middleware's reception time (ns, system clock; on stop, messages already queued are
written before the bag closes); each topic carries its type's full definition
(``ff_msgs_py.definitions``: ff_msgs types from the interface files, including the action feedback
message) and the publishers' type hash (RIHS01) and QoS. Each subscription takes the
publishers' reliability and durability (a reliable, transient-local subscription would not hear
a best-effort publisher).

Recorded types (the suite's; a topic of any other type is skipped with a note): those in
:data:`MESSAGE_TYPES`. Exit codes: 0 bag written with at least one message; 1 nothing recorded
(no topic, nothing published); 2 bad usage (the output folder exists, bad options).
"""
from __future__ import annotations

import argparse
import re
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, NoReturn, Optional, Sequence

from action_msgs.msg import GoalStatusArray
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import TransitionEvent
from rcl_interfaces.msg import Log, ParameterEvent
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from ff_executor.ros.session import Session
from ff_msgs.action import ExecuteProfile
from ff_msgs.msg import CurrentProfile, CurrentSetpoint
from ff_msgs_py.definitions import message_definition
from ff_msgs_py.extras import missing_extra

PROG = "ff-record"
#: the message types the recorder knows (imported here by name, so the import contracts see them)
MESSAGE_TYPES: dict[str, Any] = {
    "sensor_msgs/msg/JointState": JointState,
    "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray,
    "ff_msgs/msg/CurrentSetpoint": CurrentSetpoint,
    "ff_msgs/msg/CurrentProfile": CurrentProfile,
    "ff_msgs/action/ExecuteProfile_FeedbackMessage": ExecuteProfile.Impl.FeedbackMessage,
    "action_msgs/msg/GoalStatusArray": GoalStatusArray,
    "lifecycle_msgs/msg/TransitionEvent": TransitionEvent,
    "rcl_interfaces/msg/Log": Log,
    "rcl_interfaces/msg/ParameterEvent": ParameterEvent,
}
READY = "recording"


class RecordUsageError(ValueError):
    """Bad options for the recorder (exit code 2)."""


@dataclass
class RecordSummary:
    """What a recording holds: messages per topic, its folder and length (s)."""

    path: Path
    counts: dict[str, int] = field(default_factory=dict)
    types: dict[str, str] = field(default_factory=dict)
    duration: float = 0.0
    skipped: dict[str, str] = field(default_factory=dict)   # topic -> why


def _qos_time(ns: int) -> Any:
    from rosbags.interfaces import QosTime

    sec, nsec = divmod(int(ns), 1_000_000_000)
    return QosTime(sec, nsec)


def _rosbags_qos(p: Any) -> Any:
    """rclpy QoSProfile -> rosbags Qos (the bag's offered_qos_profiles)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability

    return Qos(QosHistory(int(p.history)), int(p.depth), QosReliability(int(p.reliability)),
               QosDurability(int(p.durability)), _qos_time(p.deadline.nanoseconds),
               _qos_time(p.lifespan.nanoseconds), QosLiveliness(int(p.liveliness)),
               _qos_time(p.liveliness_lease_duration.nanoseconds), False)


class Recorder:
    """Subscribes (raw CDR) to the chosen topics of ``node``'s graph and writes them to a bag."""

    def __init__(self, node: Node, path: str | Path, topics: Optional[Sequence[str]] = None,
                 exclude: Optional[str] = None, log: Callable[[str], None] = print) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError   # optional dependency

        self.node = node
        self.path = Path(path)
        self.topics = list(topics) if topics else None
        self.exclude = re.compile(exclude) if exclude else None
        self.log = log
        try:
            self.writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        except WriterError as exc:
            raise RecordUsageError(str(exc)) from None
        self.writer.open()
        self._lock = threading.Lock()
        self._conns: dict[str, Any] = {}
        self._subs: list[Any] = []
        self._last_rx: dict[str, int] = {}    # topic -> reception time of its newest message (ns)
        self.summary = RecordSummary(self.path)
        self._t0 = time.monotonic()
        self._closed = False

    def _wanted(self, topic: str) -> bool:
        if self.topics is not None:
            return topic in self.topics
        return not (self.exclude and self.exclude.search(topic))

    def poll(self) -> None:
        """Join wanted topics that have appeared since the last poll."""
        me = self.node.get_name()
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self._conns or topic in self.summary.skipped or not self._wanted(topic):
                continue
            pubs = [i for i in self.node.get_publishers_info_by_topic(topic) if i.node_name != me]
            if not pubs:
                continue    # learn QoS and type hash from a publisher
            typename = types[0]
            if typename not in MESSAGE_TYPES:
                self.summary.skipped[topic] = f"type {typename} is not one the recorder knows"
                self.log(f"{PROG}: skipping {topic}: {self.summary.skipped[topic]}")
                continue
            self._join(topic, typename, pubs)

    def _join(self, topic: str, typename: str, pubs: list[Any]) -> None:
        reliable = all(p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in pubs)
        latched = all(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in pubs)
        qos = QoSProfile(depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)
        h = pubs[0].topic_type_hash
        rihs01 = f"RIHS{int(h.version):02d}_{bytes(h.value).hex()}"
        with self._lock:
            conn = self.writer.add_connection(topic, typename, msgdef=message_definition(typename), rihs01=rihs01,
                                              offered_qos_profiles=[_rosbags_qos(p.qos_profile) for p in pubs])
            self._conns[topic] = conn
            self.summary.counts[topic] = 0
            self.summary.types[topic] = typename

        def on_raw(data: bytes, info: Any) -> None:
            # the middleware's reception time: a busy recorder that takes a message late still
            # stamps it when it arrived
            stamp = int(info.get("received_timestamp") or 0) or self.node.get_clock().now().nanoseconds
            with self._lock:
                if not self._closed:
                    self.writer.write(conn, stamp, data)
                    self.summary.counts[topic] += 1
                    self._last_rx[topic] = stamp

        callback: Any = on_raw    # rclpy passes (message, message info) to a two-argument callback
        self._subs.append(self.node.create_subscription(MESSAGE_TYPES[typename], topic, callback, qos, raw=True))
        self.log(f"{PROG}: + {topic} [{typename}]")

    def drain(self, timeout: float = 3.0, recent: float = 1.0) -> bool:
        """Wait until every topic that delivered within ``recent`` s before now has delivered a
        message received after now: the messages already queued when a stop was asked for are
        written, not dropped. At most ``timeout`` s; True when drained."""
        t_stop = time.time_ns()
        with self._lock:
            live = [t for t, ns in self._last_rx.items() if t_stop - ns < recent * 1e9]
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._lock:
                if all(self._last_rx[t] >= t_stop for t in live):
                    return True
            time.sleep(0.02)
        return False

    def close(self) -> RecordSummary:
        """Stop writing, close the bag (writes metadata.yaml); returns the summary."""
        for sub in self._subs:
            self.node.destroy_subscription(sub)
        with self._lock:
            self._closed = True
            self.writer.close()
        self.summary.duration = time.monotonic() - self._t0
        return self.summary


def record(node: Node, path: str | Path, duration: Optional[float] = None,
           topics: Optional[Sequence[str]] = None, exclude: Optional[str] = None,
           stop: Optional[threading.Event] = None, log: Callable[[str], None] = print,
           discovery: float = 10.0, quiet: float = 1.5) -> RecordSummary:
    """Record until ``duration`` s passed, ``stop`` is set, or Ctrl-C; the node must be spinning.

    Prints the ``recording`` line once discovery is steady (no new topic or publisher for ``quiet``
    s, at most ``discovery`` s: Fast DDS finds a node's endpoints one by one); topics appearing
    later are joined as they come.
    """
    rec = Recorder(node, path, topics, exclude, log)
    t0 = time.monotonic()
    end = None if duration is None else t0 + duration
    announced, last, since = False, None, t0
    try:
        while (end is None or time.monotonic() < end) and not (stop is not None and stop.is_set()):
            rec.poll()
            if not announced:
                now = sorted((t, len(node.get_publishers_info_by_topic(t)))
                             for t, _ in node.get_topic_names_and_types())
                if now != last:
                    last, since = now, time.monotonic()
                if time.monotonic() - since >= quiet or time.monotonic() - t0 >= discovery:
                    log(f"{PROG}: {READY} {len(rec._conns)} topic(s) into {rec.path} (MCAP); "
                        + ("Ctrl-C stops" if end is None else f"for {duration:g} s"))
                    announced = True
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    try:
        if not rec.drain():
            log(f"{PROG}: stopped before every queued message was written (the recorder fell behind)")
    except KeyboardInterrupt:    # a second Ctrl-C: close at once
        pass
    return rec.close()


def add_record_arguments(p: argparse.ArgumentParser) -> None:
    """The recorder's options (``ff-record`` and ``ff-ctl record``)."""
    p.add_argument("-o", "--output", default=None, metavar="DIR",
                   help="bag folder to create (must not exist; default ff_bag_<date>_<time>)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S s (default: Ctrl-C)")
    p.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                   help="only these topics (default: every topic of a type the recorder knows)")
    p.add_argument("--exclude", default=None, metavar="REGEX", help="skip topics matching this")


def run_record(s: Session, a: argparse.Namespace, prog: str = PROG) -> int:
    """Record with parsed options on a session's node; prints a summary; returns the exit code."""
    if a.duration is not None and not a.duration > 0:
        raise RecordUsageError("--duration must be > 0 s")
    out = a.output or time.strftime("ff_bag_%Y%m%d_%H%M%S")
    if threading.current_thread() is threading.main_thread():   # SIGTERM closes the bag too
        signal.signal(signal.SIGTERM, _interrupt)
    summary = record(s.node, out, a.duration, a.topics, a.exclude)
    total = sum(summary.counts.values())
    print(f"{prog}: wrote {total} messages on {len(summary.counts)} topic(s) in {summary.duration:.1f} s "
          f"to {summary.path}")
    for topic in sorted(summary.counts):
        print(f"  {topic}  [{summary.types[topic]}]  {summary.counts[topic]}")
    missing = sorted(set(a.topics or ()) - set(summary.counts))
    if missing:
        print(f"{prog}: never saw a publisher on {', '.join(missing)}", file=sys.stderr)
    return 0 if total else 1


def _interrupt(*_: Any) -> None:
    raise KeyboardInterrupt


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise RecordUsageError(f"{message} (see {self.prog} --help)")


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Console script ``ff-record``."""
    ap = _Parser(prog=PROG, description=__doc__.splitlines()[0].replace("``", ""),
                 formatter_class=argparse.RawDescriptionHelpFormatter,
                 epilog="\n".join(__doc__.splitlines()[2:5]))
    ap.add_argument("--domain-id", type=int, default=None, help="ROS domain (default: ROS_DOMAIN_ID, else 0)")
    add_record_arguments(ap)
    try:
        a = ap.parse_args(argv)
        with Session(a.domain_id, name="ff_record") as s:
            return run_record(s, a)
    except SystemExit as exc:   # --help
        return int(exc.code or 0)
    except (RecordUsageError, ValueError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:
        print(f"{PROG}: {missing_extra(exc)}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
