"""The whole chain across processes.

planner SERVICE → executor ACTION → bridge (lifecycle node) → CAN hub on 127.0.0.1 → simulated EPOS
+ arm whose true Coulomb friction is 20 % above the planner's model. Each motion runs once (every
run counts, no repeats). The robust plan must land within ROBUST_TOL of the goal; the non-robust
baseline (energy-optimal) must miss by more than BASELINE_MIN and by at least 3x the robust move.
"""
from __future__ import annotations

import time

import numpy as np
import pytest
from action_msgs.msg import GoalStatus

from ff_executor.bringup.demo import MOTIONS, plan_request, run_motions
from ff_executor.bringup.stack import Stack, StackOptions
from ff_executor.ros.client import StackClient

pytestmark = pytest.mark.integration

#: rad. The model predicts +2.2 mrad for this plan and friction (+3.7 mrad with the EPOS4's 3 mA
#: current steps, docs/timing.md). Setpoints are applied on receipt, timed by Python (each 100 µs
#: of relative switch delay moves the rest position by up to 2.7 mrad): 24 consecutive runs without
#: repeats, SCHED_FIFO 10 as here, on the 2-core machine under load average 5-6 (other test suites,
#: two busy processes) landed -0.8 ... +9.4 mrad; 20 mrad leaves 2x margin.
ROBUST_TOL = 0.02
#: rad. The baseline's own error for this friction: -115 mrad by the model, -112 measured.
BASELINE_MIN = 0.06


@pytest.fixture(scope="module")
def stack_client(tmp_path_factory):
    # the stack's default priorities: the hub's own SCHED_FIFO (SYNC timer 50, forwarding 49),
    # the bridge's player and bus receiver SCHED_FIFO 50 where permitted, nice -10 for the bridge
    # and the simulated drive
    stack = Stack(StackOptions(true_scale={"pc": 1.2},
                               run_dir=str(tmp_path_factory.mktemp("e2e"))), log=lambda s: None)
    stack.start()
    client = StackClient(stack.env, "ff_e2e_test")
    try:
        yield stack, client
    finally:
        client.close()
        stack.stop()


def machine_stalls(stack, before):
    """SYNC slots the hub's SCHED_FIFO timer thread sent more than a period late since
    ``before`` (its report): the machine gave no CPU to the stack's highest-priority thread."""
    after = stack.sync_report()
    assert before is not None and after is not None, "the hub must report its SYNC timing"
    return int(after["late_slots"]) - int(before["late_slots"])


def log_marks(stack) -> dict[str, int]:
    """How much each process of the stack has printed so far (for :func:`stall_evidence`)."""
    return {p.name: len(p.output()) for p in stack.procs}


def stall_evidence(stack, sync_before, marks: dict[str, int]) -> str:
    """What says the MACHINE held the stack off the CPU since ``sync_before`` / ``marks`` (""
    when nothing does): the hub's SCHED_FIFO SYNC timer sent late, the simulated driver handled
    frames more than 100 ms after their bus time (its own warning), or SCHED_FIFO was refused (the
    stack's real-time threads then run at normal priority). Not the bridge's own lateness: a bridge
    that misses its cycle on a machine that gave the simulation its CPU fails the test."""
    seen = []
    n = machine_stalls(stack, sync_before)
    if n:
        seen.append(f"the hub's SYNC timer late {n} slot(s)")
    for p in stack.procs:
        new = p.output()[marks.get(p.name, 0):]
        late = [line for line in new.splitlines() if "handled more than" in line]
        if p.name == "ff_sim_driver" and late:
            seen.append("the simulated driver stalled: " + late[-1].split("]: ", 1)[-1][:160])
        if "cannot use SCHED_FIFO" in p.output():
            seen.append(f"{p.name}: SCHED_FIFO refused, its real-time threads at normal priority")
    return "; ".join(seen)


def test_robust_lands_and_baseline_misses_with_coulomb_20_percent_off(stack_client):
    stack, client = stack_client
    before, marks = stack.sync_report(), log_marks(stack)
    s = run_motions(client, 1.0, 1.0, MOTIONS, log=lambda _m: None)
    rob, base = s["robust"], s["baseline"]
    evidence = stall_evidence(stack, before, marks)
    if evidence and (rob["missed_cycles"] or base["missed_cycles"] or not (rob["executed"] and base["executed"])):
        # the machine held the stack off the CPU past a SYNC period and a setpoint missed its
        # cycle (the drive's interpolation supervision stops the arm, as a real EPOS4 does): the
        # stack must stop safely and say so; no landing can be claimed from such a run, and the
        # test says that it could not check one (an xfail with the reason, never a pass).
        for m in (rob, base):
            assert m["executed"] or "missed" in m["message"] or "safe state" in m["message"], m
        stops = "; ".join(m["message"][:200] for m in (rob, base) if not m["executed"])
        pytest.xfail(f"the machine stalled the stack ({evidence}): {stops or 'missed cycles reported'}; "
                     "the safe stop was checked, the landing could not be")
    for m in (rob, base):
        assert m["executed"], m["message"]
        assert m["setpoints_sent"] >= m["steps"] // 2
        # >= 10 Hz (as received in this process; single gaps may stretch on a loaded machine)
        assert m["feedback_messages"] >= 10 and m["feedback_rate_hz"] >= 10.0, m
        assert m["feedback_gap_max_s"] < 1.0, m
        # the executor's figure (bridge joint states) agrees with the simulator's ground truth
        assert m["error"] == pytest.approx(m["error_truth"], abs=2e-4)
        assert m["missed_cycles"] == 0, m
        # the model's rest position for the profile, beside the measured one
        assert len(m["predicted_position"]) == 1 and np.isfinite(m["measured_minus_predicted"]), m
    assert rob["plan_success"] and rob["robust"]
    logs = "\n".join(f"--- {p.name}:\n{p.output()[-1500:]}" for p in stack.procs
                     if p.name in ("ff_can_hub", "ff_sim_driver", "ff_hwbridge"))
    keys = ("error_truth", "switch_spread_s", "switch_error_s", "start_delay_s", "missed_cycles", "message")
    assert abs(rob["error_truth"]) <= ROBUST_TOL, ({k: rob.get(k) for k in keys}, logs)
    assert abs(rob["error"]) <= ROBUST_TOL, rob
    assert abs(base["error_truth"]) >= BASELINE_MIN, base
    assert abs(base["error_truth"]) >= 3 * abs(rob["error_truth"]), (rob["error_truth"],
                                                                      base["error_truth"])
    assert np.isfinite(rob["switch_error_s"]["p99"])
    assert all(p.alive() for p in stack.procs)


