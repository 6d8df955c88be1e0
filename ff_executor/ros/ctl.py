"""``ff-ctl``: what the ``ros2`` command line does, for the ff suite (the ``ros2`` CLI is not on PyPI).

    ff-ctl graph                                  # nodes, topics with types, services, actions
    ff-ctl lifecycle get ff_hwbridge              # the bridge's lifecycle state, e.g. active
    ff-ctl lifecycle set ff_hwbridge deactivate   # a transition, or its goal state (inactive)
    ff-ctl diag --follow                          # /diagnostics, formatted
    ff-ctl fault-reset                            # clear the bridge's latched safe state
    ff-ctl status                                 # the bridge: state, why not active, owner, refusals
    ff-ctl claim --hold                           # own the drive until Ctrl-C (also: release, enable)
    ff-ctl echo /ff_hwbridge/joint_states --count 1   # any topic as YAML; ff-ctl call SERVICE '{...}'
    ff-ctl param get ff_executor lead_time        # also: param set NODE NAME VALUE, param list NODE
    ff-ctl plan --qf 1 --tf 1 --uncertain pv pc pt -o move.json   # ff-plan's options, via the service
    ff-ctl execute move.json                      # an ff-motion/1 file (or plan options): live feedback
    ff-ctl record -o run_bag --duration 10        # = ff-record: the suite's topics into rosbag2/MCAP

ROS settings: discovery on loopback only unless ROS_AUTOMATIC_DISCOVERY_RANGE is set; the domain
from --domain-id, else ROS_DOMAIN_ID, else 0 (``ff-bringup`` prints its stack's domain); relative
names (ff_hwbridge, ff_planner/plan) under ``--namespace`` (a namespaced stack).
Exit codes: 0 done; 1 the operation failed (nothing answered, refused, goal not succeeded); 2 bad usage.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from typing import Any, NoReturn, Optional, Sequence

import numpy as np
import yaml
from action_msgs.msg import GoalStatus
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.action import get_action_names_and_types
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from ff_executor.ros.client import SafeActionClient
from ff_executor.ros.record import add_record_arguments, run_record
from ff_executor.ros.session import CallFailed, Session
from ff_msgs.action import ExecuteProfile
from ff_msgs.msg import DriveGroupStatus
from ff_msgs.srv import ClaimDrive, OwnerCommand, PlanTrajectory
from ff_msgs_py.claims import ClaimError, DriveClaim, call_claim, owner_command
from ff_msgs_py.convert import profile_to_msg, request_to_msg, response_to_result
from ff_msgs_py.extras import missing_extra
from ff_msgs_py.introspect import checked, fill, interface_type, to_data
from ff_planner.cli import plan as plan_cli
from ff_planner.export.motion_file import MotionFileError, read_motion
from ff_planner.model.params import ParameterError
from ff_planner.model.profile import PlanningError, PlanRequest
from ff_planner.model.simulate import rest_position

PROG = "ff-ctl"
#: PlanTrajectory errors that mean "change the request" (exit 2, as ff-plan), not "planning failed"
BAD_INPUT = ("INVALID_REQUEST", "UNKNOWN_MODEL", "UNKNOWN_PARAMETER", "UNREACHABLE")
LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
#: services every rclpy node offers; ``graph`` lists them with --all only
STANDARD_SERVICES = ("describe_parameters", "get_parameter_types", "get_parameters", "list_parameters",
                     "set_parameters", "set_parameters_atomically", "get_type_description")


class UsageError(Exception):
    """Bad command-line input (exit code 2)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (see {self.prog} --help)")


def _node_name(name: str, namespace: str = "") -> str:
    """A node, topic or service name made absolute: ``/x`` stays, ``x`` -> ``/<namespace>/x``
    (``/x`` without a namespace)."""
    if name.startswith("/"):
        return name
    ns = namespace.strip("/")
    return f"/{ns}/{name}" if ns else f"/{name}"


def _fmt(values: Any, digits: int = 4) -> str:
    return "[" + ", ".join(f"{float(v):.{digits}f}" for v in values) + "]"


# --- graph ------------------------------------------------------------------------------------
def graph(s: Session, a: argparse.Namespace) -> int:
    """Nodes, topics (types, publisher/subscriber counts), services and actions of the domain."""
    s.settle_graph(a.wait, expect=[_node_name(n, a.namespace) for n in a.expect])
    me = s.node.get_fully_qualified_name()
    nodes = sorted(f"{ns.rstrip('/')}/{n}" for n, ns in s.node.get_node_names_and_namespaces()
                   if f"{ns.rstrip('/')}/{n}" != me and (a.all or not n.startswith("_")))
    actions = sorted((n, t) for n, t in get_action_names_and_types(s.node))
    topics = []
    for name, types in sorted(s.node.get_topic_names_and_types()):
        if "/_action/" in name and not a.all:
            continue
        pubs = [i for i in s.node.get_publishers_info_by_topic(name) if i.node_name != me.lstrip("/")]
        subs = [i for i in s.node.get_subscriptions_info_by_topic(name) if i.node_name != me.lstrip("/")]
        topics.append((name, types, len(pubs), len(subs)))
    services = sorted((n, t) for n, t in s.node.get_service_names_and_types()
                      if a.all or ("/_action/" not in n and n.rsplit("/", 1)[-1] not in STANDARD_SERVICES))
    if a.json:
        print(json.dumps({"domain_id": s.domain_id, "nodes": nodes,
                          "topics": [{"name": n, "types": t, "publishers": p, "subscribers": c}
                                     for n, t, p, c in topics],
                          "services": [{"name": n, "types": t} for n, t in services],
                          "actions": [{"name": n, "types": t} for n, t in actions]}, indent=2))
        return 0 if nodes else 1
    print(f"ROS_DOMAIN_ID={s.domain_id}")
    print(f"nodes ({len(nodes)}):")
    for n in nodes:
        print(f"  {n}")
    print(f"topics ({len(topics)}):")
    for n, t, p, c in topics:
        print(f"  {n}  [{', '.join(t)}]  {p} pub, {c} sub")
    print(f"services ({len(services)}{'' if a.all else ', per-node parameter services hidden: --all'}):")
    for n, t in services:
        print(f"  {n}  [{', '.join(t)}]")
    print(f"actions ({len(actions)}):")
    for n, t in actions:
        print(f"  {n}  [{', '.join(t)}]")
    if not nodes:
        print(f"{PROG}: no node found on ROS_DOMAIN_ID={s.domain_id} (set --domain-id / ROS_DOMAIN_ID "
              "to the stack's, e.g. the one ff-bringup prints)", file=sys.stderr)
        return 1
    return 0


