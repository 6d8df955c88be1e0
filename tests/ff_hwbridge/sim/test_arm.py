"""The arm plant behind the emulated drives: the planner's model with its own (true) friction,
current changes applied exactly at their instants, and the drives + arm rig end to end."""
from __future__ import annotations

import math
import struct
import time

import numpy as np
import pytest

from ff_hwbridge.sim.arm import SimArm
from ff_hwbridge.sim.drive import SimConfigError
from ff_hwbridge.sim.rig import RigConfig, SimRig
from ff_planner.model import arm1dof, scara2
from ff_planner.model.params import ParameterError, preset
from tests.support.canopen_helpers import open_network, waiter


class FakeClock:
    def __init__(self):
        self.t = 1_000_000_000

    def __call__(self):
        return self.t


MS = 1_000_000


def test_matches_planner_model_with_switch_at_arrival_instant():
    p = preset("table2")
    clk = FakeClock()
    arm = SimArm(p, 0.2, clock=clk)
    t0 = clk.t
    arm.set_current(0, 6.0, t0)
    t_switch = t0 + 123_456_789                      # 0.123456789 s: not on any step grid
    arm.set_current(0, -4.0, t_switch)
    s = arm.state(t0 + 300 * MS)
    q, qd = arm1dof.advance(p, 0.2, 0.0, 6.0, 0.123456789)
    q, qd = arm1dof.advance(p, q, qd, -4.0, 0.3 - 0.123456789)
    assert s.q[0] == pytest.approx(q, abs=1e-9) and s.qd[0] == pytest.approx(qd, abs=1e-9)
    assert s.current == (-4.0,) and s.t_ns == t0 + 300 * MS
    # the same switch 1 ms later lands measurably elsewhere (timing matters)
    arm2 = SimArm(p, 0.2, clock=clk)
    arm2.set_current(0, 6.0, t0)
    arm2.set_current(0, -4.0, t_switch + MS)
    assert abs(arm2.state(t0 + 300 * MS).q[0] - s.q[0]) > 1e-3


def test_a_change_handled_late_lands_where_it_belongs_and_one_older_than_the_history_starts_late():
    from ff_hwbridge.sim.arm import REWIND_NS

    p = preset("table2")
    clk = FakeClock()
    t0 = clk.t
    steps = [(t0, 6.0), (t0 + 120 * MS, -4.0), (t0 + 230 * MS, 0.0)]
    on_time = SimArm(p, 0.0, clock=clk)
    for t, c in steps:
        on_time.set_current(0, c, t)
    ref = on_time.state(t0 + 600 * MS)
    late = SimArm(p, 0.0, clock=clk)
    late.set_current(0, 6.0, t0)
    late.state(t0 + 180 * MS)                        # the plant ran on: its readers looked
    late.set_current(0, -4.0, t0 + 120 * MS)         # 60 ms late
    late.state(t0 + 400 * MS)
    late.set_current(0, 0.0, t0 + 230 * MS)          # 170 ms late
    got = late.state(t0 + 600 * MS)
    assert got.q[0] == pytest.approx(ref.q[0], abs=1e-12) and got.qd[0] == pytest.approx(ref.qd[0], abs=1e-12)
    assert late.rewound_changes == 2 and late.rewound_max_ns == 170 * MS and late.late_changes == 0
    # beyond the history: the change starts at the plant's time and is counted as late
    t_end = t0 + 600 * MS + REWIND_NS + 10 * MS
    late.state(t_end)
    late.set_current(0, 1.0, t0 + 590 * MS)
    assert late.late_changes == 1 and late.state().current == (1.0,)


