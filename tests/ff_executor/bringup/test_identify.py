"""``ff-identify --sim``: the excitation through the executor action on the simulated stack."""
from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from ff_executor.bringup.identify import ArmNotAtRest, StackProbe, execute_run, run_on_stack
from ff_executor.bringup.stack import COUNTS_PER_REV, Stack, StackOptions
from ff_executor.ros.client import StackClient
from ff_msgs_py.convert import profile_to_msg
from ff_planner.identify import Envelope, design_excitation, fit_friction
from ff_planner.model.params import preset
from ff_planner.model.profile import CurrentProfile

pytestmark = pytest.mark.integration

BASE = preset("table2")
TRUE = {"pv": -0.04, "pc": 0.23, "pt": 0.18}
ENV = Envelope(-1.0, 1.0, 3.0)
Q_RES = 2.0 * math.pi / (COUNTS_PER_REV * BASE.n)


def test_identification_on_the_stack_is_honest(tmp_path):
    # the envelope holds with a switch 20 ms late (a loaded CI host); every run counts (no
    # repeats): the fit takes each run's switch times as the bridge applied them
    ex = design_excitation(BASE, ENV, 0.0, levels=[1.0, 2.0], min_step=0.05, timing_margin=0.02)
    records, meta = run_on_stack(ex, BASE, TRUE, 0.0, log=lambda s: None, run_dir=str(tmp_path),
                                 measure="joints")
    assert len(records) == len(ex.runs) == 4
    for rec, run in zip(records, ex.runs):
        assert rec.t.size >= 50 and rec.t[0] < 0.0 < rec.t[-1]
        assert ENV.q_min <= rec.q.min() and rec.q.max() <= ENV.q_max
        assert np.ptp(rec.q) > 0.02                                  # the arm moved
        assert np.nanmax(np.abs(rec.current)) == pytest.approx(run.level, rel=0.01)   # measured current
    fit = fit_friction(records, BASE)
    # never tight intervals that miss the truth: either they contain it, or the fit says it does not fit
    for k, v in TRUE.items():
        lo, hi = fit.interval95[k]
        assert (lo <= v <= hi) or not fit.adequate, (k, v, fit.interval95, fit.message)
    assert fit.estimates["pc"] == pytest.approx(TRUE["pc"], rel=0.5)


def test_a_moving_arm_is_refused(tmp_path):
    with Stack(StackOptions(planner=False, run_dir=str(tmp_path)), log=lambda s: None) as stack:
        client = StackClient(stack.env, "ff_identify_test")
        try:
            probe = StackProbe(client)
            assert probe.wait_at_rest(Q_RES) == pytest.approx(0.0, abs=1e-6)
            slow = CurrentProfile(np.array([0.0, 1.5]), np.array([[0.6]]), 4.0, 2.5)
            msg = profile_to_msg(slow, "arm1dof", [0.0], [0.5])
            mover = threading.Thread(target=client.execute, args=(msg,), kwargs={"timeout": 20.0})
            mover.start()
            time.sleep(1.2)                                         # the arm is now moving
            with pytest.raises(ArmNotAtRest, match="not at rest"):
                probe.wait_at_rest(Q_RES, timeout=0.6)
            ex = design_excitation(BASE, ENV, 0.0, levels=[1.0])
            with pytest.raises(ArmNotAtRest):
                execute_run(client, probe, ex.runs[0], Q_RES, ENV, log=lambda s: None)
            mover.join(30.0)
        finally:
            client.close()