# --- lifecycle --------------------------------------------------------------------------------
def _transitions(s: Session, node: str, timeout: float) -> list[Any]:
    res = s.call(GetAvailableTransitions, f"{node}/get_available_transitions",
                 GetAvailableTransitions.Request(), timeout)
    return list(res.available_transitions)


#: (from, to) primary states -> the transitions that lead there (ROS 2 managed-node state machine)
LIFECYCLE_PATHS = {
    ("unconfigured", "inactive"): ("configure",), ("unconfigured", "active"): ("configure", "activate"),
    ("inactive", "active"): ("activate",), ("active", "inactive"): ("deactivate",),
    ("inactive", "unconfigured"): ("cleanup",), ("active", "unconfigured"): ("deactivate", "cleanup"),
    ("unconfigured", "finalized"): ("shutdown",), ("inactive", "finalized"): ("shutdown",),
    ("active", "finalized"): ("shutdown",),
}


def _state(s: Session, node: str, timeout: float) -> str:
    try:
        return s.call(GetState, f"{node}/get_state", GetState.Request(), timeout).current_state.label
    except CallFailed as exc:
        raise CallFailed(f"{node} is not a running lifecycle node ({exc})") from None


def lifecycle(s: Session, a: argparse.Namespace) -> int:
    """``get``: the state (-v: and the transitions from it); ``set``: a transition or a goal state
    (``active`` from ``unconfigured`` runs configure, then activate)."""
    node = _node_name(a.node, a.namespace)
    state = _state(s, node, a.timeout)
    avail = [t.transition.label for t in _transitions(s, node, a.timeout)]
    if a.action == "get":
        print(state)
        if a.verbose:
            print(f"  transitions: {', '.join(avail) or 'none'}")
        return 0
    want = a.state.strip().lower()
    if want in avail:
        steps: tuple[str, ...] = (want,)
    elif want == state:
        print(f"{node} is already {state}")
        return 0
    elif (state, want) in LIFECYCLE_PATHS:
        steps = LIFECYCLE_PATHS[(state, want)]
    else:
        raise CallFailed(f"{node} is '{state}'; '{a.state}' is neither a transition available from there "
                         f"({', '.join(avail) or 'none'}) nor a state reachable from it")
    for label in steps:
        trans = {t.transition.label: t.transition for t in _transitions(s, node, a.timeout)}
        if label not in trans:
            raise CallFailed(f"{node}: transition '{label}' is not available in state '{state}'")
        tr = trans[label]
        res = s.call(ChangeState, f"{node}/change_state",
                     ChangeState.Request(transition=Transition(id=tr.id, label=tr.label)), a.timeout)
        after = _state(s, node, a.timeout)
        if not res.success:
            raise CallFailed(f"transition '{label}' of {node} failed; it is now '{after}' "
                             "(its log and ff-ctl diag say why)")
        print(f"{node}: {label}: {state} -> {after}")
        state = after
    return 0


def fault_reset(s: Session, a: argparse.Namespace) -> int:
    """Leave a latched safe state: the bridge's ``~/fault_reset`` (std_srvs/Trigger, open while no
    client holds the drive), or with ``--token`` the owner's ``~/owner_command`` FAULT_RESET."""
    node = _node_name(a.node, a.namespace)
    if a.token:
        res = owner_command(s.node, node, OwnerCommand.Request.FAULT_RESET, a.token, a.timeout)
    else:
        res = s.call(Trigger, f"{node}/fault_reset", Trigger.Request(), a.timeout)
    print(f"{node}: fault reset {'done' if res.success else 'refused'}: {res.message}")
    return 0 if res.success else 1


# --- ownership of the drive -------------------------------------------------------------------
def claim(s: Session, a: argparse.Namespace) -> int:
    """Claim the bridge's drive (``~/claim``): print the token; ``--hold`` keeps it (renewing)
    until Ctrl-C, then releases it; ``--renew`` renews the claim of ``--token``."""
    node = _node_name(a.node, a.namespace)
    if a.renew:
        if not a.token:
            raise UsageError("claim --renew needs --token")
        res = call_claim(s.node, node, ClaimDrive.Request.RENEW, token=a.token, timeout=a.timeout)
        print(f"{node}: {'renewed' if res.success else 'refused'}: {res.message}")
        return 0 if res.success else 1
    if a.hold:
        try:
            held = DriveClaim(s.node, node, lease=a.lease, timeout=a.timeout)
        except ClaimError as exc:
            raise CallFailed(f"{node}: {exc}") from None
        print(f"{node}: claimed by {s.node.get_fully_qualified_name()} (lease {held.lease:g} s, renewed "
              f"every {held.lease / 3:g} s); token {held.token}; holding until Ctrl-C", flush=True)
        try:
            while not held.lost:
                time.sleep(0.1)
        except KeyboardInterrupt:
            pass
        if held.lost:
            raise CallFailed(f"{node}: the claim was lost: {held.lost}")
        res = held.release()
        print(f"{node}: {res.message if res.success else 'release refused: ' + res.message}")
        return 0 if res.success else 1
    client = a.client or s.node.get_fully_qualified_name()
    res = call_claim(s.node, node, ClaimDrive.Request.CLAIM, client=client, lease=a.lease, timeout=a.timeout)
    if not res.success:
        raise CallFailed(f"{node}: claim refused: {res.message}")
    print(f"{node}: {res.message}; token {res.token}")
    print(f"  carry it in CurrentSetpoint.token / the effort command's header.frame_id; renew within "
          f"{res.lease:g} s (ff-ctl claim --renew --token T, or any accepted command); "
          f"ff-ctl release --token T")
    return 0


def release(s: Session, a: argparse.Namespace) -> int:
    """Release the claim of ``--token`` (``~/claim`` RELEASE)."""
    node = _node_name(a.node, a.namespace)
    res = call_claim(s.node, node, ClaimDrive.Request.RELEASE, token=a.token, timeout=a.timeout)
    print(f"{node}: {res.message if res.success else 'release refused: ' + res.message}")
    return 0 if res.success else 1