@pytest.mark.parametrize("mismatch", [False, True])
def test_a_state_read_after_the_plant_passed_its_instant_is_the_state_at_that_instant(mismatch):
    """A drive that handles a SYNC after the plant's clock passed the SYNC's instant samples the
    arm at that instant (from the history), not where the plant is now; the read moves nothing."""
    from ff_hwbridge.sim.arm import REWIND_NS
    from ff_planner.identify.measure import FrictionMismatch

    p = preset("table2")
    clk = FakeClock()
    t0 = clk.t
    steps = [(t0, 3.0), (t0 + 150 * MS, -3.0), (t0 + 300 * MS, 0.0)]
    reads = [t0 + 40 * MS, t0 + 150 * MS, t0 + 151_234_567, t0 + 299 * MS, t0 + 420 * MS]
    arms = [SimArm(p, 0.1, clock=clk), SimArm(p, 0.1, clock=clk)]
    if mismatch:
        for arm in arms:
            arm.set_friction(FrictionMismatch(stribeck=0.3, stribeck_speed=0.1))
    on_time, ahead = arms
    ref = []
    events = sorted([(t, 0, c) for t, c in steps] + [(t, 1, None) for t in reads])
    for t, kind, c in events:                       # each sample taken at its instant
        if kind == 0:
            on_time.set_current(0, c, t)
        else:
            ref.append(on_time.state(t))
    for t, c in steps:                              # the plant ran on 0.5 s before anyone looked
        ahead.set_current(0, c, t)
    ahead.state(t0 + 500 * MS)
    moving = ahead.state(t0 + 500 * MS)
    got = [ahead.state(t) for t in reads]
    tol = 1e-8 if mismatch else 1e-12               # sub-steps from another start: their grid differs
    for g, r in zip(got, ref):
        assert g.t_ns == r.t_ns
        assert g.q[0] == pytest.approx(r.q[0], abs=tol) and g.qd[0] == pytest.approx(r.qd[0], abs=tol)
        assert g.current == r.current
    assert len({round(g.q[0], 9) for g in got}) == len(reads)     # five different positions
    assert ahead.port(0).sample(reads[2]) == (got[2].q[0], got[2].qd[0], got[2].current[0])   # the drive's read
    assert ahead.state(t0 + 500 * MS) == moving and ahead.stale_reads == 0
    # older than the history: the oldest state kept, counted
    ahead.set_current(0, 0.0, t0 + 500 * MS + REWIND_NS + 100 * MS)
    old = ahead.state(t0 + 10 * MS)
    assert old.t_ns > t0 + 10 * MS and ahead.stale_reads == 1


def test_true_friction_differs_from_planner():
    clk = FakeClock()
    nominal = SimArm(preset("table2"), 0.0, clock=clk)
    rough = SimArm(preset("table2").replace(pc=0.19 * 1.3), 0.0, clock=clk)
    for a in (nominal, rough):
        a.set_current(0, 3.0, clk.t)
    t = clk.t + 200 * MS
    assert rough.state(t).q[0] < nominal.state(t).q[0] - 1e-4


def test_stiction_and_no_time_travel():
    p = preset("table2")
    clk = FakeClock()
    arm = SimArm(p, 0.5, clock=clk)
    arm.set_current(0, 0.1, clk.t)                   # below breakaway (≈0.169 A)
    assert arm.state(clk.t + 100 * MS).q[0] == 0.5
    arm.state(clk.t + 200 * MS)
    arm.set_current(0, 5.0, clk.t + 150 * MS)        # stamped in the past: the plant rewinds
    at = arm.state(clk.t + 150 * MS)                 # an instant the plant has passed: its history
    assert at.t_ns == clk.t + 150 * MS and at.q[0] == 0.5 and at.current == (5.0,)
    after = arm.state(clk.t + 200 * MS)
    assert after.t_ns == clk.t + 200 * MS and after.q[0] > 0.5 and arm.rewound_changes == 1
    arm.reset(1.0)
    s = arm.state()
    assert s.q == (1.0,) and s.qd == (0.0,) and s.current == (0.0,)


def test_scara_two_ports_match_model():
    p = preset("table3")
    clk = FakeClock()
    arm = SimArm(p, [-0.5, 0.0], step=1e-3, clock=clk)
    assert arm.n_joints == 2
    a, b = arm.port(0), arm.port(1)
    assert a.gear_ratio == 54.0 and b.gear_ratio == 198.0 and b.torque_constant == p.kt2
    a.set_current(5.0, clk.t)
    b.set_current(2.0, clk.t)
    q, qd, i = b.sample(clk.t + 50 * MS)
    ref_q, ref_qd = np.array([-0.5, 0.0]), np.zeros(2)
    for _ in range(50):
        ref_q, ref_qd = scara2.advance(p, ref_q, ref_qd, np.array([5.0, 2.0]), 1e-3)
    assert q == pytest.approx(ref_q[1], abs=1e-9) and qd == pytest.approx(ref_qd[1], abs=1e-9)
    assert i == 2.0


