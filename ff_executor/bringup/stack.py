"""``ff-bringup``: start the simulated stack — sim driver, bridge, planner, executor — as processes.

    ff-bringup                              # table 2 arm, true friction = the planner's model
    ff-bringup --true-scale pc=1.2          # the simulated arm's Coulomb friction 20 % higher
    ff-bringup --true-param pc=0.25 --no-planner --hub-port 54701
    ff-bringup --print-config               # the effective configuration, nothing started
    ff-bringup --bridge-config config/bridge_epos4_1dof.yaml   # the shipped robot config, bus on the hub
    ff-bringup --record run_bag             # also record the topics (ff-record, rosbag2/MCAP)
    ff-bringup --namespace arm_a            # every node under /arm_a (a second arm: --namespace arm_b)
    ff-bringup --cell config/arms/arm3h.cell.yaml   # an arm from a URDF: one simulated EPOS4 per joint

Safe defaults, always: ROS traffic on loopback only (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``),
the CAN hub on 127.0.0.1 in its own process (it also produces SYNC). The domain: ``--domain-id``, else
``ROS_DOMAIN_ID`` when set, else a free one per run; ROS logs: ``ROS_LOG_DIR`` when set, else the run
folder (``ff_msgs_py.launch.ros_environment``). Start order and readiness (each waits for the
previous one, checked in the ROS graph, not by sleeping):

0. ``ff_can_hub`` (ff_hwbridge.cli.can_hub --sync-period 0.01) → "CAN hub on" (no ROS);
1. ``ff_sim_driver`` (ff_hwbridge.ros.sim_driver_node) on the hub → service ``~/reset``;
2. ``ff_hwbridge`` (ff_hwbridge.ros.bridge_node --autostart) on the hub → lifecycle state *active*;
3. ``ff_planner`` (ff_planner.ros.planner_node) → service ``~/plan`` (its motion library in the run folder);
4. ``ff_executor`` (ff_executor.ros.executor_node) → action ``~/execute``.

Stopping (Ctrl-C, SIGTERM, or any child dying): every child gets SIGINT, then SIGTERM, then
SIGKILL, by PID, in reverse start order — the executor first, so a running move ends with a zero
current. The :class:`Stack` class does the same for the demo, tests and benchmarks.

Timing (the end nearest the bus decides when a current switches; 1 ms ≈ 0.04 rad at 10 A): the sim
driver, the bridge and the executor run through ``ff_executor.bringup.timed`` (0.1 ms GIL switch
interval) at nice −10 where permitted; ``--rt-priority N`` puts the simulated drive under
SCHED_FIFO N and asks the bridge for a SCHED_FIFO scheduler thread (root / CAP_SYS_NICE; off by
default here, the demo, tests and benchmarks use 10 where permitted).

Configuration (``--print-config`` shows every value): the executor reads ``config/executor.yaml``
then ``config/executor_sim.yaml`` (lead time 0.8 s, start margin 1.0 s for a shared machine), the
planner ``config/planner.yaml`` (its motion library moved into the run folder); the simulated
drive's encoder resolution and nominal current come from ``config/sim_arm1dof.yaml``. Generated
for each run in the run folder: the sim driver's and bridge's parameter files and the bridge
config (remote bus on the hub). Its timing differs from ``config/bridge_*.yaml`` (1 ms SYNC, 10 ms
heartbeats, 40-100 ms timeouts: for a real bus on a dedicated machine) on purpose: 10 ms SYNC,
produced by the CAN hub's own timer (the hub runs in its own process; the drives latch each
setpoint at a SYNC, the planner's switch grid is the SYNC period; ``--setpoint-timing on_receipt``
applies setpoints when they arrive instead, with the bridge producing SYNC), 50 ms drive heartbeats with a
3 s timeout on both sides and 3 s for the executor's joint-state watchdog (above the scheduling
gaps of a normal-priority process on a loaded shared machine, measured up to 1.4 s). A bridge
that does not come up stops the start with its own reason (``configure failed: ...`` or
``activate failed: drives did not reach Operation enabled (states ...; fault ...)``); it is not
started again (its drives, armed against its heartbeat, would be in Fault 0x8130).

``--namespace NS`` starts every node under ``/NS`` (``/NS/ff_executor``, ``/NS/ff_hwbridge``, ...)
with its own CAN hub, so two stacks share one ROS domain: their parameters come from the same
shipped files, merged and written for the namespaced node names; the executor's topics are the
bridge's inside NS, and its ``bridge_node`` (relative) finds the bridge there. Talk to it with
``ff-ctl --namespace NS``. ``--record`` is refused with it (ff-record records the root names).

``--bridge-config FILE`` runs a robot's bridge file instead, as it is, with only its ``bus``
section replaced by the hub (``remote``, ws://127.0.0.1:PORT/): for the shipped
``config/bridge_epos4_1dof.yaml`` the player in the bridge's process, SYNC every 10 ms from a
timer outside the bridge's process (on SocketCAN the kernel's, here the hub's), 10 ms drive
heartbeats, the derived 130 ms timeouts. The simulated
drives take the file's family, nominal current and encoder resolution; a file whose joints
(node ids 1..n) or motor data (torque constant, gear ratio) are not the simulated arm's is
refused with the key to change, before anything starts.

``--cell FILE [--urdf FILE]`` (as ``ff-plan --cell``; the URDF defaults to the one the cell names)
simulates an arm from a URDF instead of ``--model``: one simulated EPOS4 per moving joint on the
hub, node ids from the cell (``node_id``, else 1..n), the plant the planner's n-joint model
(``ff_hwbridge.sim.urdf_plant``) with the cell's Eq. 9 friction per joint (``--true-scale
pc2=1.2`` / ``--true-param pc2=0.15``: keys pv1, pc1, pt1, pv2, ... for joint 1 = the first moving
joint). The bridge's joints are the URDF's moving joints, named as there, with the cell's motor
data, current limits and position/velocity limits (outside them: the bridge's safe state); the
executor takes those joint names; the planner serves the arm as ``urdf:NAME`` (NAME from the cell).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import signal
import socket
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import rclpy
import yaml
from lifecycle_msgs.srv import GetState
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from ff_msgs_py.configs import config_dir
from ff_msgs_py.launch import NodeProcess, apply_ros_environment, ros_environment, start_module
from ff_planner.model.params import ParameterError, default_params
from ff_planner.model.registry import MODELS, model_spec

REPO = Path(__file__).resolve().parents[2]
CONFIG_DIR = config_dir()


def config_parameters(name: str, node: str) -> dict:
    """``ros__parameters`` of ``node`` in ``config/<name>`` ({} if the file or node is missing)."""
    try:
        data = yaml.safe_load((CONFIG_DIR / name).read_text()) or {}
    except (OSError, yaml.YAMLError):
        return {}
    return dict(((data.get(node) or {}).get("ros__parameters") or {}))


_SIM = config_parameters("sim_arm1dof.yaml", "ff_sim_driver")
# From config/sim_arm1dof.yaml (the simulated drive; the bridge gets the same numbers):
COUNTS_PER_REV = int(_SIM.get("counts_per_rev", 2048))        # encoder increments per motor revolution
NOMINAL_CURRENT = float(_SIM.get("nominal_current", 3.0))     # A, motor nominal current (EPOS4 per mille)
# Deliberately more lenient than config/bridge_*.yaml (1 ms SYNC, 10 ms heartbeat with a 40-100 ms
# timeout, for a real bus on a dedicated machine): the simulated stack shares a possibly busy
# machine (1 ms SYNC costs ~1.25 of the 2 cores across the hub, drive and bridge). Switch times sit on
# this grid (the planner's switch_grid), so it costs no accuracy.
SYNC_PERIOD = 0.01         # s
HEARTBEAT_PRODUCER_MS = 50  # ms, the drives' heartbeat
# Watchdog timeouts above the longest scheduling gap measured here for a normal-priority process
# on the loaded 2-core machine (a 1 ms sleep loop woke up to 1.4 s late at load average 6-8, while
# a SCHED_FIFO one never missed by 0.1 s; docs/timing.md): 1 s tripped there.
HEARTBEAT_TIMEOUT = 3.0    # s, the bridge's timeout on the drives' heartbeat; the drives' on the
MASTER_HEARTBEAT_TIMEOUT_MS = 3000   # bridge's (100 ms) heartbeat: 3 s too
JOINT_STATE_TIMEOUT = 3.0  # s, the executor stops a move whose joint states stop this long
EXECUTOR_FILES = ("executor.yaml", "executor_sim.yaml")   # config/ files layered for the executor


class BringupError(RuntimeError):
    """The stack could not be started; the message names the process and shows its last output."""


@dataclass
class StackOptions:
    """How to start the simulated stack. Friction: SI units; ``true_scale`` multiplies the model's."""

    model: str = "arm1dof"
    true_scale: Mapping[str, float] = field(default_factory=dict)   # e.g. {"pc": 1.2}
    true_params: Mapping[str, float] = field(default_factory=dict)  # absolute, e.g. {"pc": 0.25}
    planner: bool = True
    executor: bool = True
    hub_port: int = 0                          # 0 = a free port on 127.0.0.1
    namespace: str = ""                        # ROS namespace of every node ("arm_a"); "" = root
    domain_id: Optional[int] = None            # None = random per run
    run_dir: Optional[str] = None              # logs, generated parameter files, motion library
    log_dir: Optional[str] = None              # ROS_LOG_DIR; None = <run_dir>/ros-log
    executor_params: Optional[str] = None      # default config/executor.yaml + executor_sim.yaml
                                               # (lead time 0.8 s, start margin 1.0 s) + the model's joints
    planner_params: Optional[str] = None       # default config/planner.yaml
    executor_overrides: Mapping[str, object] = field(default_factory=dict)
    planner_overrides: Mapping[str, object] = field(default_factory=dict)
    sim_overrides: Mapping[str, object] = field(default_factory=dict)
    bridge_overrides: Mapping[str, object] = field(default_factory=dict)
    start_timeout: float = 90.0                # s per process (first start may JIT-compile)
    q0: Sequence[float] = ()                   # rad, initial arm position (default zeros)
    switch_interval: Optional[float] = 1e-4    # s, GIL switch interval of the sim driver and the
                                               # bridge (ff_executor.bringup.timed); None = Python's 5 ms
    separate_hub: bool = True                  # CAN hub in its own process (else the sim driver hosts it)
    setpoint_timing: str = "sync"              # "sync": the drives latch setpoints at SYNC, produced by
                                               # the hub's timer (separate hub) every SYNC_PERIOD;
                                               # "on_receipt": applied when they arrive, at their stamps
    sync_jitter_model_us: float = 0.0          # µs: the hub's SYNC bus instant is its timer deadline
                                               # plus a jitter drawn uniformly in [0, this] (0: ideal)
    player_process: bool = True                # sync: the bridge's setpoint player in a process of
                                               # its own, which no ROS executor (nor its GIL) stalls
    stall_dump: float = 0.1                    # s: the bridge's setpoint cycle away this long while
                                               # setpoints are pending dumps every thread's stack
                                               # to ff_hwbridge.out (0 = off)
    rt_priority: int = 0                       # 1..99: SCHED_FIFO for the sim driver process and the
                                               # bridge's scheduler thread (root/CAP_SYS_NICE); 0 = off
    timing_nice: Optional[int] = -10           # nice value for the sim driver and the bridge (the
                                               # timing-critical end); None = leave as is
    record: Optional[str] = None               # bag folder: record the run with ff-record (MCAP)
    joint_envelope: Optional[tuple[float, float, float]] = None   # (q_min rad, q_max rad, v_max rad/s)
                                               # for every joint: outside it the bridge latches its
                                               # safe state (None: no envelope)
    sim_friction: Mapping[str, float] = field(default_factory=dict)   # the simulated arm's friction
                                               # that is not Eq. 9 (1-DOF): stribeck, stribeck_speed,
                                               # coulomb_ripple, coulomb_period (sim driver friction.*)
    bridge_config_file: Optional[str] = None   # a robot's bridge YAML (e.g. the shipped
                                               # config/bridge_epos4_1dof.yaml) run as it is, only its
                                               # bus re-pointed at the hub: its SYNC producer, period,
                                               # player placement, heartbeats and derived timeouts;
                                               # setpoint_timing, player_process,
                                               # stall_dump and rt_priority above then do not apply
                                               # to the bridge (None: the stack's own bridge config)

    cell: Optional[str] = None                 # an arm from a URDF: its cell file (replaces model)
    urdf: Optional[str] = None                 # ... and its URDF (None: the one the cell names)

    def base_params(self) -> Any:
        """The simulated arm's nominal parameters: the model's table, or the cell's friction."""
        if self.cell:
            from ff_hwbridge.sim.urdf_plant import UrdfArmParams
            return UrdfArmParams.of(urdf_arm(self.cell, self.urdf))
        return default_params(self.model)

    @property
    def model_id(self) -> str:
        """The planner's model id of the simulated arm: ``model``, or ``urdf:NAME`` of a cell."""
        return str(self.base_params().model) if self.cell else self.model

    def true_friction(self) -> dict[str, float]:
        """The simulated arm's true parameters that differ from the planner's model."""
        base = self.base_params()
        out: dict[str, float] = {}
        unknown = [k for k in self.true_scale if k not in base.keys()]
        if unknown:
            raise ParameterError(f"unknown parameter(s) {unknown} for model '{self.model}'; "
                                 f"valid keys are: {', '.join(base.keys())}")
        for k, s in self.true_scale.items():
            out[k] = float(getattr(base, k)) * float(s)
        out.update({k: float(v) for k, v in self.true_params.items()})
        base.replace(**out)     # ParameterError on unknown keys or bad values
        return out