def enable(s: Session, a: argparse.Namespace) -> int:
    """The owner's ``~/owner_command`` ENABLE (lifecycle activate while it holds the drive)."""
    node = _node_name(a.node, a.namespace)
    res = owner_command(s.node, node, OwnerCommand.Request.ENABLE, a.token, a.timeout)
    print(f"{node}: enable {'done' if res.success else 'refused'}: {res.message}")
    return 0 if res.success else 1


STATE_NAMES = {DriveGroupStatus.UNCONFIGURED: "unconfigured", DriveGroupStatus.INACTIVE: "inactive",
               DriveGroupStatus.ACTIVE: "active", DriveGroupStatus.SAFE_STATE: "safe state"}


def format_drive_status(node: str, m: Any) -> str:
    """The bridge's typed ~/status (ff_msgs/msg/DriveGroupStatus) as text."""
    lines = [f"{node}: {STATE_NAMES.get(m.state, str(m.state))}: {m.message}"]
    if m.config_error:
        lines.append(f"  configure failed: {m.config_error}")
    if m.latch_reason:
        lines.append(f"  safe state: {m.latch_reason} (ff-ctl fault-reset clears it)")
    limited = list(m.current_limited_cycles) or [0] * len(m.joint_names)
    for name, state, emcy, lim in zip(m.joint_names, m.drive_states, m.last_emcy, limited):
        lines.append(f"  {name}: {state}" + (f"; last EMCY {emcy}" if emcy else "")
                     + (f"; current limited in {lim} cycles of the latest motion (statusword bit 11: "
                        "the drive clipped it)" if lim else ""))
    if m.state != DriveGroupStatus.UNCONFIGURED:
        owner = m.owner or "nobody"
        since = m.claimed_since.sec + m.claimed_since.nanosec * 1e-9
        held = (f", held since {time.strftime('%H:%M:%S', time.localtime(since))}"
                f" ({max(0.0, time.time() - since):.1f} s)" if since > 0 else "")
        lines.append(f"  owner: {owner}" + (f" (claimed{held}, {m.lease_left:.1f} s lease left)" if m.claimed
                                            else " (default owner, no claim)" if m.owner else ""))
        lines.append(f"  refused: {m.refused}" + (f" (latest: {m.last_refusal})" if m.last_refusal else ""))
        lines.append(f"  setpoints: SYNC period {m.sync_period * 1e3:g} ms, {m.missed_setpoints} missed "
                     f"their cycle")
    return "\n".join(lines)


def status(s: Session, a: argparse.Namespace) -> int:
    """The bridge's typed ``~/status``: state, why it is not active (configure error, safe state),
    drives, owner, refusals. Exit 0 when active, 1 otherwise."""
    node = _node_name(a.node, a.namespace)
    got: list[Any] = []
    s.node.create_subscription(DriveGroupStatus, f"{node}/status", got.append, 10)
    end = time.monotonic() + a.timeout
    while not got and time.monotonic() < end:
        time.sleep(0.05)
    if not got:
        raise CallFailed(f"no {node}/status within {a.timeout:g} s (is the bridge running, on "
                         f"ROS_DOMAIN_ID={s.domain_id}?)")
    m = got[-1]
    print(format_drive_status(node, m))
    return 0 if m.state == DriveGroupStatus.ACTIVE else 1


# --- any topic or service ---------------------------------------------------------------------
def _wait_for_type(s: Session, name: str, services: bool, timeout: float) -> str:
    """The interface type of topic / service ``name`` once discovery shows it."""
    end = time.monotonic() + timeout
    while True:
        found = dict((n, t) for n, t in (s.node.get_service_names_and_types() if services
                                         else s.node.get_topic_names_and_types()))
        if name in found and found[name]:
            return str(found[name][0])
        if time.monotonic() >= end:
            what = "service" if services else "topic"
            raise CallFailed(f"{what} {name} is not on ROS_DOMAIN_ID={s.domain_id} within {timeout:g} s "
                             f"(ff-ctl graph lists what is)")
        time.sleep(0.1)


def echo(s: Session, a: argparse.Namespace) -> int:
    """Print the messages of a topic as YAML documents (``--count N``: stop after N)."""
    topic = _node_name(a.topic, a.namespace)
    cls = interface_type(_wait_for_type(s, topic, False, a.timeout))
    got: list[Any] = []
    cond = threading.Condition()

    def on_msg(m: Any) -> None:
        with cond:
            got.append(m)
            cond.notify_all()

    # best effort takes reliable and best-effort publishers alike
    s.node.create_subscription(cls, topic, on_msg, QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT))
    shown = 0
    end = time.monotonic() + a.timeout
    try:
        while not a.count or shown < a.count:
            with cond:
                cond.wait(0.2)
                batch, got[:] = list(got), []
            for m in batch[: (a.count - shown) if a.count else None]:
                print(yaml.safe_dump(to_data(m), sort_keys=False, allow_unicode=True) + "---", flush=True)
                shown += 1
            if a.count and not shown and time.monotonic() > end:
                raise CallFailed(f"no message on {topic} within {a.timeout:g} s")
    except KeyboardInterrupt:
        return 0
    return 0


def call_service(s: Session, a: argparse.Namespace) -> int:
    """Call a service with a request given as YAML (``'{field: value, ...}'``); print the response."""
    name = _node_name(a.service, a.namespace)
    typ = _wait_for_type(s, name, True, a.timeout)
    cls = interface_type(typ)
    try:
        data = yaml.safe_load(a.request) if a.request else {}
    except yaml.YAMLError as exc:
        raise UsageError(f"the request is not YAML: {exc}") from None
    request = fill(checked(cls.Request), data or {})
    res = s.call(cls, name, request, a.timeout)
    print(f"# {name} ({typ})")
    print(yaml.safe_dump(to_data(res), sort_keys=False, allow_unicode=True), end="")
    return 0


# --- diagnostics ------------------------------------------------------------------------------
def format_status(st: Any, values: bool = True) -> str:
    """One diagnostic status as text: ``[LEVEL] name: message`` and its key/value pairs indented."""
    level = st.level if isinstance(st.level, int) else int.from_bytes(st.level, "little")
    lines = [f"[{LEVELS.get(level, str(level)):<5}] {st.name}: {st.message}"]
    if values:
        lines += [f"          {kv.key}: {kv.value}" for kv in st.values]
    return "\n".join(lines)