def test_cancel_mid_move_stops_the_arm_across_the_chain(stack_client):
    stack, client = stack_client
    # this module's stack is shared: a safe state an earlier test left latched is cleared first
    client.fault_reset()
    resp = client.plan(plan_request("robust-derivative"))
    client.reset_arm([0.0])
    mv = client.execute(resp.profile, cancel_into_move=0.3)
    assert mv.status == GoalStatus.STATUS_CANCELED, mv.result.message
    # after the cancel the motor current measured by the bridge goes to zero and stays there
    t, _, _, eff = mv.joints.arrays()
    assert eff.size and abs(eff[-1, 0]) < 0.05


#: rad: |measured rest - the model's prediction| of the robust move with the shipped robot
#: configuration, the arm's friction as the model's (the issue's bound with two busy processes;
#: the stack's defaults land within 0.02 mrad, benchmarks/results/exec_defaults_quiet.json)
SHIPPED_TOL = 0.002


#: what a safe stop says when a watchdog of the shipped config's 10 ms timing tripped (a drive's
#: interpolation supervision, a heartbeat, SYNC or the drive's feedback lost, a missed cycle). On a
#: shared 2-core machine the simulated driver (a normal-priority ROS process) is the weak part: at
#: load 5-7 it handled CAN frames up to 2.6 s after their bus time (one frame 530 ms) and the
#: bridge's 130 ms feedback watchdog tripped 0.5 s into a hold. Such a run, with that evidence
#: (:func:`stall_evidence`), checks the safe stop only and says so (xfail with the reason); a stop
#: without it, or any other stop, fails.
_TIMING_WORDS = ("0x8250", "0x8130", "heartbeat", "SYNC", "missed", "feedback lost")


def _timing_stop(text: str) -> bool:
    return any(w in text for w in _TIMING_WORDS)


@pytest.mark.xfail(strict=False, reason=(
    "intermittent on a shared 2-core machine: the shipped config's 10 ms timing with derived 130 ms "
    "watchdogs, beside a simulated hub and a normal-priority simulated driver. Fresh-clone runs: "
    "passed at load 3.7-4.7 and 10.8; at load 1.3 the stack did not come up (no SYNC from the "
    "hub's timer for 273 ms while it started, sync_timeout 130 ms); at load 3-4 0x8250 during the "
    "hold with the simulated driver handling frames 155 ms late; at load 5-7 the bridge's feedback "
    "watchdog tripped 0.5 s into the hold (frames handled up to 2.6 s late)"))
def test_the_shipped_robot_configuration_runs_a_robust_move_on_the_simulated_epos4(tmp_path):
    """config/bridge_epos4_1dof.yaml as a robot runs it (player in the bridge's process, SYNC
    every 10 ms from a timer outside it: the kernel's on SocketCAN, the hub's here; 10 ms
    heartbeats, derived 130 ms timeouts), its bus on the simulated hub: it comes up without a
    latch, holds for 3 s, and the robust move lands where the model says, no cycle missed."""
    from ff_executor.bringup.stack import CONFIG_DIR

    shipped = str(CONFIG_DIR / "bridge_epos4_1dof.yaml")
    # the arm's friction as the planner's model: the executor's predicted rest (the model's, for
    # the drive-exact profile) is then the true arm's
    stack = Stack(StackOptions(bridge_config_file=shipped, run_dir=str(tmp_path)), log=lambda s: None)
    stack.start()
    client = StackClient(stack.env, "ff_e2e_shipped")
    try:
        assert stack.hub_syncs and not stack.bridge_data().get("player_process")
        before, marks = stack.sync_report(), {}
        time.sleep(3.0)
        bridge_log = next(p for p in stack.procs if p.name == "ff_hwbridge").output()
        latched = [line for line in bridge_log.splitlines() if "safe state" in line]
        evidence = stall_evidence(stack, before, marks) if latched else ""
        if latched and _timing_stop(latched[0]) and evidence:
            pytest.xfail(f"the machine stalled the stack while it held ({evidence}): {latched[0][-200:]}")
        assert not latched, bridge_log[-2000:]
        before, marks = stack.sync_report(), log_marks(stack)
        s = run_motions(client, 1.0, 1.0, MOTIONS[:1], log=lambda _m: None)
        rob = s["robust"]
        evidence = stall_evidence(stack, before, marks) if not rob["executed"] else ""
        if not rob["executed"] and _timing_stop(rob["message"]) and evidence:
            pytest.xfail(f"the machine stalled the stack during the move ({evidence}): {rob['message'][-200:]}")
        assert rob["executed"], rob["message"]
        assert rob["missed_cycles"] == 0, rob
        assert abs(rob["measured_minus_predicted"]) <= SHIPPED_TOL, rob
        assert all(p.alive() for p in stack.procs)
    finally:
        client.close()
        stack.stop()