def _parameter_value(v: object) -> ParameterValue:
    """A ROS parameter value of a Python bool, int, float or str."""
    if isinstance(v, bool):
        return ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=v)
    if isinstance(v, int):
        return ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=v)
    if isinstance(v, float):
        return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=v)
    return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=str(v))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _params_file(path: Path, node: str, params: Mapping[str, object]) -> Path:
    path.write_text(yaml.safe_dump({node: {"ros__parameters": dict(params)}}, sort_keys=False))
    return path


def merged_parameters(files: Sequence[str], node: str, over: Mapping[str, object]) -> dict:
    """``ros__parameters`` of ``node`` from each file in order, then ``over``."""
    out: dict[str, object] = {}
    for f in files:
        data = yaml.safe_load(Path(f).read_text()) or {}
        out.update((data.get(node) or {}).get("ros__parameters") or {})
    out.update(over)
    return out


def check_namespace(namespace: str) -> str:
    """``"/arm_a"`` for ``"arm_a"`` or ``"/arm_a"`` ("" for ""); ValueError on a name ROS refuses
    (segments of letters, digits and ``_``, not starting with a digit)."""
    ns = namespace.strip().strip("/")
    if not ns:
        return ""
    for seg in ns.split("/"):
        if not seg or not (seg[0].isalpha() or seg[0] == "_") or not all(c.isalnum() or c == "_" for c in seg):
            raise ValueError(f"--namespace {namespace!r}: use letters, digits and _ (not first), "
                             "segments separated by /, e.g. arm_a")
    return "/" + ns