def diag(s: Session, a: argparse.Namespace) -> int:
    """Collect /diagnostics for ``--duration`` s and print each status's latest report, or follow."""
    latest: dict[str, DiagnosticStatus] = {}

    def on_msg(msg: DiagnosticArray) -> None:
        for st in msg.status:
            if a.follow:
                print(format_status(st, not a.brief), flush=True)
            latest[st.name] = st

    s.node.create_subscription(DiagnosticArray, a.topic, on_msg, 50)
    try:
        if a.follow:
            while True:
                time.sleep(0.2)
        # listen --duration s once the publishers are discovered (at most 5 s more)
        s.settle_graph(timeout=5.0, quiet=1.0)
        time.sleep(a.duration)
    except KeyboardInterrupt:
        return 0
    if not latest:
        raise CallFailed(f"no message on {a.topic} within {a.duration:g} s "
                         f"(ROS_DOMAIN_ID={s.domain_id})")
    for name in sorted(latest):
        print(format_status(latest[name], not a.brief))
    return 0


# --- parameters -------------------------------------------------------------------------------
def _value_msg(text: str, current_type: int) -> Any:
    """A ParameterValue from command-line text (YAML scalar or list), coerced to ``current_type``."""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        value = text
    if current_type == ParameterType.PARAMETER_DOUBLE and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if current_type == ParameterType.PARAMETER_DOUBLE_ARRAY and isinstance(value, list):
        value = [float(v) if isinstance(v, int) and not isinstance(v, bool) else v for v in value]
    if current_type == ParameterType.PARAMETER_STRING and not isinstance(value, str):
        value = text
    try:
        return Parameter("v", value=value).get_parameter_value()
    except (TypeError, ValueError, AttributeError) as exc:
        raise UsageError(f"cannot make a parameter value of {text!r}: {exc}") from None


def param(s: Session, a: argparse.Namespace) -> int:
    """``list`` / ``get`` / ``describe`` / ``set`` a node's parameters (its parameter services)."""
    node = _node_name(a.node, a.namespace)
    if a.action == "list":
        res = s.call(ListParameters, f"{node}/list_parameters", ListParameters.Request(), a.timeout)
        for n in sorted(res.result.names):
            print(n)
        return 0
    got = s.call(GetParameters, f"{node}/get_parameters", GetParameters.Request(names=[a.name]), a.timeout)
    current = got.values[0] if got.values else None
    if current is None or current.type == ParameterType.PARAMETER_NOT_SET:
        raise CallFailed(f"{node} has no parameter '{a.name}' (ff-ctl param list {a.node})")
    if a.action == "get":
        print(json.dumps(parameter_value_to_python(current), default=list))
        return 0
    if a.action == "describe":
        d = s.call(DescribeParameters, f"{node}/describe_parameters",
                   DescribeParameters.Request(names=[a.name]), a.timeout).descriptors[0]
        print(f"{a.name}: {json.dumps(parameter_value_to_python(current), default=list)}")
        print(f"  description: {d.description or '-'}")
        for r in d.floating_point_range:
            print(f"  range: {r.from_value:g} .. {r.to_value:g}" + (f" step {r.step:g}" if r.step else ""))
        for r in d.integer_range:
            print(f"  range: {r.from_value} .. {r.to_value}" + (f" step {r.step}" if r.step else ""))
        if d.additional_constraints:
            print(f"  constraints: {d.additional_constraints}")
        print(f"  read only: {'yes (applies at start only)' if d.read_only else 'no'}")
        return 0
    if a.value is None:
        raise UsageError("param set needs NODE NAME VALUE")
    value = _value_msg(a.value, current.type)
    param_msg = Parameter(a.name).to_parameter_msg()
    param_msg.value = value
    res = s.call(SetParameters, f"{node}/set_parameters", SetParameters.Request(parameters=[param_msg]),
                 a.timeout).results[0]
    if not res.successful:
        raise CallFailed(f"{node} refused {a.name} = {a.value}: {res.reason or 'no reason given'}")
    print(f"{node}: {a.name} = {json.dumps(parameter_value_to_python(value), default=list)}")
    return 0


# --- plan / execute ---------------------------------------------------------------------------
_PLAN_OPTIONS = ("q0", "qf", "tf", "uncertain", "objective", "steps", "starts", "seed", "time_budget",
                 "model", "preset", "params", "config", "box", "coast_max", "q_min", "q_max", "qd_max",
                 "tolerance", "tf_max")


def _plan_request(a: argparse.Namespace) -> PlanRequest:
    if a.coast is not None or a.tol is not None:
        raise UsageError("--coast and --tol are the planner node's settings "
                         "(ff-ctl param get ff_planner coast / tol), not part of a request")
    try:
        return plan_cli.make_request(a)
    except plan_cli.UsageError as exc:
        raise UsageError(str(exc)) from None


