"""On-stack identification (``ff-identify --sim``) and the loop it closes: the excitation through
the executor action, timed on the CAN bus; the fit; a box-robust plan over the identified box
landing within its certificate; and bad input refused with one clear line, nothing moved."""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from ff_executor.bringup.identify import (ArmNotAtRest, DriveFault, StackNotRunning, StackProbe, bus_monitor,
                                          execute_run, identification_options, identify_runs,
                                          stack_q_resolution)
from ff_executor.bringup.loop import box_of, execute_plan, identify_friction, params_of, plan_request
from ff_executor.bringup.stack import Stack
from ff_executor.ros.client import StackClient
from ff_msgs_py.convert import profile_to_msg
from ff_msgs_py.launch import ros_environment
from ff_planner.identify import Envelope, design_excitation
from ff_planner.model.params import preset
from ff_planner.model.profile import CurrentProfile

pytestmark = pytest.mark.integration

BASE = preset("table2")
#: all three off table 2: pv −15 %, pc +20 %, pt −15 %
TRUE = {"pv": -0.0425, "pc": 0.228, "pt": 0.187}
ENV = Envelope(-1.0, 1.0, 3.0, i_max=3.0)
Q_RES = stack_q_resolution(BASE)


@pytest.fixture(scope="module")
def loop_stack(tmp_path_factory):
    """One stack for the module: planner on, setpoints latched at SYNC, the arm's friction TRUE."""
    stack = Stack(identification_options(TRUE, planner=True, run_dir=str(tmp_path_factory.mktemp("ident"))),
                  log=lambda s: None)
    stack.start()
    bus = bus_monitor(stack)
    client = StackClient(stack.env, "ff_identify_test")
    try:
        yield stack, client, StackProbe(client), bus
    finally:
        client.close()
        bus.close()
        stack.stop()


def _moves(bus, t_from):
    """Current changes the drive saw on the bus since ``t_from`` (wall s)."""
    return bus.current_changes(t_from, time.time() + 1.0, latched=False)


def test_identify_then_box_robust_lands_within_its_certificate(loop_stack):
    stack, client, probe, bus = loop_stack
    client.reset_arm([0.0])
    idf = identify_friction(client, BASE, bus=bus, probe=probe)
    fit = idf.fit
    assert idf.meta["timing"] == "bus" and fit.motion_seconds <= 60.0
    err = {k: fit.estimates[k] / TRUE[k] - 1.0 for k in TRUE}
    assert abs(err["pc"]) <= 0.03 and abs(err["pt"]) <= 0.03 and abs(err["pv"]) <= 0.10, err
    # honest: the truth lies within the 99.9 % interval (the 95 % one widened by 3.29 / 1.96), or the
    # fit says Eq. 9 does not describe the runs. A single trial's 95 % interval misses the truth 1 time
    # in 20 per parameter by design; its coverage (>= 18 of 20) is what bench_identify.py measures.
    for k, v in TRUE.items():
        lo, hi = fit.interval95[k]
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo) * 3.29 / 1.96
        assert abs(v - mid) <= half or not fit.adequate, (k, v, fit.interval95, fit.message)
    for k in range(2):
        before = stack.sync_report()
        landing, resp, _ = execute_plan(client, f"identified {k}", plan_request(
            "robust-box", params_of(fit), box_of(idf), seed=k + 1), bus=bus, probe=probe)
        after = stack.sync_report()
        assert before is not None and after is not None, "the hub must report its SYNC timing"
        assert resp.success and landing.certified, landing.message
        if after["late_slots"] > before["late_slots"] and (landing.missed_cycles or not landing.executed):
            # the machine stalled even the hub's SCHED_FIFO SYNC timer past a period, and a
            # setpoint missed its cycle: the stack must say so and claim no landing
            assert not landing.within_certificate, landing
            continue
        assert landing.executed, landing.message
        assert landing.box == pytest.approx(box_of(idf))
        assert landing.within_certificate, (landing.error_truth, landing.error_bridge, landing.certificate_worst,
                                            landing.switch_spread_s, landing.missed_cycles, fit.message)


def test_a_moving_arm_is_refused_and_identification_sends_nothing(loop_stack):
    stack, client, probe, bus = loop_stack
    probe.fault_reset()
    client.reset_arm([0.0])
    slow = CurrentProfile(np.array([0.0, 1.5]), np.array([[0.6]]), 4.0, 2.5)
    mover = threading.Thread(target=client.execute, args=(profile_to_msg(slow, "arm1dof", [0.0], [0.5]),),
                             kwargs={"timeout": 20.0})
    t0 = time.time()
    mover.start()
    # the arm is moving: seen by the simulation's ground truth (the move starts about 1 s after
    # the goal is accepted; later on a loaded machine), with 1.3 s of the 1.5 s push left at most
    end = time.monotonic() + 20.0
    while time.monotonic() < end:
        truth = client.last_truth
        if truth is not None and abs(truth[2][0]) > 0.05:
            break
        time.sleep(0.01)
    assert truth is not None and abs(truth[2][0]) > 0.05, "the mover's profile never moved the arm"
    time.sleep(0.2)
    with pytest.raises(ArmNotAtRest, match="not at rest"):
        probe.wait_at_rest(Q_RES, timeout=0.6)
    ex = design_excitation(BASE, ENV, 0.0, levels=[1.0])
    with pytest.raises(ArmNotAtRest, match="not at rest") as info:
        execute_run(client, probe, ex.runs[0], Q_RES, ENV, log=lambda s: None)
    assert "\n" not in str(info.value)
    mover.join(30.0)
    # the drive saw the mover's current (0.6 A, then 0) and nothing else
    assert [a for _, a in _moves(bus, t0)] == pytest.approx([0.6, 0.0], abs=0.003)


def test_a_drive_in_fault_is_refused_and_nothing_moves(loop_stack):
    stack, client, probe, bus = loop_stack
    client.reset_arm([0.0])
    stack.set_sim_parameters({"fault.n1.emcy_code": 0x4210})      # the drive: over-temperature, FAULT
    end = time.monotonic() + 10.0
    while time.monotonic() < end:
        try:
            probe.check_drive()
        except DriveFault:
            break
        time.sleep(0.1)
    q_before = client.last_truth[1][0]
    t0 = time.time()
    ex = design_excitation(BASE, ENV, 0.0, levels=[1.0])
    with pytest.raises(DriveFault, match="in fault") as info:
        identify_runs(client, ex, Q_RES, ENV, probe=probe, bus=bus, log=lambda s: None)
    assert "\n" not in str(info.value) and "nothing was sent" in str(info.value)
    time.sleep(0.5)
    assert _moves(bus, t0) == [] or all(a == 0.0 for _, a in _moves(bus, t0))
    assert client.last_truth[1][0] == pytest.approx(q_before, abs=1e-9)          # the arm did not move
    stack.set_sim_parameters({"fault.n1.emcy_code": 0})
    probe.fault_reset()


def test_no_stack_is_a_clear_error_and_nothing_is_sent(tmp_path):
    env = ros_environment(None, str(tmp_path / "ros-log"))           # a free domain: nothing runs there
    client = StackClient(env, "ff_identify_alone")
    try:
        ex = design_excitation(BASE, ENV, 0.0, levels=[1.0])
        t0 = time.monotonic()
        with pytest.raises(StackNotRunning, match="is the stack running") as info:
            identify_runs(client, ex, Q_RES, ENV, log=lambda s: None)
        assert time.monotonic() - t0 < 15.0 and "\n" not in str(info.value)
    finally:
        client.close()
