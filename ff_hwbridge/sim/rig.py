"""A simulated rig: the arm plant (``sim.arm``) plus one emulated EPOS per joint (``sim.drive``)
on one CAN bus. No ROS: the ``ff_sim_driver`` node, the ``ff-sim-rig`` command
(``ff_hwbridge.cli.sim_rig``) and the multi-process tests wrap it.

``run_command`` executes one line of the rig's stdin command channel (for tests that inject
faults into a running process). Commands:
``emcy NODE CODE`` · ``resetnode NODE`` (NMT reset node: power-cycle the drive) ·
``power NODE off|on`` (switch the drive off; on = power-on boot) ·
``warn NODE [CODE]`` (warning EMCY, default 0xFF01) · ``warnclear NODE`` ·
``heartbeat NODE on|off`` · ``sdo NODE on|off`` ·
``supervision NODE on|off`` (the drive's interpolation supervision, EMCY 0x8250; on by default) ·
``delay NODE MS [rx|tx|both]`` ·
``drop NODE FRACTION [rx|tx|both]`` · ``dropnext NODE N [rx|tx|both]`` · ``clear NODE`` ·
``reset Q0...`` · ``state`` (prints ``state q=... qd=... i=...``) · ``info NODE`` (drive state,
faults, heartbeat consumer, frame counts) · ``quit``.
"""
from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Optional, Sequence

from ff_hwbridge.drive.bus import open_network
from ff_hwbridge.sim.arm import AdvanceFn, Params, SimArm, joint_param
from ff_hwbridge.sim.drive import DriveConfig, SimConfigError, SimEpos
from ff_planner.model.params import Arm1DofParams, default_params, n_joints

#: Thread switch interval for simulator processes (s). Python's default 5 ms lets the hub's and
#: the heartbeat's threads hold the CAN receive thread off for whole milliseconds; measured here
#: (loaded 2-core machine) the frame latency tail shrank with 0.5 ms.
SWITCH_INTERVAL = 0.0005


@dataclass
class RigConfig:
    """What to simulate: model, drives and the bus (SI units; currents in A)."""

    model: str = "arm1dof"
    node_ids: tuple[int, ...] = (1,)
    family: str = "epos4"
    bus: Mapping[str, Any] = field(default_factory=lambda: {"interface": "virtual",
                                                            "channel": "ff-sim"})
    true_params: Optional[Params] = None          # default: the model's paper table
    q0: tuple[float, ...] = (0.0,)
    step: float = 1e-4                            # s, physics sub-step
    clock_period: float = 0.002                   # s, the plant's own clock (0 = advance on demand)
    counts_per_rev: int = DriveConfig.counts_per_rev
    nominal_current: float = DriveConfig.nominal_current   # A (sets the ‰ scale on EPOS4)
    nominal_currents: Optional[tuple[float, ...]] = None   # A per joint (default nominal_current)
    interpolation_supervision: bool = True        # the EPOS4's CSx rule (0x8250); off: old tests only

    def params(self) -> Params:
        return self.true_params if self.true_params is not None else default_params(self.model)

    def drive_configs(self) -> list[DriveConfig]:
        p = self.params()
        nj = n_joints(self.model)
        noms = self._per_drive(nj, f"model '{self.model}' has {nj} joint(s)")
        out = []
        for j, nid in enumerate(self.node_ids):
            n, kt, imax = (joint_param(p, k, j) for k in ("n", "kt", "i_max"))
            out.append(DriveConfig(node_id=int(nid), family=self.family,
                                   nominal_current=float(noms[j]), current_limit=imax,
                                   torque_constant=kt, counts_per_rev=self.counts_per_rev,
                                   gear_ratio=n, load_inertia=joint_inertia(p, j),
                                   interpolation_supervision=self.interpolation_supervision))
        return out

    def _per_drive(self, nj: int, arm: str) -> tuple[float, ...]:
        """The nominal current (A) of each of the ``nj`` drives, after checking that there is one
        distinct node id per joint; SimConfigError (``arm`` describes the arm) otherwise."""
        if len(self.node_ids) != nj:
            raise SimConfigError(f"{arm} but {len(self.node_ids)} node id(s) were given: {list(self.node_ids)}")
        if len(set(self.node_ids)) != nj:
            raise SimConfigError(f"node ids must differ, got {list(self.node_ids)}")
        noms = tuple(self.nominal_currents or (self.nominal_current,) * nj)
        if len(noms) != nj:
            raise SimConfigError(f"nominal_currents needs {nj} value(s), got {list(noms)}")
        return noms

    def make_arm(self, q0: Sequence[float], advance: Optional[AdvanceFn] = None) -> SimArm:
        """The plant the drives push current into (a rig for another kind of arm overrides it)."""
        return SimArm(self.params(), q0, step=self.step, advance=advance)