def _plan(s: Session, a: argparse.Namespace, request: PlanRequest) -> tuple[Any, int]:
    """Call the planner service; print the answer; (response, exit code)."""
    t0 = time.monotonic()
    a.plan_service = _node_name(a.plan_service, a.namespace)
    resp = s.call(PlanTrajectory, a.plan_service, request_to_msg(request), timeout=a.plan_timeout)
    wall = time.monotonic() - t0
    result = response_to_result(resp, request)
    if a.output and result.profile is not None:
        from ff_planner.export.motion_file import write_motion

        write_motion(a.output, result, extra={"planned_by": a.plan_service})
    if a.plot and result.profile is not None:
        from ff_planner.export.plotting import plot_motion

        plot_motion(result.params or request.resolved_params(), result.profile, list(request.q0),
                    list(request.qf), result.uncertain, a.plot,
                    title=f"{result.objective} via {a.plan_service}: {list(request.q0)} -> {list(request.qf)} rad")
    code = 0 if resp.success else 2 if result.error_code in BAD_INPUT else 1
    if a.json:
        d = plan_cli.summary(result, a.output if result.profile is not None else None,
                             a.plot if result.profile is not None else None)
        d["call_time_s"] = wall
        print(json.dumps(d))
        return resp, code
    state = ("robust plan" if resp.robust else "plan" if resp.success
             else f"no plan [{result.error_code}]" if result.profile is None
             else f"BEST-EFFORT plan [{result.error_code}]")
    print(f"{PROG}: {request.objective}: {state} — {resp.message}")
    if result.profile is not None:
        print(f"  steps: {result.profile.n_steps}, currents (A): "
              f"{np.round(result.profile.currents, 4).tolist()}, step times (s): "
              f"{np.round(result.profile.step_times, 4).tolist()}")
        print(f"  q(tf) = {_fmt(resp.q_final, 6)} rad, qd(tf) = {_fmt(resp.qd_final, 6)} rad/s")
        if resp.sensitivity_names:
            print("  dq(tf)/dp: " + ", ".join(f"{k} {v:+.2e}" for k, v in
                                              list(zip(resp.sensitivity_names, resp.sensitivity_values))[:8]))
        _print_certificate(result)
    print(f"  {'warm start, ' if resp.warm_start else ''}{resp.starts_tried} starts, solve "
          f"{resp.solve_time * 1e3:.1f} ms, call {wall * 1e3:.0f} ms")
    for what, path in (("motion file", a.output), ("plot", a.plot)):
        if path and result.profile is not None:
            print(f"  wrote {what} {path}")
    return resp, code


def _print_certificate(result: Any) -> None:
    """The certificate the service sent: worst rest error over the box and the excursion."""
    c = result.certificate
    if c is None:
        return
    box = ", ".join(f"{k} ±{v * 100:g} %" for k, v in c.box.items())
    print(f"  box ({box}): worst rest error {c.worst_rest_error * 1e3:.3g} mrad "
          f"({c.samples} points), moving at tf: {c.moving_at_tf * 100:.0f} % of the box")
    ex = c.excursion
    if ex is not None:
        print(f"  excursion until rest (per joint): nominal {_fmt(ex.nominal_min, 4)} … "
              f"{_fmt(ex.nominal_max, 4)} rad, peak speed {_fmt(ex.nominal_speed, 4)} rad/s; over "
              f"the box {_fmt(ex.worst_min, 4)} … {_fmt(ex.worst_max, 4)} rad, peak speed "
              f"{_fmt(ex.worst_speed, 4)} rad/s")


def plan(s: Session, a: argparse.Namespace) -> int:
    """Plan through the planner node (same options as ff-plan)."""
    return _plan(s, a, _plan_request(a))[1]


def _file_rest(motion: Any) -> Optional[np.ndarray]:
    """Where the motion file's model says the arm comes to rest (rad per joint), None if unknown."""
    try:
        rest = rest_position(motion.params, motion.profile, motion.q0)
    except (ParameterError, ValueError):
        return None
    return rest if np.all(np.isfinite(rest)) else None


def execute(s: Session, a: argparse.Namespace) -> int:
    """Send a motion file (or a fresh plan) to the executor action; live feedback; the result."""
    if a.motion is not None:
        given = [k for k in _PLAN_OPTIONS if getattr(a, k, None) not in (None, [])] + (["set"] if a.set else [])
        if given:
            raise UsageError(f"give a motion file or plan options, not both (got {', '.join(given)})")
        try:
            motion = read_motion(a.motion)
        except MotionFileError as exc:
            raise UsageError(str(exc)) from None
        msg = profile_to_msg(motion.profile, motion.model, motion.q0, motion.qf, a.joint_names,
                             predicted_rest=_file_rest(motion))
        print(f"{PROG}: {a.motion}: {motion.model} {_fmt(motion.q0)} -> {_fmt(motion.qf)} rad in "
              f"{motion.tf:g} s, {motion.profile.n_steps} steps")
    else:
        resp, code = _plan(s, a, _plan_request(a))
        if resp.profile.n_steps == 0 or (not resp.success and not a.best_effort):
            print(f"{PROG}: not executing: the planner gave no plan that meets its tolerances"
                  + ("" if resp.profile.n_steps == 0 else " (--best-effort runs it anyway)"), file=sys.stderr)
            return code or 1
        msg = resp.profile
        if a.joint_names:
            msg.joint_names = list(a.joint_names)
    return _send_goal(s, a, msg)


#: the /diagnostics statuses that speak of the drives: the bridge's and the simulated drives'
DRIVE_STATUSES = ("ff_hwbridge:", "ff_sim_driver:")


def _number_value(st: Any, key: str) -> Optional[float]:
    """A numeric key/value of a diagnostic status, None when absent or not a number."""
    for kv in st.values:
        if kv.key == key:
            try:
                return float(kv.value)
            except ValueError:
                return None
    return None


def late_switches(statuses: Sequence[Any]) -> tuple[int, float]:
    """The simulated arm's current changes that started late (the simulator's ``late_switches``,
    summed over its drives) and the worst lateness (``late_switch_max_us``, µs); (0, 0) without a
    simulator."""
    count, worst = 0, 0.0
    for st in statuses:
        n = _number_value(st, "late_switches")
        if n is not None:
            count += int(n)
            worst = max(worst, _number_value(st, "late_switch_max_us") or 0.0)
    return count, worst


def bridge_notes(before: Optional[Any], after: Optional[Any], node: str = "/ff_hwbridge") -> list[str]:
    """What the bridge's typed status (ff_msgs/msg/DriveGroupStatus) says about a move, from the
    one before and the one after it: a latched safe state and its reason, commands refused as not
    the owner's (e.g. a client claimed the drive, so the executor's setpoints were refused)."""
    if after is None:
        return []
    notes = []
    if after.state == DriveGroupStatus.SAFE_STATE:
        notes.append(f"{node}: safe state: {after.latch_reason}")
    refused = int(after.refused) - (int(before.refused) if before is not None else 0)
    if refused > 0:
        notes.append(f"{node} refused {refused} command(s) that were not its owner's during the move "
                     f"(owner {after.owner or 'none'}; latest: {after.last_refusal})")
    return notes