def bridge_config(model: str, hub_url: str) -> dict:
    """The bridge's config (ff_hwbridge.drive.config) for the simulated drives on the hub."""
    p = default_params(model)
    nj = model_spec(model).n_joints
    joints = []
    for j in range(nj):
        sfx = _joint_suffix(nj, j)             # parameter keys: "kt" (1 joint), "kt1", "kt2", ...
        joints.append({"name": f"joint{j + 1}", "node_id": j + 1, "family": "epos4",
                       "current_limit": float(getattr(p, "i_max" + sfx)),
                       "units": {"nominal_current": NOMINAL_CURRENT,
                                 "torque_constant": float(getattr(p, "kt" + sfx)),
                                 "counts_per_rev": COUNTS_PER_REV, "gear_ratio": float(getattr(p, "n" + sfx))}})
    return {"bus": {"interface": "remote", "channel": hub_url, "bitrate": 1_000_000},
            "sync_period": SYNC_PERIOD, "heartbeat_producer_ms": HEARTBEAT_PRODUCER_MS,
            "heartbeat_timeout": HEARTBEAT_TIMEOUT, "master_heartbeat_timeout_ms": MASTER_HEARTBEAT_TIMEOUT_MS,
            "setpoint_timeout": 0.5, "joints": joints}


_ARMS: dict[tuple[str, str], Any] = {}


def urdf_arm(cell: str, urdf: Optional[str] = None) -> Any:
    """The ``ff_planner.arm.model.UrdfArm`` of a cell file (and URDF), loaded once per process;
    ValueError with the cell's own one-line reason (joint and field) when the suite cannot use it."""
    key = (str(Path(cell).resolve()), str(Path(urdf).resolve()) if urdf else "")
    if key not in _ARMS:
        from ff_hwbridge.sim.drive import SimConfigError
        from ff_hwbridge.sim.urdf_plant import load_plant_arm
        try:
            _ARMS[key] = load_plant_arm(cell, urdf)
        except SimConfigError as exc:
            raise ValueError(str(exc)) from None
    return _ARMS[key]


def urdf_bridge_config(arm: Any, hub_url: str) -> dict:
    """The bridge's config for the simulated drives of an arm from a URDF (``urdf_arm``): one
    EPOS4 per moving joint, named as in the URDF, node ids from the cell, its motor data, current
    limit and limits (``position_min``/``max`` rad, ``velocity_max`` rad/s: the bridge's envelope)."""
    from ff_hwbridge.sim.urdf_plant import cell_node_ids

    base = bridge_config("arm1dof", hub_url)
    joints = []
    for jc, nid in zip(arm.cells, cell_node_ids(arm)):
        joint: dict[str, object] = {
            "name": jc.name, "node_id": int(nid), "family": "epos4", "current_limit": float(jc.motor.i_max),
            "units": {"nominal_current": NOMINAL_CURRENT, "torque_constant": float(jc.motor.kt),
                      "counts_per_rev": COUNTS_PER_REV, "gear_ratio": float(jc.motor.gear)}}
        lim = jc.limits
        if "position_min" in lim and "position_max" in lim:
            joint["position_limits"] = [float(lim["position_min"]), float(lim["position_max"])]
        if "velocity_max" in lim:
            joint["velocity_limit"] = float(lim["velocity_max"])
        joints.append(joint)
    base["joints"] = joints
    return base


def _joint_suffix(nj: int, j: int) -> str:
    """Parameter key suffix of joint ``j`` (0-based): "" for one joint ("kt"), else "1", "2"..."""
    return "" if nj == 1 else str(j + 1)