def test_bad_inputs():
    with pytest.raises(ParameterError, match="2 finite"):
        SimArm(preset("table3"), [0.0, 1.0, 2.0])
    with pytest.raises(ParameterError, match="step"):
        SimArm(preset("table2"), 0.0, step=0.0)
    with pytest.raises(ParameterError, match="joint index"):
        SimArm(preset("table2")).set_current(1, 1.0)
    with pytest.raises(SimConfigError, match="2 joint"):
        RigConfig(model="scara2", node_ids=(1,)).drive_configs()


def remap(node, comm, cob_id, entries, trans_type):
    """Standard PDO remap over SDO: disable, count 0, entries, count, type, enable."""
    node.sdo[comm][1].raw = cob_id | 0x80000000
    node.sdo[comm + 0x200][0].raw = 0
    for k, e in enumerate(entries, 1):
        node.sdo[comm + 0x200][k].raw = e
    node.sdo[comm + 0x200][0].raw = len(entries)
    node.sdo[comm][2].raw = trans_type
    node.sdo[comm][1].raw = cob_id


def test_rig_drives_move_the_arm_and_report_it():
    """In-process: a master enables the drive, streams current, reads position by SYNC."""
    cfg = RigConfig(bus={"interface": "virtual", "channel": "test-sim-arm-rig"}, q0=(0.3,))
    with SimRig(cfg) as rig:
        master = open_network("test-sim-arm-rig")
        tpdo = []
        master.subscribe(0x181, lambda i, d, t: tpdo.append(bytes(d)))
        try:
            rig.boot()
            node = master.add_node(1, rig.drives[0].node.object_dictionary)
            node.sdo.RESPONSE_TIMEOUT = 2.0
            node.sdo[0x6060].raw = 10
            remap(node, 0x1800, 0x181, [0x60410010, 0x60640020], 1)
            remap(node, 0x1400, 0x201, [0x60400010, 0x60710010], 255)
            node.nmt.send_command(0x01)
            time.sleep(0.02)
            for cw in (0x06, 0x0F):
                master.send_message(0x201, struct.pack("<Hh", cw, 0))
            time.sleep(0.02)
            master.send_message(0x201, struct.pack("<Hh", 0x0F, 1500))   # 4.5 A
            time.sleep(0.15)
            master.send_message(0x201, struct.pack("<Hh", 0x0F, 0))
            time.sleep(0.05)
            q_before = rig.arm.state().q[0]
            master.sync.transmit()
            end = time.monotonic() + 1
            while not tpdo and time.monotonic() < end:
                time.sleep(0.005)
            truth = rig.arm.state()
            assert q_before > 0.3 + 0.01                  # it moved, and still coasts
            assert truth.qd[0] > 0 and rig.drives[0].applied_current == 0.0
            sw, pos = struct.unpack("<Hi", tpdo[-1])
            q_reported = pos / 2048 * 2 * math.pi / 54.0  # sampled at the SYNC's arrival
            tol = 2 * math.pi / 2048 / 54
            assert q_before - tol <= q_reported <= truth.q[0] + tol
        finally:
            master.disconnect()