def timing_notes(before: Sequence[Any], after: Sequence[Any], bridge_before: Optional[Any] = None,
                 bridge_after: Optional[Any] = None) -> list[str]:
    """What /diagnostics say about a move, from the statuses seen before and after it: a latched
    safe state (level ERROR) and current changes the simulated arm started late. With the bridge's
    typed status (``bridge_after``), the bridge's part comes from it (:func:`bridge_notes`)."""
    typed = bridge_after is not None
    notes = bridge_notes(bridge_before, bridge_after)
    notes += [f"{st.name}: {st.message}" for st in after
              if (st.level if isinstance(st.level, int) else int.from_bytes(st.level, "little")) >= 2
              and not (typed and st.name.startswith(DRIVE_STATUSES[0]))]
    (n0, _w0), (n1, w1) = late_switches(before), late_switches(after)
    if n1 > n0:
        notes.append(f"the simulated arm started {n1 - n0} current change(s) late during the move (the "
                     f"worst so far {w1 / 1e3:.1f} ms): the simulator handled their CAN frames after its "
                     "plant's lag (a loaded machine), so the rest error comes from the simulation, not "
                     "from the plan or the bridge")
    return notes


class _DiagWatch:
    """The latest /diagnostics status per name and when it came (monotonic s), and the latest typed
    status of the bridge (``bridge_status``), kept in the background."""

    def __init__(self, s: Session, topic: str = "/diagnostics", bridge: str = "/ff_hwbridge") -> None:
        self._lock = threading.Lock()
        self.latest: dict[str, tuple[float, Any]] = {}
        self.bridge_status: Optional[Any] = None
        s.node.create_subscription(DiagnosticArray, topic, self._on_msg, 50)
        s.node.create_subscription(DriveGroupStatus, f"{bridge}/status", self._on_status, 10)

    def _on_status(self, msg: Any) -> None:
        with self._lock:
            self.bridge_status = msg

    def _on_msg(self, msg: DiagnosticArray) -> None:
        now = time.monotonic()
        with self._lock:
            for st in msg.status:
                self.latest[st.name] = (now, st)

    def statuses(self) -> list[Any]:
        with self._lock:
            return [st for _t, st in self.latest.values()]

    def fresh_after(self, t: float, timeout: float) -> list[Any]:
        """The statuses once the drives' (the bridge's and the simulator's) seen so far have been
        updated after ``t`` (at most ``timeout`` s)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._lock:
                drives = [seen for name, (seen, _st) in self.latest.items() if name.startswith(DRIVE_STATUSES)]
                if drives and all(seen > t for seen in drives):
                    break
            time.sleep(0.05)
        return self.statuses()


def _send_goal(s: Session, a: argparse.Namespace, profile_msg: Any) -> int:
    watch = _DiagWatch(s, bridge=_node_name("ff_hwbridge", a.namespace))
    a.action_name = _node_name(a.action_name, a.namespace)
    client = SafeActionClient(s.node, ExecuteProfile, a.action_name)
    if not client.wait_for_server(timeout_sec=a.timeout):
        raise CallFailed(f"the executor action {a.action_name} is not available "
                         f"(ROS_DOMAIN_ID={s.domain_id})")
    last = [0.0]

    def on_feedback(m: Any) -> None:
        fb, now = m.feedback, time.monotonic()
        if now - last[0] < 1.0 / a.feedback_hz:
            return
        last[0] = now
        print(f"  t = {fb.elapsed:6.3f} s   I = {_fmt(fb.commanded_currents, 3)} A   "
              f"q = {_fmt(fb.measured_positions)} rad   qd = {_fmt(fb.measured_velocities)} rad/s", flush=True)

    tf = float(profile_msg.move_time)
    before, bridge_before = watch.statuses(), watch.bridge_status
    handle = s.wait(client.send_goal_async(ExecuteProfile.Goal(profile=profile_msg), feedback_callback=on_feedback),
                    a.timeout, "send goal")
    if not handle.accepted:
        raise CallFailed("the executor rejected the goal (refuse_mode 'reject': its log says why)")
    future = handle.get_result_async()
    try:
        res = s.wait(future, tf + a.timeout + 60.0, "execute")
    except KeyboardInterrupt:
        print(f"{PROG}: cancelling (zero current)", file=sys.stderr, flush=True)
        s.wait(handle.cancel_goal_async(), a.timeout, "cancel")
        res = s.wait(future, a.timeout, "result after cancel")
        _print_result(res)
        return 130
    _print_result(res)
    after = watch.fresh_after(time.monotonic(), timeout=2.5)
    for note in timing_notes(before, after, bridge_before, watch.bridge_status):
        print(f"  diagnostics: {note}")
    if not (res.status == GoalStatus.STATUS_SUCCEEDED and res.result.success):
        return 1
    err = max((abs(e) for e in res.result.position_error), default=math.inf)
    if a.land_tolerance > 0 and not err <= a.land_tolerance:
        print(f"{PROG}: the arm settled {err:.4g} rad from the goal, beyond --tolerance {a.land_tolerance:g} rad "
              "(ff-ctl diag: is the bridge in a safe state?)", file=sys.stderr)
        return 1
    return 0


def _print_result(res: Any) -> None:
    r = res.result
    status = {GoalStatus.STATUS_SUCCEEDED: "succeeded", GoalStatus.STATUS_ABORTED: "aborted",
              GoalStatus.STATUS_CANCELED: "cancelled"}.get(res.status, f"status {res.status}")
    print(f"{PROG}: execute {status}: {r.message}")
    if len(r.final_position):
        print(f"  final position {_fmt(r.final_position, 6)} rad, velocity {_fmt(r.final_velocity, 6)} rad/s, "
              f"error {_fmt(r.position_error, 6)} rad")
    if r.setpoints_sent:
        print(f"  {r.setpoints_sent} setpoints, start delay {r.start_delay * 1e3:.0f} ms, switch timing "
              f"|applied - stamp| p50 {r.switch_error_p50 * 1e6:.0f} us, p99 {r.switch_error_p99 * 1e6:.0f} us, "
              f"max {r.switch_error_max * 1e6:.0f} us")
        sync = (f"SYNC {r.sync_period * 1e3:g} ms, {r.missed_cycles} setpoint(s) missed their cycle"
                if r.sync_period > 0 else "setpoints applied on receipt (no SYNC latching)")
        print(f"  {sync}")
    print("  " + predicted_vs_measured(list(r.predicted_position), list(r.final_position)))


def predicted_vs_measured(predicted: list[float], measured: list[float]) -> str:
    """One line: the model's rest position for the profile beside the measured one (rad)."""
    if not predicted:
        return "model's predicted rest position: unknown (the profile carries none)"
    if len(measured) != len(predicted):
        return f"model's predicted rest position {_fmt(predicted, 6)} rad; measured: none"
    diff = [m - p for m, p in zip(measured, predicted)]
    return (f"predicted rest {_fmt(predicted, 6)} rad, measured {_fmt(measured, 6)} rad, "
            f"measured - predicted {_fmt([d * 1e3 for d in diff], 3)} mrad")