def joint_inertia(p: Params, joint: int) -> float:
    """kg m² the drive's velocity loop is tuned for (as a regulation tuning on the real arm
    would find): the 1-DOF arm's J; on the SCARA, joint 1 with the arm half folded (elbow at
    90°), joint 2 its own link."""
    if isinstance(p, Arm1DofParams):
        return float(p.J)
    jc1, jc2, m1, m2 = (float(getattr(p, k)) for k in ("Jc1", "Jc2", "m1", "m2"))
    l1, lc1, lc2 = (float(getattr(p, k)) for k in ("l1", "lc1", "lc2"))
    if joint == 0:
        return jc1 + m1 * lc1 ** 2 + jc2 + m2 * (l1 ** 2 + lc2 ** 2)
    return jc2 + m2 * lc2 ** 2


class SimRig:
    """Arm + drives on a connected canopen Network (opened from ``config.bus`` unless given)."""

    def __init__(self, config: RigConfig, *, network: Any = None,
                 advance: Optional[AdvanceFn] = None) -> None:
        self.config = config
        drive_cfgs = config.drive_configs()
        q0 = config.q0 if len(config.q0) == len(drive_cfgs) else tuple(config.q0[:1]) * len(drive_cfgs)
        self.arm = config.make_arm(q0, advance)
        self.drives = [SimEpos(c, self.arm.port(j)) for j, c in enumerate(drive_cfgs)]
        self._own_network = network is None
        self.network = open_network(config.bus) if network is None else network
        for d in self.drives:
            d.attach(self.network)
        if config.clock_period > 0:
            self.arm.start_clock(config.clock_period)   # physics never waits for a CAN frame

    def boot(self) -> None:
        """Power on every drive: boot-up frames, PRE-OPERATIONAL."""
        for d in self.drives:
            d.boot()

    def drive(self, node_id: int) -> SimEpos:
        for d in self.drives:
            if d.node_id == node_id:
                return d
        raise SimConfigError(f"no simulated drive with node id {node_id}; have "
                             f"{[d.node_id for d in self.drives]}")

    def reset_arm(self, q0: Optional[Sequence[float]] = None, params: Optional[Params] = None) -> None:
        """Arm back to ``q0`` (default the configured one) at rest; each drive then drives the
        current it is applying now (0 A unless it is enabled with a non-zero setpoint)."""
        self.arm.reset(self.config.q0 if q0 is None else q0, None, params)
        for d in self.drives:
            d.reapply()

    def watch_bus(self, on_event: Callable[[str], None], on_give_up: Callable[[], None],
                  reconnect_timeout: float = 30.0, period: float = 0.02) -> None:
        """Watch the bus this rig opened (``config.bus``, e.g. a hub it joined). When it fails
        (the hub went away: python-can's receive thread stops with the error), every drive
        takes it as bus off (``SimEpos.bus_lost``: Fault 0x81FD, current 0 at once); the rig
        then opens the bus again every 0.5 s and puts the drives back on it
        (``SimEpos.reattach``: PRE-OPERATIONAL, EMCY 0x81FD, heartbeat), or calls
        ``on_give_up`` after ``reconnect_timeout`` s without a bus. ``on_event`` gets a line
        for each step."""
        if not self._own_network:
            raise SimConfigError("watch_bus needs a rig that opened its own bus")
        self._watch_stop = threading.Event()

        def run() -> None:
            while not self._watch_stop.wait(period):
                exc = getattr(getattr(self.network, "notifier", None), "exception", None)
                if exc is None:
                    continue
                t_lost = time.monotonic()
                for d in self.drives:
                    d.bus_lost()
                on_event(f"CAN bus lost ({type(exc).__name__}: {exc}); drives "
                         f"{[d.node_id for d in self.drives]} in Fault 0x81FD (CAN bus off), "
                         f"current 0; reconnecting (seen at monotonic {t_lost:.6f} s)")
                try:
                    self.network.disconnect()
                except Exception:  # noqa: BLE001 - the bus is gone already
                    pass
                while not self._watch_stop.is_set():
                    try:
                        net = open_network(self.config.bus)
                    except Exception as err:  # noqa: BLE001 - not back yet
                        if time.monotonic() - t_lost > reconnect_timeout:
                            on_event(f"CAN bus not back within {reconnect_timeout:g} s ({err}); "
                                     "giving up")
                            on_give_up()
                            return
                        self._watch_stop.wait(0.5)
                        continue
                    self.network = net
                    for d in self.drives:
                        d.reattach(net)
                    on_event(f"CAN bus back after {time.monotonic() - t_lost:.1f} s; drives in "
                             "PRE-OPERATIONAL, Fault 0x81FD until a fault reset")
                    break

        self._watch_thread = threading.Thread(target=run, name="sim-rig-bus-watch", daemon=True)
        self._watch_thread.start()

    def close(self) -> None:
        stop = getattr(self, "_watch_stop", None)
        if stop is not None:
            stop.set()
            self._watch_thread.join(timeout=2.0)
        self.arm.stop_clock()
        for d in self.drives:
            d.close()
        if self._own_network:
            try:
                self.network.disconnect()
            except Exception:  # noqa: BLE001 - a bus that is gone cannot be closed cleanly
                pass

    def __enter__(self) -> "SimRig":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_command(rig: SimRig, line: str) -> str:
    """Execute one stdin command (see module doc); returns a reply line."""
    parts = line.split()
    if not parts:
        return ""
    cmd, args = parts[0].lower(), parts[1:]
    try:
        if cmd == "state":
            s = rig.arm.state()
            return f"state q={list(s.q)} qd={list(s.qd)} i={list(s.current)}"
        if cmd == "reset":
            rig.reset_arm([float(x) for x in args] or None)
            return "ok reset"
        d = rig.drive(int(args[0], 0))
        if cmd == "emcy":
            d.raise_emcy(int(args[1], 0))
        elif cmd == "resetnode":
            d.reset_node()
        elif cmd == "power":
            if args[1] == "off":
                d.power_off()
            else:
                d.boot()
        elif cmd == "warn":
            d.raise_warning(int(args[1], 0) if len(args) > 1 else 0xFF01)
        elif cmd == "warnclear":
            d.clear_warning()
        elif cmd == "heartbeat":
            d.stop_heartbeat(args[1] == "off")
        elif cmd == "sdo":
            d.set_sdo_silent(args[1] == "off")
        elif cmd == "supervision":
            if args[1] not in ("on", "off"):
                return f"error supervision takes on|off, got {args[1]!r}"
            d.interpolation_supervision = args[1] == "on"
        elif cmd == "delay":
            d.set_delay(float(args[1]), *(args[2:3] or ["both"]))
        elif cmd == "drop":
            d.drop_fraction(float(args[1]), *(args[2:3] or ["rx"]))
        elif cmd == "dropnext":
            d.drop_next(int(args[1]), *(args[2:3] or ["rx"]))
        elif cmd == "clear":
            d.clear_injected_faults()
        elif cmd == "info":
            now = time.monotonic()
            hb_age = {k: round(now - v, 4) for k, v in d.heartbeats_seen().items()}
            rx_by_id = {hex(k): v for k, v in d.frames_by_id().items()} if d.attached else None
            return (f"info node={d.node_id} nmt={d.nmt_state} state={d.state.value!r} "
                    f"fault=0x{d.fault_code:04X} error_t={d.last_error_time:.6f} "
                    f"supervision={'on' if d.interpolation_supervision else 'off'} "
                    f"interpolation_faults={d.interpolation_faults} "
                    f"interpolation_unjudged={d.interpolation_unjudged} "
                    f"left_enabled_t={d.left_enabled_ns * 1e-9:.6f} "
                    f"zero_current_t={d.zero_current_ns * 1e-9:.6f} i={d.applied_current} "
                    f"last_sync_ns={d.last_sync_ns} "
                    f"consumers={d.heartbeat_consumers()} hb_age={hb_age} "
                    f"faults={vars(d.faults)} link={vars(d.link_stats)} rx_by_id={rx_by_id}")
        else:
            return f"error unknown command {cmd!r}"
        return f"ok {cmd}"
    except (IndexError, ValueError) as exc:
        return f"error {exc}"


def write_record(rig: SimRig, path: str, hub: Optional[Mapping[str, Any]] = None) -> None:
    """Setpoint arrival log of every drive as JSON: {node_id: [[mono_ns, wall_ns, raw, A], ...]},
    the drives' link statistics and (``hub``) those of a hub the rig hosts."""
    data = {str(d.node_id): [[r.mono_ns, r.wall_ns, r.raw, r.applied] for r in d.setpoint_log()]
            for d in rig.drives}
    stats = {str(d.node_id): vars(d.link_stats) for d in rig.drives}
    with open(path, "w", encoding="utf-8") as fh:
        json.dump({"setpoints": data, "link_stats": stats, "hub": hub}, fh)