def test_scara_rig_two_drives_on_one_bus():
    """Two emulated drives (nodes 1, 2) boot on one bus and push current into the coupled arm;
    setpoints written over SDO apply too."""
    chan = "test-sim-arm-scara"
    cfg = RigConfig(model="scara2", node_ids=(1, 2), bus={"interface": "virtual", "channel": chan},
                    q0=(-0.5, 0.0))
    with SimRig(cfg) as rig:
        master = open_network(chan)
        boots = []
        master.subscribe(0x701, lambda i, d, t: boots.append(1))
        master.subscribe(0x702, lambda i, d, t: boots.append(2))
        try:
            rig.boot()
            assert waiter(3.0)(lambda: sorted(boots) == [1, 2]), boots
            nodes = [master.add_node(n, rig.drive(n).node.object_dictionary) for n in (1, 2)]
            for node in nodes:
                node.sdo.RESPONSE_TIMEOUT = 2.0
            assert nodes[1].sdo[0x3001][2].raw == 10000 and rig.drive(2).config.gear_ratio == 198.0
            for node in nodes:
                node.sdo[0x6060].raw = 10
                for cw in (0x06, 0x0F):
                    node.sdo[0x6040].raw = cw
            nodes[0].sdo[0x6071].raw = 1000              # 3 A on joint 1
            nodes[1].sdo[0x6071].raw = -500              # -1.5 A on joint 2
            s = rig.arm.state()
            assert s.current == (pytest.approx(3.0), pytest.approx(-1.5))
            time.sleep(0.1)
            assert rig.arm.state().q[0] > -0.5
            assert [r.source for r in rig.drive(1).setpoint_log()] == ["sdo"]
        finally:
            master.disconnect()


@pytest.mark.parametrize("mismatch", [False, True])
def test_replaying_seconds_of_history_is_exact_and_takes_milliseconds(mismatch):
    """A plant that fell behind its frames (a stalled drive process) replays the history at a
    late change: exactly, and fast enough not to fall further behind (the 1-DOF Eq. 9 motion in
    one exact step per interval, a non-Eq. 9 friction law in compiled sub-steps)."""
    from ff_planner.identify.measure import FrictionMismatch

    p = preset("table2")
    clk = FakeClock()
    t0 = clk.t
    steps = [(t0, 3.0), (t0 + 200 * MS, -3.0), (t0 + 400 * MS, 0.0)]
    arms = [SimArm(p, 0.0, clock=clk), SimArm(p, 0.0, clock=clk)]
    if mismatch:
        for arm in arms:
            arm.set_friction(FrictionMismatch(stribeck=0.3, stribeck_speed=0.1))
    on_time, late = arms
    for t, c in steps:
        on_time.set_current(0, c, t)
    ref = on_time.state(t0 + 1900 * MS)
    late.set_current(0, 3.0, t0)
    late.set_current(0, -3.0, t0 + 200 * MS)
    late.state(t0 + 1900 * MS)                       # the plant ran on without the last change
    began = time.perf_counter()
    late.set_current(0, 0.0, t0 + 400 * MS)          # 1.5 s late: replayed from its instant
    took = time.perf_counter() - began
    got = late.state(t0 + 1900 * MS)
    assert late.rewound_changes == 1 and late.late_changes == 0
    assert got.q[0] == pytest.approx(ref.q[0], abs=1e-9) and got.qd[0] == pytest.approx(ref.qd[0], abs=1e-9)
    # sub-stepped in Python (0.1 ms steps) the same replay took 0.2-0.4 s
    assert took < 0.1, f"replaying 1.5 s of the plant took {took * 1e3:.0f} ms"


def test_friction_that_is_not_eq9_matches_the_offline_measurement_and_can_be_switched_off():
    from ff_planner.identify.measure import FrictionMismatch, simulate_mismatch
    from ff_planner.model.params import default_params
    from ff_planner.model.profile import CurrentProfile

    p = preset("table2")
    prof = CurrentProfile(np.array([0.0, 0.3, 0.55]), np.array([[2.0], [-2.0]]), 1.5, 0.95)
    samples = [0.2, 0.45, 0.8, 1.5]
    events = sorted([(t, "q", None) for t in samples]
                    + [(0.0, "i", 2.0), (0.3, "i", -2.0), (0.55, "i", 0.0)])

    def run(arm, t0):
        out = []
        for t, kind, cur in events:
            if kind == "i":
                arm.set_current(0, cur, t0 + int(round(t * 1e9)))
            else:
                out.append(arm.state(t0 + int(round(t * 1e9))).q[0])
        return np.array(out)

    clk = FakeClock()
    eq9 = run(SimArm(p, 0.0, clock=clk), clk.t)
    for mm in (FrictionMismatch(stribeck=0.3, stribeck_speed=0.1),
               FrictionMismatch(coulomb_ripple=0.1, coulomb_period=0.25)):
        arm = SimArm(p, 0.0, clock=clk)
        arm.set_friction(mm)
        assert arm.friction is mm
        q = run(arm, clk.t)
        np.testing.assert_allclose(q, simulate_mismatch(p, prof, 0.0, np.array(samples), mm), atol=1e-9)
        assert np.max(np.abs(q - eq9)) > 1e-3                 # not the Eq. 9 arm
        arm.set_friction(FrictionMismatch())                  # inactive: the model's Eq. 9 again
        assert arm.friction is None
    with pytest.raises(ParameterError, match="1-DOF"):
        SimArm(default_params("scara2"), 0.0).set_friction(FrictionMismatch(stribeck=0.2))
    with pytest.raises(ParameterError):
        SimArm(p, 0.0).set_friction(FrictionMismatch(stribeck=5.0))