# --- the command line -------------------------------------------------------------------------
def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--domain-id", type=int, default=None,
                   help="ROS domain (default: ROS_DOMAIN_ID, else 0)")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S",
                   help="s to wait for a service or action server (default 10)")
    p.add_argument("--namespace", "-n", default="", metavar="NS",
                   help="the stack's namespace: relative node, topic and service names are under it "
                        "(e.g. arm_a: ff_hwbridge -> /arm_a/ff_hwbridge)")


def _plan_parent(tolerance_search: bool = True) -> Any:
    """ff-plan's parser: its options become those of ``plan`` and ``execute`` (execute: without
    --tolerance / --tf-max, its --tolerance is the landing check; plan with --tolerance first)."""
    return plan_cli.build_parser(tolerance_search=tolerance_search, tradeoff=False)


def _add_plan_target(p: argparse.ArgumentParser) -> None:
    p.add_argument("--plan-service", default="ff_planner/plan",
                   help="the planner service (relative: under --namespace)")
    p.add_argument("--plan-timeout", type=float, default=120.0, metavar="S",
                   help="s to wait for the plan (default 120)")


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog=PROG, description=__doc__.splitlines()[0].replace("``", ""),
                 formatter_class=argparse.RawDescriptionHelpFormatter,
                 epilog="\n".join(__doc__.splitlines()[2:]))
    sub = ap.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    g = sub.add_parser("graph", help="nodes, topics with types, services, actions",
                       description="List the ROS graph of the domain (like ros2 node/topic/service/action list).")
    _add_common(g)
    g.add_argument("--wait", type=float, default=5.0, metavar="S",
                   help="discovery: wait until the graph is steady for 1.5 s, at most S s (default 5)")
    g.add_argument("--expect", nargs="+", default=[], metavar="NODE",
                   help="keep waiting (up to --wait) until these nodes are discovered, e.g. ff_hwbridge")
    g.add_argument("--all", action="store_true", help="also hidden nodes, action internals, parameter services")
    g.add_argument("--json", action="store_true", help="print JSON")
    g.set_defaults(func=graph)

    lc = sub.add_parser("lifecycle", help="get or set a lifecycle node's state (the bridge is one)",
                        description="ff-ctl lifecycle get NODE | ff-ctl lifecycle set NODE TRANSITION_OR_STATE "
                                    "(transitions: configure, activate, deactivate, cleanup, shutdown; or the "
                                    "goal state: inactive, active, unconfigured, finalized)")
    _add_common(lc)
    lc.add_argument("action", choices=("get", "set"))
    lc.add_argument("node", help="node name, e.g. ff_hwbridge")
    lc.add_argument("state", nargs="?", help="for set: transition label or goal state")
    lc.add_argument("-v", "--verbose", action="store_true", help="get: also the available transitions")
    lc.set_defaults(func=lifecycle)

    fr = sub.add_parser("fault-reset", help="clear the bridge's latched safe state (~/fault_reset)",
                        description="Call NODE/fault_reset (std_srvs/Trigger; refused while a client holds "
                                    "the drive), or with --token the owner's NODE/owner_command FAULT_RESET; "
                                    "the reason is in ff-ctl status / diag.")
    _add_common(fr)
    fr.add_argument("node", nargs="?", default="ff_hwbridge", help="the bridge node (default ff_hwbridge)")
    fr.add_argument("--token", default="", help="the claim's token (ff-ctl claim): reset as the owner")
    fr.set_defaults(func=fault_reset)

    cl = sub.add_parser("claim", help="claim the bridge's drive: only the owner's commands move the arm",
                        description="ff-ctl claim [NODE] [--lease S] [--client NAME]: claim and print the "
                                    "token (the claim expires after its lease unless renewed); --hold: "
                                    "keep it, renewed, until Ctrl-C, then release it; --renew --token T.")
    _add_common(cl)
    cl.add_argument("node", nargs="?", default="ff_hwbridge", help="the bridge node (default ff_hwbridge)")
    cl.add_argument("--lease", type=float, default=0.0, metavar="S",
                    help="s the claim lasts without renewal (default: the bridge's claim_lease)")
    cl.add_argument("--client", default="", metavar="NODE",
                    help="the owner's node name shown in the status (default: this tool's node)")
    cl.add_argument("--hold", action="store_true", help="hold the drive until Ctrl-C, then release it")
    cl.add_argument("--renew", action="store_true", help="renew the claim of --token")
    cl.add_argument("--token", default="", help="for --renew: the claim's token")
    cl.set_defaults(func=claim)

    rl = sub.add_parser("release", help="release a claim on the bridge's drive",
                        description="ff-ctl release [NODE] --token T")
    _add_common(rl)
    rl.add_argument("node", nargs="?", default="ff_hwbridge", help="the bridge node (default ff_hwbridge)")
    rl.add_argument("--token", required=True, help="the claim's token")
    rl.set_defaults(func=release)

    en = sub.add_parser("enable", help="the owner enables the drives (lifecycle activate)",
                        description="ff-ctl enable [NODE] --token T: NODE/owner_command ENABLE.")
    _add_common(en)
    en.add_argument("node", nargs="?", default="ff_hwbridge", help="the bridge node (default ff_hwbridge)")
    en.add_argument("--token", required=True, help="the claim's token")
    en.set_defaults(func=enable)

    st = sub.add_parser("status", help="the bridge's typed status: state, why not active, owner",
                        description="Print NODE/status (ff_msgs/msg/DriveGroupStatus): state, a failed "
                                    "configure's reason, the safe state's reason, drives, owner, refusals. "
                                    "Exit 0 when active, else 1.")
    _add_common(st)
    st.add_argument("node", nargs="?", default="ff_hwbridge", help="the bridge node (default ff_hwbridge)")
    st.set_defaults(func=status)

    ec = sub.add_parser("echo", help="print a topic's messages as YAML (like ros2 topic echo)",
                        description="ff-ctl echo TOPIC [--count N]: the messages of TOPIC as YAML documents "
                                    "(its type from discovery); until Ctrl-C, or N messages.")
    _add_common(ec)
    ec.add_argument("topic", help="e.g. /ff_hwbridge/status (relative: under --namespace)")
    ec.add_argument("--count", type=int, default=0, metavar="N",
                    help="stop after N messages (exit 1 if none within --timeout); 0 = until Ctrl-C")
    ec.set_defaults(func=echo)

    ca = sub.add_parser("call", help="call a service with a YAML request (like ros2 service call)",
                        description="ff-ctl call SERVICE ['{field: value, ...}'] [options]: the request as YAML "
                                    "(nested mappings for nested messages; its type from discovery); "
                                    "prints the response as YAML.")
    _add_common(ca)
    ca.add_argument("service", help="e.g. /ff_hwbridge/claim (relative: under --namespace)")
    ca.add_argument("request", nargs="?", default="", help="YAML mapping of the request's fields (default: {})")
    ca.set_defaults(func=call_service)

    d = sub.add_parser("diag", help="formatted /diagnostics",
                       description="Print the latest report of each diagnostic status, or follow them.")
    _add_common(d)
    d.add_argument("--follow", "-f", action="store_true", help="print every status as it comes, until Ctrl-C")
    d.add_argument("--duration", type=float, default=3.0, metavar="S", help="s to listen (default 3)")
    d.add_argument("--brief", action="store_true", help="no key/value pairs")
    d.add_argument("--topic", default="/diagnostics")
    d.set_defaults(func=diag)

    pa = sub.add_parser("param", help="list / get / describe / set a node's parameters",
                        description="ff-ctl param list NODE | get NODE NAME | describe NODE NAME | "
                                    "set NODE NAME VALUE (VALUE as YAML: 0.2, true, [1.0, 2.0], text)")
    _add_common(pa)
    pa.add_argument("action", choices=("list", "get", "describe", "set"))
    pa.add_argument("node")
    pa.add_argument("name", nargs="?")
    pa.add_argument("value", nargs="?")
    pa.set_defaults(func=param)

    pl = sub.add_parser("plan", parents=[_plan_parent()], add_help=False,
                        formatter_class=argparse.RawDescriptionHelpFormatter,
                        help="plan through the planner service (ff-plan's options)",
                        description="Call /ff_planner/plan with ff-plan's options and print the answer; "
                                    "-o writes an ff-motion/1 file for 'ff-ctl execute'. --coast and --tol "
                                    "are the planner node's parameters.")
    _add_common(pl)
    _add_plan_target(pl)
    pl.set_defaults(func=plan)

    ex = sub.add_parser("execute", parents=[_plan_parent(tolerance_search=False)], add_help=False,
                        formatter_class=argparse.RawDescriptionHelpFormatter,
                        help="send a motion file (or a fresh plan) to the executor; live feedback",
                        description="ff-ctl execute MOTION.json | ff-ctl execute [ff-plan options]. The arm must "
                                    "be at rest at the motion's q0 (executor parameter start_tolerance, rad).")
    _add_common(ex)
    _add_plan_target(ex)
    ex.add_argument("motion", nargs="?", help="ff-motion/1 file (ff-plan -o / ff-ctl plan -o)")
    ex.add_argument("--action-name", default="ff_executor/execute",
                    help="the executor action (relative: under --namespace)")
    ex.add_argument("--joint-names", nargs="+", default=None, metavar="NAME",
                    help="joint names of the profile (default joint1..N, as the executor's config)")
    ex.add_argument("--feedback-hz", type=float, default=10.0, help="feedback lines per second at most")
    ex.add_argument("--best-effort", action="store_true", help="run a plan that misses its tolerances too")
    ex.add_argument("--tolerance", type=float, default=0.05, metavar="RAD", dest="land_tolerance",
                    help="exit 1 if the arm settles farther than this from the goal (default 0.05; 0 = off)")
    ex.set_defaults(func=execute)

    rec = sub.add_parser("record", help="record topics into a rosbag2 folder (MCAP) = ff-record",
                         description="Record the suite's topics into a rosbag2 folder with MCAP storage.")
    _add_common(rec)
    add_record_arguments(rec)
    rec.set_defaults(func=lambda s, a: run_record(s, a, prog=f"{PROG} record"))
    return ap


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Console script ``ff-ctl``; returns the exit code (module docstring)."""
    args_in = list(sys.argv[1:] if argv is None else argv)
    try:
        a = build_parser().parse_args(args_in)
        if a.command == "lifecycle" and a.action == "set" and not a.state:
            raise UsageError("lifecycle set needs NODE and a transition or state")
        if a.command == "param" and a.action != "list" and not a.name:
            raise UsageError(f"param {a.action} needs NODE NAME")
        if a.command == "execute" and a.motion is None and not any(
                getattr(a, k, None) not in (None, []) for k in _PLAN_OPTIONS):
            raise UsageError("execute needs a motion file or plan options (e.g. --qf 1 --tf 1)")
        if getattr(a, "timeout", 1.0) <= 0 or not math.isfinite(getattr(a, "timeout", 1.0)):
            raise UsageError("--timeout must be > 0 s")
        with Session(a.domain_id) as s:
            return int(a.func(s, a))
    except SystemExit as exc:   # --help
        return int(exc.code or 0)
    except (UsageError, ParameterError, PlanningError, ValueError) as exc:   # ValueError: e.g. ROS_DOMAIN_ID
        return _fail(f"error: {exc}", 2)
    except CallFailed as exc:
        return _fail(str(exc), 1)
    except ModuleNotFoundError as exc:
        return _fail(missing_extra(exc), 1)
    except KeyboardInterrupt:
        return _fail("interrupted", 130)
    except Exception as exc:  # never a traceback for the user unless asked
        if "--debug" in args_in:
            raise
        return _fail(f"internal error: {type(exc).__name__}: {exc} (rerun with --debug)", 1)


def _fail(text: str, code: int) -> int:
    """Print one line on stderr; return the exit code."""
    print(f"{PROG}: {' '.join(text.split())}", file=sys.stderr)
    return code

if __name__ == "__main__":
    sys.exit(main())