def robot_bridge_config(path: str | Path, model: str, hub_url: str) -> dict:
    """A robot's bridge YAML (``path``) with its ``bus`` section replaced by the simulation's
    hub (python-can ``remote`` on ``hub_url``); everything else as shipped, except where the file
    puts SYNC in the kernel (``interface: socketcan`` with ``sync_producer: master``: the kernel's
    broadcast manager sends it): the hub's timer sends it instead (``sync_producer: external``).

    ValueError naming the key when the file cannot run on the simulated ``model``: it does not
    load as a bridge config, its joints are not the model's (count, node ids 1..n), its drives
    are not one family, or its motor data (units.torque_constant Nm/A, units.gear_ratio) differ
    from the simulated arm's by more than 0.1 % (the simulated drives take nominal current,
    encoder resolution and family from the file)."""
    from ff_hwbridge.drive.config import ConfigError, config_from_mapping

    where = f"bridge config {path}"
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ValueError(f"{where}: cannot read it ({exc.strerror or exc})") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"{where}: not valid YAML ({' '.join(str(exc).split())})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a mapping of bridge settings")
    raw_bus = data.get("bus")
    bus: dict = raw_bus if isinstance(raw_bus, dict) else {}
    data["bus"] = {"interface": "remote", "channel": hub_url,
                   "bitrate": int(bus.get("bitrate", 1_000_000))}
    if str(bus.get("interface", "")) == "socketcan" and data.get("sync_producer", "master") == "master":
        # on SocketCAN the master hands SYNC to the kernel's broadcast manager, whose timer keeps
        # the period whatever the bridge's process does; the hub's timer (SCHED_FIFO, its own
        # process) is that kernel here. The hub's remote bus has no kernel: left to the bridge,
        # SYNC would come from a python-can thread of its process, late whenever it is.
        data["sync_producer"] = "external"
    try:
        cfg = config_from_mapping(data)
    except (ConfigError, ValueError, TypeError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    nj = model_spec(model).n_joints
    cannot = f"{where} cannot run on the simulated {model}"
    ids = [j.node_id for j in cfg.joints]
    if ids != list(range(1, nj + 1)):
        raise ValueError(f"{cannot}: its joints have node ids {ids}; the simulation has "
                         f"{nj} drive(s) with node ids {list(range(1, nj + 1))}")
    families = {j.family for j in cfg.joints}
    nominal = {float(j.units.nominal_current) for j in cfg.joints}
    cpr = {int(j.units.counts_per_rev) for j in cfg.joints}
    if len(families) > 1 or len(nominal) > 1 or len(cpr) > 1:
        raise ValueError(f"{cannot}: the simulated drives share one family, nominal current and "
                         f"encoder resolution; the file has {sorted(families)}, {sorted(nominal)} A, "
                         f"{sorted(cpr)} counts/rev")
    p = default_params(model)
    for j, joint in enumerate(cfg.joints):
        sfx = _joint_suffix(nj, j)
        for key, have, want in (("torque_constant", joint.units.torque_constant, getattr(p, "kt" + sfx)),
                                ("gear_ratio", joint.units.gear_ratio, getattr(p, "n" + sfx))):
            if abs(float(have) - float(want)) > 1e-3 * abs(float(want)):
                raise ValueError(f"{cannot}: {joint.name} units.{key} is {have}, the simulated "
                                 f"arm's is {want} (the model's {'kt' if key == 'torque_constant' else 'n'}"
                                 f"{sfx}); plan and simulate that arm, or fix the file")
    return data


#: ms: a simulated driver that handled CAN frames this late is named in a bridge's failure (an SDO
#: answer or a state change that late misses the bridge's own timeouts)
LATE_DRIVES_MS = 500.0


def bridge_failure(output: str, sim_output: str = "") -> str:
    """Why a bridge did not come up, from its output: its last ``configure failed: ...`` or
    ``activate failed: ...`` log line (for the enable sequence: the drives' states and fault),
    else its last error line, else a note that it logged none; with the simulated driver's last
    report of CAN frames it handled late (``sim_output``) where they were ``LATE_DRIVES_MS`` or
    more late: drives that answer that late cannot be enabled in time."""
    lines = [ln.strip() for ln in output.splitlines() if ln.strip()]
    tags = ("configure failed: ", "activate failed: ")
    tagged = [ln for ln in lines if any(t in ln for t in tags)]
    if tagged:
        why = tagged[-1][min(tagged[-1].index(t) for t in tags if t in tagged[-1]):]
    else:
        errors = [ln for ln in lines if "[ERROR]" in ln or "Error:" in ln or "failed" in ln]
        why = errors[-1] if errors else "it logged no error (its output is below)"
    late = [ln.strip() for ln in sim_output.splitlines() if "handled more than" in ln]
    lag = re.search(r"up to ([0-9.]+) ms", late[-1]) if late else None
    if lag is not None and float(lag.group(1)) >= LATE_DRIVES_MS:
        line, mark = late[-1], "ff_sim_driver]: "
        why += "; the simulated driver: " + (line.split(mark, 1)[1] if mark in line else line)
    return why


class Stack:
    """The four processes of the simulated stack; a context manager (stops everything on exit).

    ``with Stack(StackOptions(true_scale={"pc": 1.2})) as stack: ...`` — ``stack.env`` is the
    ROS environment to use in this process too (apply it before ``rclpy.init``).
    """

    def __init__(self, options: StackOptions | None = None,
                 log: Callable[[str], None] = lambda s: print(s, flush=True)) -> None:
        self.options = options or StackOptions()
        self.log = log
        self.run_dir = Path(self.options.run_dir or tempfile.mkdtemp(prefix="ff-bringup-"))
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.env = ros_environment(self.options.domain_id, self.options.log_dir or str(self.run_dir / "ros-log"))
        self.env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(REPO), self.env.get("PYTHONPATH", "")) if p)
        self.hub_port = self.options.hub_port or free_port()
        self.procs: list[NodeProcess] = []
        self._renice: list[NodeProcess] = []
        self._ctx: Optional[Context] = None
        self._node: Optional[Node] = None
        self._robot: Optional[dict] = None
        self.ns = check_namespace(self.options.namespace)

    def name(self, relative: str) -> str:
        """The fully qualified name of a node, topic or service of the stack (``ff_hwbridge`` ->
        ``/arm_a/ff_hwbridge`` under the namespace arm_a)."""
        return f"{self.ns}/{relative.lstrip('/')}"

    def _node_args(self, node: str, files: Sequence[str], over: Mapping[str, object], path: Path) -> list[str]:
        """``--ros-args`` for ``node``: its parameter files then ``over`` (written to ``path``); under
        a namespace all merged into ``path`` keyed by the namespaced name (a file's plain ``node``
        key matches only the root one), and the namespace remap."""
        if not self.ns:
            args = ["--ros-args"] + [x for f in files for x in ("--params-file", f)]
            if over:
                args += ["--params-file", str(_params_file(path, node, over))]
            return args
        merged = merged_parameters(files, node, over)
        return ["--ros-args", "-r", f"__ns:={self.ns}",
                "--params-file", str(_params_file(path, self.name(node), merged))]

    @property
    def hub_url(self) -> str:
        return f"ws://127.0.0.1:{self.hub_port}/"

    # --- the graph probe (this process's own rclpy context) ----------------------------------
    def _probe(self) -> Node:
        if self._node is None:
            apply_ros_environment(self.env)
            self._ctx = rclpy.Context()
            rclpy.init(context=self._ctx)
            self._node = Node(f"ff_bringup_{os.getpid()}", namespace=self.ns or None, context=self._ctx)
        return self._node

    def has_service(self, name: str) -> bool:
        """True if a service ``name`` (fully qualified) is in the stack's ROS graph."""
        return any(n == name for n, _ in self._probe().get_service_names_and_types())

    def lifecycle_state(self, node_name: str) -> Optional[str]:
        """The lifecycle state label of ``node_name`` (e.g. "active"), None if it does not answer."""
        node = self._probe()
        cli = node.create_client(GetState, f"{self.name(node_name)}/get_state")
        try:
            if not cli.wait_for_service(timeout_sec=0.5):
                return None
            fut = cli.call_async(GetState.Request())
            ex = SingleThreadedExecutor(context=self._ctx)
            ex.add_node(node)
            ex.spin_until_future_complete(fut, timeout_sec=2.0)
            ex.remove_node(node)
            return fut.result().current_state.label if fut.done() and fut.result() else None
        finally:
            node.destroy_client(cli)

    def _wait(self, proc: NodeProcess, ready: Callable[[], bool], what: str) -> None:
        end = time.monotonic() + self.options.start_timeout
        while time.monotonic() < end:
            if not proc.alive():
                raise BringupError(f"{proc.name} exited (code {proc.popen.returncode}) before "
                                   f"{what}; its output:\n{proc.output()[-3000:]}")
            if ready():
                if proc in self._renice:
                    self._apply_nice(proc)
                self.log(f"  {proc.name} up ({what}), pid {proc.pid}")
                return
            time.sleep(0.2)
        raise BringupError(f"{proc.name} did not get to '{what}' within "
                           f"{self.options.start_timeout:.0f} s; its output:\n{proc.output()[-3000:]}")

    # --- start / stop -------------------------------------------------------------------------
    def _start(self, name: str, module: str, args: Sequence[str], timing: bool = False) -> NodeProcess:
        if timing and self.options.switch_interval:
            args = ["--switch-interval", repr(float(self.options.switch_interval)), module, *args]
            module = "ff_executor.bringup.timed"
        proc = start_module(name, module, list(args), self.env, str(self.run_dir))
        self.procs.append(proc)
        if timing and (self.options.timing_nice is not None or self.options.rt_priority):
            self._renice.append(proc)
            self._apply_nice(proc)
        return proc

    def _apply_nice(self, proc: NodeProcess) -> None:
        """Give every thread of ``proc`` the timing nice value (Linux nice is per thread;
        threads inherit it from their creator, so this runs at start and again once up); with
        ``rt_priority`` the simulated driver's threads get SCHED_FIFO instead. The CAN hub keeps
        the SCHED_FIFO it sets itself (SYNC timer 50, forwarding threads 49): at the driver's
        lower priority, a driver thread busy with the plant would hold the SYNC timer off its CPU
        (measured: SYNC frames up to 103 ms late, setpoints missing their cycle)."""
        task_dir = f"/proc/{proc.pid}/task"
        tids = [int(t) for t in os.listdir(task_dir)] if os.path.isdir(task_dir) else [proc.pid]
        rt = int(self.options.rt_priority) if proc.name == "ff_sim_driver" else 0
        nice = self.options.timing_nice
        for tid in tids:
            try:
                if rt:
                    os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(rt))
                    continue
            except PermissionError:
                rt = 0
                self.log(f"  note: SCHED_FIFO not permitted for {proc.name}; using nice instead")
            except OSError:
                continue
            try:
                if nice is not None:
                    os.setpriority(os.PRIO_PROCESS, tid, int(nice))
            except PermissionError as exc:
                self.log(f"  note: cannot raise the priority of {proc.name} ({exc}); its timing "
                         "may suffer on a busy machine")
                self._renice.remove(proc)
                return
            except OSError:
                continue

    # --- what each process gets (start() and --print-config) ---------------------------------
    def sim_parameters(self) -> dict[str, object]:
        """The simulated driver's parameters (written to <run_dir>/sim_driver.yaml)."""
        o = self.options
        base = o.base_params()
        nj = base.n_joints
        sim: dict[str, object] = {
            "model": o.model, "host_hub": not o.separate_hub, "hub_port": self.hub_port,
            "bus.interface": "remote", "bus.channel": self.hub_url, "node_ids": list(range(1, nj + 1)),
            "q0": [float(x) for x in (o.q0 or [0.0] * nj)], "counts_per_rev": COUNTS_PER_REV,
            "nominal_current": NOMINAL_CURRENT, "ground_truth_rate": 100.0,
            "physics_step": base.plant_step}
        if o.cell:      # an arm from a URDF: the cell's node ids and joint names
            from ff_hwbridge.sim.urdf_plant import cell_node_ids
            arm = urdf_arm(o.cell, o.urdf)
            del sim["model"]
            sim.update({"cell": str(Path(o.cell).resolve()), "urdf": str(Path(o.urdf).resolve()) if o.urdf else "",
                        "node_ids": cell_node_ids(arm), "joint_names": list(arm.joints)})
        robot = self.robot_config()
        if robot is not None:     # the simulated drives carry the motor data the file asserts
            j0 = robot["joints"][0]
            sim["family"] = str(j0.get("family", "epos4"))
            sim["nominal_current"] = float(j0["units"]["nominal_current"])
            sim["counts_per_rev"] = int(j0["units"]["counts_per_rev"])
        sim.update({f"true_params.{k}": v for k, v in o.true_friction().items()})
        sim.update({f"friction.{k}": float(v) for k, v in o.sim_friction.items()})
        sim.update(o.sim_overrides)
        return sim

    def robot_config(self) -> Optional[dict]:
        """The robot's bridge file (``bridge_config_file``) re-pointed at the hub, None without one;
        ValueError when it cannot run on the simulation (:func:`robot_bridge_config`)."""
        if self.options.bridge_config_file is None:
            return None
        if self.options.cell:
            raise ValueError("--bridge-config runs a shipped robot file on the built-in arms; with --cell "
                             "the bridge's config comes from the cell (leave --bridge-config out)")
        if self._robot is None:
            self._robot = robot_bridge_config(self.options.bridge_config_file, self.options.model,
                                              self.hub_url)
        return self._robot

    @property
    def sync_period(self) -> float:
        """s, the SYNC period on the hub's bus (the robot file's, else the stack's)."""
        robot = self.robot_config()
        return float(robot.get("sync_period", 0.01)) if robot is not None else SYNC_PERIOD

    @property
    def hub_syncs(self) -> bool:
        """The hub (its own process) produces SYNC: synchronous setpoints on a separate hub (with
        a robot file: when it says ``sync_producer: external``)."""
        robot = self.robot_config()
        if robot is not None:
            return (self.options.separate_hub and robot.get("setpoint_timing", "sync") == "sync"
                    and robot.get("sync_producer", "master") == "external")
        return self.options.separate_hub and self.options.setpoint_timing == "sync"

    def bridge_data(self) -> dict:
        """The bridge's config file (ff_hwbridge.drive.config), written to <run_dir>/bridge.yaml."""
        robot = self.robot_config()
        if robot is not None:
            bdata = dict(robot)
            self._apply_envelope(bdata)
            return bdata
        bdata = (urdf_bridge_config(urdf_arm(self.options.cell, self.options.urdf), self.hub_url)
                 if self.options.cell else bridge_config(self.options.model, self.hub_url))
        bdata["setpoint_timing"] = self.options.setpoint_timing
        if self.hub_syncs:
            bdata["sync_producer"] = "external"
        if self.options.setpoint_timing == "sync":
            bdata["player_process"] = bool(self.options.player_process)
        bdata["stall_dump"] = float(self.options.stall_dump)
        if self.options.rt_priority:
            bdata["scheduler_rt_priority"] = int(self.options.rt_priority)
        self._apply_envelope(bdata)
        return bdata

    def _apply_envelope(self, bdata: dict) -> None:
        if self.options.joint_envelope is not None:
            lo, hi, vmax = (float(x) for x in self.options.joint_envelope)
            bdata["joints"] = [dict(j) for j in bdata["joints"]]
            for joint in bdata["joints"]:
                joint["position_limits"] = [lo, hi]
                joint["velocity_limit"] = vmax

    def planner_files(self) -> tuple[list[str], dict[str, object]]:
        """(parameter files in order, overrides written after them) for the planner."""
        pp: dict[str, object] = {"library_path": str(self.run_dir / "motions.sqlite")}
        # plans drive-exact for the drive this stack runs (the bridge's own file, written before
        # the planner starts): currents on its setpoint unit (per mille of the rated torque),
        # switch times on its SYNC cycle, the certificate on that profile
        pp["drive_config"] = str(self.run_dir / "bridge.yaml")
        robot = self.robot_config()
        nominal = (float(robot["joints"][0]["units"]["nominal_current"]) if robot is not None
                   else NOMINAL_CURRENT)
        pp["current_quantum"] = nominal / 1000.0
        if self.options.cell:      # served as urdf:NAME, whatever config/planner.yaml registers
            arm = urdf_arm(self.options.cell, self.options.urdf)
            pp[f"arms.{arm.name}.cell"] = str(Path(self.options.cell).resolve())
            pp[f"arms.{arm.name}.urdf"] = str(Path(self.options.urdf).resolve() if self.options.urdf
                                              else arm.cell.urdf)
        pp.update(self.options.planner_overrides)
        return [self.options.planner_params or str(CONFIG_DIR / "planner.yaml")], pp

    def executor_files(self) -> tuple[list[str], dict[str, object]]:
        """(parameter files in order, overrides written after them) for the executor: by default
        config/executor.yaml, then config/executor_sim.yaml, then the model's joint names and the
        simulated stack's joint-state watchdog (``JOINT_STATE_TIMEOUT``)."""
        o = self.options
        ep: dict[str, object] = {"joint_state_timeout": JOINT_STATE_TIMEOUT}
        if o.executor_params is None:   # the default file's joints are the 1-DOF arm's
            files = [str(CONFIG_DIR / f) for f in EXECUTOR_FILES if (CONFIG_DIR / f).is_file()]
            joints = (urdf_bridge_config(urdf_arm(o.cell, o.urdf), self.hub_url) if o.cell
                      else bridge_config(o.model, self.hub_url))["joints"]
            ep["joint_names"] = [j["name"] for j in joints]
        else:
            files = [o.executor_params]
        if self.ns:     # the bridge's topics inside the namespace (bridge_node is relative)
            given = merged_parameters(files, "ff_executor", {})
            for key in ("setpoint_topic", "joint_state_topic", "current_topic", "applied_topic"):
                topic = str(given.get(key, ""))
                if topic.startswith("/"):
                    ep[key] = self.name(topic)
        ep.update(o.executor_overrides)
        return files, ep

    def effective_config(self) -> dict:
        """Everything start() would use, with the value each process ends up with (for --print-config)."""
        merged = merged_parameters
        o = self.options
        pf, pov = self.planner_files()
        ef, eov = self.executor_files()
        return {
            "ros": {k: self.env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOG_DIR")},
            "run_dir": str(self.run_dir), "can_hub": self.hub_url, "record": o.record,
            "namespace": self.ns or "/",
            "ff_sim_driver": {"source": ("generated (family, counts_per_rev, nominal_current from "
                                         f"{o.bridge_config_file or 'config/sim_arm1dof.yaml'}"
                                         + (f"; the arm, node ids and joints from {o.cell}" if o.cell else "")
                                         + ")"),
                              "parameters": self.sim_parameters()},
            "ff_hwbridge": {"source": (f"{o.bridge_config_file}, its bus re-pointed at the hub"
                                       if o.bridge_config_file else
                                       "generated: lenient timing for a shared machine (config/bridge_*.yaml "
                                       "are for real hardware)"), "config": self.bridge_data(),
                            "parameters": dict(o.bridge_overrides)},
            **({"ff_planner": {"files": pf, "parameters": merged(pf, "ff_planner", pov)}} if o.planner else {}),
            **({"ff_executor": {"files": ef, "parameters": merged(ef, "ff_executor", eov)}} if o.executor else {}),
        }

    def start(self) -> "Stack":
        o = self.options
        model = o.model
        true = o.true_friction()
        self.robot_config()          # a robot file that cannot run here: refused before anything starts
        self.log(f"ff-bringup: run folder {self.run_dir}, ROS_DOMAIN_ID={self.env['ROS_DOMAIN_ID']} "
                 f"(loopback only), CAN hub {self.hub_url}")
        if o.cell:
            arm = urdf_arm(o.cell, o.urdf)
            model = f"{o.model_id} ({o.cell}: joints {list(arm.joints)})"
        self.log(f"  simulated arm: {model}, true friction differs from the model by {true or 'nothing'}")
        if o.bridge_config_file:
            sync = "from the hub, as a kernel timer sends it" if self.hub_syncs else "from the bridge"
            self.log(f"  bridge: {o.bridge_config_file} as shipped, its bus on the hub "
                     f"(SYNC {sync}, {self.sync_period * 1e3:g} ms)")
        try:
            if o.separate_hub:
                hub_args = ["--port", str(self.hub_port)]
                if self.hub_syncs:
                    hub_args += ["--sync-period", str(self.sync_period),
                                 "--sync-jitter-model-us", str(float(o.sync_jitter_model_us))]
                p = self._start("ff_can_hub", "ff_hwbridge.cli.can_hub", hub_args, timing=True)
                self._wait(p, lambda: "CAN hub on" in p.output(), "serving on 127.0.0.1")
            sim_args = self._node_args("ff_sim_driver", [], self.sim_parameters(), self.run_dir / "sim_driver.yaml")
            p = self._start("ff_sim_driver", "ff_hwbridge.ros.sim_driver_node", sim_args, timing=True)
            self._wait(p, lambda: self.has_service(self.name("ff_sim_driver/reset")), "service ~/reset")

            bcfg = self.run_dir / "bridge.yaml"
            bdata = self.bridge_data()
            bcfg.write_text(yaml.safe_dump(bdata, sort_keys=False))
            bp: dict[str, object] = {"config_file": str(bcfg)}
            bp.update(o.bridge_overrides)
            bargs = self._node_args("ff_hwbridge", [], bp, self.run_dir / "bridge_params.yaml")
            # one try: a bridge that exits has left its drives armed against its heartbeat (a
            # second one would find them in Fault 0x8130); its own error line says why
            p = self._start("ff_hwbridge", "ff_hwbridge.ros.bridge_node", ["--autostart", *bargs], timing=True)
            try:
                self._wait(p, lambda: self.lifecycle_state("ff_hwbridge") == "active", "lifecycle state active")
            except BringupError as exc:
                sim = next((q.output() for q in self.procs if q.name == "ff_sim_driver"), "")
                raise BringupError(f"ff_hwbridge did not come up: {bridge_failure(p.output(), sim)}\n{exc}") from None

            if o.planner:
                files, pp = self.planner_files()
                args = self._node_args("ff_planner", files, pp, self.run_dir / "planner_overrides.yaml")
                p = self._start("ff_planner", "ff_planner.ros.planner_node", args)
                self._wait(p, lambda: self.has_service(self.name("ff_planner/plan")), "service ~/plan")

            if o.executor:
                files, ep = self.executor_files()
                args = self._node_args("ff_executor", files, ep, self.run_dir / "executor_overrides.yaml")
                p = self._start("ff_executor", "ff_executor.ros.executor_node", args, timing=True)
                self._wait(p, lambda: self.has_service(self.name("ff_executor/execute/_action/send_goal")),
                           "action ~/execute")
            if o.record:
                p = self._start("ff_record", "ff_executor.ros.record", ["-o", str(o.record)])
                self._wait(p, lambda: "ff-record: recording" in p.output(), f"recording into {o.record}")
        except BaseException:
            self.stop()
            raise
        self.log("ff-bringup: all up")
        return self

    def set_true_params(self, values: Mapping[str, float], timeout: float = 10.0) -> None:
        """Change the simulated arm's true parameters at runtime (``true_params.<key>``, SI)."""
        self.options.base_params().replace(**values)   # refuse unknown keys early
        self.set_sim_parameters({f"true_params.{k}": float(v) for k, v in values.items()}, timeout)

    def set_sim_friction(self, values: Mapping[str, float], timeout: float = 10.0) -> None:
        """Change the simulated arm's friction that is not Eq. 9 at runtime (``friction.<key>``:
        stribeck, stribeck_speed, coulomb_ripple, coulomb_period; all levels 0 = Eq. 9)."""
        self.set_sim_parameters({f"friction.{k}": float(v) for k, v in values.items()}, timeout)

    def set_sim_parameters(self, values: Mapping[str, object], timeout: float = 10.0) -> None:
        """Set parameters of the running ``ff_sim_driver`` (double, integer, bool or string
        values), all in one call; BringupError if it refuses or does not answer."""
        node = self._probe()
        cli = node.create_client(SetParameters, self.name("ff_sim_driver/set_parameters"))
        try:
            if not cli.wait_for_service(timeout_sec=timeout):
                raise BringupError("ff_sim_driver's set_parameters service is not available")
            req = SetParameters.Request(parameters=[Parameter(name=k, value=_parameter_value(v))
                                                    for k, v in values.items()])
            fut = cli.call_async(req)
            ex = SingleThreadedExecutor(context=self._ctx)
            ex.add_node(node)
            ex.spin_until_future_complete(fut, timeout_sec=timeout)
            ex.remove_node(node)
            if not fut.done() or fut.result() is None:
                raise BringupError("ff_sim_driver did not answer set_parameters")
            bad = [r.reason for r in fut.result().results if not r.successful]
            if bad:
                raise BringupError(f"ff_sim_driver refused the parameters: {bad}")
        finally:
            node.destroy_client(cli)

    def sync_report(self, timeout: float = 3.0) -> Optional[dict]:
        """The hub's SYNC report now (``ff-can-hub`` prints it on SIGUSR1): count, jitter and
        ``late_slots``, the SYNCs its timer thread (SCHED_FIFO, the stack's highest priority)
        sent more than one period late: the machine gave no CPU even to that thread, so no
        process of the stack kept its timing meanwhile. None without a SYNC-producing hub."""
        hub = next((p for p in self.procs if p.name == "ff_can_hub"), None)
        if hub is None or not self.hub_syncs or not hub.alive():
            return None

        def reports() -> list[dict]:
            out = []
            for line in hub.output().splitlines():
                if line.startswith('{"sync"'):
                    try:
                        out.append(json.loads(line)["sync"])
                    except (ValueError, KeyError):
                        pass
            return out

        seen = len(reports())
        os.kill(hub.pid, signal.SIGUSR1)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            got = reports()
            if len(got) > seen:
                return got[-1]
            time.sleep(0.05)
        return None

    def log_tails(self, chars: int = 2000) -> str:
        """The last ``chars`` characters of every process's output, for a report of what went
        wrong (a stall dump among them)."""
        return "\n".join(f"--- {p.name} ({p.log_path}):\n{p.output()[-chars:]}" for p in self.procs)

    def dead(self) -> list[NodeProcess]:
        """Children that have exited."""
        return [p for p in self.procs if not p.alive()]

    def stop(self) -> dict[str, int]:
        """Stop every child by PID in reverse start order; returns their exit codes."""
        codes = {}
        for p in reversed(self.procs):
            codes[p.name] = p.stop()
        self.procs = []
        if self._node is not None:
            self._node.destroy_node()
            self._node = None
            if self._ctx is not None and self._ctx.ok():
                rclpy.shutdown(context=self._ctx)
            self._ctx = None
        return codes

    def __enter__(self) -> "Stack":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def parse_key_values(items: Sequence[str], what: str) -> dict[str, float]:
    """``["pc=1.2", ...]`` -> ``{"pc": 1.2, ...}``; ParameterError naming ``what`` on a bad item."""
    out = {}
    for item in items:
        if "=" not in item:
            raise ParameterError(f"{what} needs KEY=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = float(v)
        except ValueError:
            raise ParameterError(f"{what} {k}: {v!r} is not a number") from None
    return out


def add_environment_arguments(ap: argparse.ArgumentParser) -> None:
    """--domain-id, --run-dir, --record, --print-config (ff-bringup and ff-demo)."""
    ap.add_argument("--domain-id", type=int, default=None,
                    help="ROS_DOMAIN_ID (default: ROS_DOMAIN_ID if set, else a free one in 1..100)")
    ap.add_argument("--run-dir", default=None, help="logs + generated files (default: a temp folder); "
                                                    "ROS logs go to ROS_LOG_DIR if set, else <run-dir>/ros-log")
    ap.add_argument("--record", default=None, metavar="DIR",
                    help="record the run's topics into this rosbag2 folder (MCAP; ff-record)")
    ap.add_argument("--print-config", action="store_true",
                    help="print the effective configuration (YAML) and exit without starting anything")


def environment_options(a: argparse.Namespace, environ: Optional[Mapping[str, str]] = None) -> dict:
    """StackOptions fields from --domain-id / --run-dir / --record and the environment: the domain
    from --domain-id, else ROS_DOMAIN_ID, else None (a free one); the log folder from ROS_LOG_DIR."""
    env = os.environ if environ is None else environ
    domain = a.domain_id
    if domain is None and env.get("ROS_DOMAIN_ID", "").strip():
        try:
            domain = int(env["ROS_DOMAIN_ID"])
        except ValueError:
            raise ValueError(f"ROS_DOMAIN_ID must be a whole number, got {env['ROS_DOMAIN_ID']!r}") from None
    if domain is not None and not 0 <= domain <= 232:
        raise ValueError(f"the ROS domain id must be 0..232, got {domain}")
    if a.record and Path(a.record).exists():
        raise ValueError(f"--record: {a.record} exists already (ff-record makes a new folder)")
    return {"domain_id": domain, "run_dir": a.run_dir, "log_dir": env.get("ROS_LOG_DIR") or None,
            "record": a.record}


def print_config(stack: "Stack") -> None:
    """The effective configuration as YAML on stdout."""
    print(yaml.safe_dump(stack.effective_config(), sort_keys=False), end="", flush=True)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="ff-bringup", description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n".join(__doc__.splitlines()[2:6]))
    ap.add_argument("--model", default="arm1dof", choices=MODELS)
    ap.add_argument("--cell", default=None, metavar="YAML",
                    help="simulate an arm from a URDF instead of --model: its cell file (motors, friction, "
                         "node ids, limits; as ff-plan --cell), e.g. config/arms/arm3h.cell.yaml")
    ap.add_argument("--urdf", default=None, metavar="FILE",
                    help="with --cell: the arm's URDF (default: the file the cell names)")
    ap.add_argument("--true-scale", action="append", default=[], metavar="KEY=FACTOR",
                    help="scale a true friction parameter of the simulated arm, e.g. pc=1.2")
    ap.add_argument("--true-param", action="append", default=[], metavar="KEY=VALUE",
                    help="set a true parameter of the simulated arm (SI units), e.g. pc=0.25")
    ap.add_argument("--no-planner", action="store_true", help="do not start the planner node")
    ap.add_argument("--hub-port", type=int, default=0, help="CAN hub port on 127.0.0.1 (0 = free)")
    ap.add_argument("--namespace", default="", metavar="NS",
                    help="start every node under /NS (e.g. arm_a), with its own CAN hub: a second arm on the "
                         "same ROS domain gets another NS (default: the root namespace)")
    add_environment_arguments(ap)
    ap.add_argument("--start-timeout", type=float, default=90.0, help="s per process")
    ap.add_argument("--rt-priority", type=int, default=0, metavar="N",
                    help="SCHED_FIFO priority 1..99 for the simulated driver and the bridge's "
                         "scheduler thread (needs root/CAP_SYS_NICE; 0 = off, the default)")
    ap.add_argument("--setpoint-timing", choices=("sync", "on_receipt"), default="sync",
                    help="sync (default): the drives latch setpoints at SYNC, produced by the CAN hub's "
                         "timer; on_receipt: setpoints applied when they arrive, at their stamps")
    ap.add_argument("--bridge-config", default=None, metavar="YAML",
                    help="run this bridge config as a robot would (e.g. config/bridge_epos4_1dof.yaml: "
                         "in-process player, 10 ms SYNC from a kernel-like timer: the hub's), its bus re-pointed at "
                         "the simulated hub; --setpoint-timing/--rt-priority then do not "
                         "apply to the bridge (default: the stack's own lenient config)")
    return ap


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Console script ``ff-bringup``: start the stack, wait for Ctrl-C or a dying child, stop all."""
    a = build_parser().parse_args(argv)
    try:
        opts = StackOptions(model=a.model, true_scale=parse_key_values(a.true_scale, "--true-scale"),
                            true_params=parse_key_values(a.true_param, "--true-param"), planner=not a.no_planner,
                            hub_port=a.hub_port, start_timeout=a.start_timeout, rt_priority=a.rt_priority,
                            setpoint_timing=a.setpoint_timing,
                            bridge_config_file=a.bridge_config, namespace=a.namespace,
                            cell=a.cell, urdf=a.urdf, **environment_options(a))
        if a.urdf and not a.cell:
            raise ValueError("--urdf needs --cell (the arm's motors, friction and node ids come from it)")
        if a.cell and a.model != "arm1dof":
            raise ValueError("give --model or --cell, not both")
        if a.cell and a.bridge_config:
            raise ValueError("--bridge-config runs a shipped robot file on the built-in arms; with --cell "
                             "the bridge's config comes from the cell (leave --bridge-config out)")
        check_namespace(a.namespace)
        if a.namespace.strip("/ ") and a.record:
            raise ValueError("--record records the root namespace's topics; record a namespaced stack "
                             "with ros2 bag or leave --namespace out")
        opts.true_friction()
        if a.bridge_config:
            robot_bridge_config(a.bridge_config, a.model, "ws://127.0.0.1:1/")
        if not 0 <= a.rt_priority <= 99:
            raise ValueError(f"--rt-priority must be 0..99, got {a.rt_priority}")
    except (ParameterError, ValueError) as exc:
        print(f"ff-bringup: {exc}", file=sys.stderr)
        return 2
    stack = Stack(opts)
    if a.print_config:
        print_config(stack)
        return 0
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    code = 0
    try:
        stack.start()
        print(f"ff-bringup: running; export ROS_DOMAIN_ID={stack.env['ROS_DOMAIN_ID']} "
              "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST to talk to it; Ctrl-C stops everything",
              flush=True)
        while not stop.wait(0.5):
            dead = stack.dead()
            if dead:
                for p in dead:
                    print(f"ff-bringup: {p.name} died (code {p.popen.returncode}); stopping all. "
                          f"Last output:\n{p.output()[-2000:]}", file=sys.stderr, flush=True)
                code = 1
                break
    except KeyboardInterrupt:
        pass
    except BringupError as exc:
        print(f"ff-bringup: {exc}", file=sys.stderr)
        code = 1
    finally:
        codes = stack.stop()
        if codes:
            print("ff-bringup: stopped " + ", ".join(f"{k} ({v})" for k, v in codes.items()),
                  flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