def test_a_current_law_runs_in_plant_time_whatever_the_caller_does():
    """A drive's law (its velocity loop braking to 0 rad/s) is evaluated by the plant every
    LAW_PERIOD_NS: read once after 2 s, the arm has stopped and stays stopped (a law evaluated
    only when its drive's thread runs would have held the first braking current for 2 s)."""
    from ff_hwbridge.sim.arm import LAW_PERIOD_NS

    p = preset("table2")
    clk = FakeClock()
    arm = SimArm(p, 0.0, qd0=3.0, clock=clk)
    tpa = p.n * p.kt

    def law(t, q, qd):                                    # speed loop, 20 ms, to 0 rad/s, +-10 A
        return max(-10.0, min(10.0, p.J * (0.0 - qd) / 0.02 / tpa))

    arm.set_law(0, law, clk.t)
    assert arm.has_law(0) and arm.state().current[0] < -5.0
    clk.t += 2_000 * MS
    s = arm.state()
    assert abs(s.qd[0]) < 1e-3 and 0.0 < s.q[0] < 0.2, s
    arm.set_law(0, None, clk.t)
    arm.set_current(0, 0.0, clk.t)
    clk.t += 100 * MS
    assert not arm.has_law(0) and arm.state().qd[0] == 0.0
    assert LAW_PERIOD_NS <= 1_000_000


def test_the_scara_plant_steps_in_compiled_code_one_call_per_interval():
    """The 2-DOF model sub-steps itself (its advance takes ``h``): the plant hands it each whole
    interval (one call per 2 ms tick, not one per 0.1 ms step: 20x fewer Python calls, which had
    left the simulated SCARA seconds behind on a loaded machine), on the same step grid: the same
    state as stepping from Python to 1e-9 rad."""
    from ff_planner.model.params import default_params
    from ff_planner.model.registry import model_spec

    p = default_params("scara2")
    ref_adv = model_spec("scara2").advance
    calls = {"n": 0}

    arms = []
    for whole in (True, False):
        clk = FakeClock()
        arm = SimArm(p, [0.0, 0.3], step=p.plant_step, clock=clk)
        assert arm._any_dt                              # it takes any interval itself
        if whole:
            inner = arm._advance

            def counted(*a, _inner=inner, **k):
                calls["n"] += 1
                return _inner(*a, **k)
            arm._advance = counted
        else:                                           # the reference: one Python call per step
            arm._advance, arm._any_dt = ref_adv, False
        arm.set_current(0, 2.0, clk.t)
        arm.set_current(1, -1.0, clk.t)
        for k in range(100):                            # 0.2 s in 2 ms ticks
            clk.t += 2 * MS
            arm.state()
            if k == 40:
                arm.set_current(0, -1.5, clk.t - 123_457)   # a change the plant had passed
        arms.append(arm.state())
    assert calls["n"] < 2 * 100 + 50, calls             # ~one call per tick (and per change)
    assert np.allclose(arms[0].q, arms[1].q, atol=1e-9) and np.allclose(arms[0].qd, arms[1].qd, atol=1e-8)


def test_the_plant_runs_its_model_once_when_built_so_its_first_tick_compiles_nothing():
    calls = []

    def advance(params, q, qd, currents, dt):
        calls.append((list(q), list(currents), dt))
        return np.asarray(q, dtype=float) + 1.0, np.asarray(qd, dtype=float) + 1.0

    clk = FakeClock()
    arm = SimArm(preset("table3"), [-0.5, 0.25], step=2e-4, advance=advance, clock=clk)
    # one sub-step from the initial state at zero current, in the constructor's thread ...
    assert calls == [([-0.5, 0.25], [0.0, 0.0], 2e-4)] and arm.warm_up_s >= 0.0
    # ... and its result thrown away: the arm is where it was put, at rest
    s = arm.state(clk.t)
    assert s.q == (-0.5, 0.25) and s.qd == (0.0, 0.0)


def test_a_late_repeat_of_the_current_in_force_changes_nothing_and_costs_no_replay():
    p = preset("table3")
    clk = FakeClock()
    t0 = clk.t
    arm = SimArm(p, [0.0, 0.0], clock=clk)
    arm.set_current(0, 1.5, t0)
    arm.set_current(1, 1.5, t0)
    arm.set_current(0, 0.0, t0 + 200 * MS)
    ref = arm.state(t0 + 500 * MS)
    # a drive repeating its setpoint every cycle, handled 300 ms late: the same value as the
    # plant carries at those instants (joint 0: 1.5 A before its switch, 0 A after) is no change
    arm.set_current(0, 1.5, t0 + 100 * MS)
    arm.set_current(0, 0.0, t0 + 300 * MS)
    arm.set_current(1, 1.5, t0 + 250 * MS)
    assert arm.rewound_changes == 0 and arm.late_changes == 0
    assert arm.state(t0 + 500 * MS) == ref
    # a late value that differs is put in its place, as before
    arm.set_current(1, 0.0, t0 + 250 * MS)
    assert arm.rewound_changes == 1
    assert arm.state(t0 + 500 * MS).q != ref.q


def test_a_rewind_keeps_the_history_dense_so_reads_of_the_replayed_span_stay_cheap():
    from ff_hwbridge.sim.arm import REPLAY_SNAP_NS

    p = preset("table3")
    clk = FakeClock()
    t0 = clk.t
    arm = SimArm(p, [0.0, 0.0], clock=clk)
    arm.set_current(0, 1.0, t0)
    arm.state(t0 + 1000 * MS)                  # the plant 1 s on, one snapshot at each end
    arm.set_current(1, 1.0, t0 + 100 * MS)     # 0.9 s late: rewound and replayed
    assert arm.rewound_changes == 1
    times = [sn.t_ns for sn in arm._snaps if sn.t_ns >= t0 + 100 * MS]
    assert times[0] == t0 + 100 * MS and times[-1] == t0 + 1000 * MS
    assert max(np.diff(times)) <= REPLAY_SNAP_NS
    # the replayed trajectory is the one an on-time change gives
    on_time = SimArm(p, [0.0, 0.0], clock=clk)
    on_time.set_current(0, 1.0, t0)
    on_time.set_current(1, 1.0, t0 + 100 * MS)
    for t in (t0 + 450 * MS, t0 + 1000 * MS):
        assert np.allclose(arm.state(t).q, on_time.state(t).q, atol=1e-9)


def test_every_drive_reading_one_past_instant_costs_one_integration_until_the_history_changes():
    calls = []
    p = preset("table3")
    clk = FakeClock()
    t0 = clk.t

    def advance(params, q, qd, currents, dt):
        calls.append(dt)
        return scara2.advance(params, q, qd, currents, dt, h=1e-4)

    arm = SimArm(p, [0.0, 0.0], clock=clk, advance=advance)
    arm.set_current(0, 1.0, t0)
    arm.state(t0 + 50 * MS)
    n = len(calls)
    a = arm.state(t0 + 20 * MS)          # a SYNC's instant the plant has passed, for drive 1 ...
    used = len(calls) - n
    assert used > 0 and arm.state(t0 + 20 * MS) == a and len(calls) == n + used   # ... drive 2: no work
    arm.set_current(1, 0.5, t0 + 10 * MS)                # a late change rewrites the history
    b = arm.state(t0 + 20 * MS)
    assert b != a and len(calls) > n + used
