"""The SCARA certificate's excursion against the dense 2-DOF trajectory (rad, rad/s)."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model import scara2
from ff_planner.model.params import Scara2Params
from ff_planner.model.profile import CurrentProfile
from ff_planner.optimize.certificate2d import certify_scara2
from ff_planner.optimize.sample_box import box_corners

P = Scara2Params()


def _dense(p: Scara2Params, prof: CurrentProfile, q0) -> tuple[np.ndarray, ...]:
    """Per joint (min q, max q, peak |v|) of a 0.1 ms trajectory until both links rest."""
    sim = scara2.simulate_scara2(p, prof, q0, trajectory=True, h=1e-4, t_end=3.0)
    assert np.all(sim.qd[-1] == 0.0)
    return sim.q.min(axis=0), sim.q.max(axis=0), np.abs(sim.qd).max(axis=0)


def test_scara2_certificate_excursion_matches_dense_trajectory():
    q0 = np.array([0.0, 0.0])
    cur = np.array([[1.04, 0.30], [1.04, 0.30], [-0.61, 0.04], [-0.61, 0.04]])
    prof = CurrentProfile.uniform(cur, 1.0, 0.05)
    qf = scara2.rest_position_scara2(P, prof, q0)
    unc = ["pc1", "pc2"]
    c = certify_scara2(P, prof, q0, qf, unc, {"pc1": 0.2, "pc2": 0.2})
    ex = c.excursion
    assert ex is not None and len(ex.worst_min) == 2
    lo, hi, sp = _dense(P, prof, q0)
    # the certificate samples every 4 ms substep and every event: positions within 1e-4 rad
    # (extremes at events), speeds within what 4 ms of acceleration can hide
    assert np.allclose(ex.nominal_min, lo, atol=1e-4)
    assert np.allclose(ex.nominal_max, hi, atol=1e-4)
    assert np.all(np.array(ex.nominal_speed) <= sp + 1e-4)
    assert np.allclose(ex.nominal_speed, sp, rtol=0.02)
    for s in box_corners({"pc1": 0.2, "pc2": 0.2}, unc):
        pp = P.replace(pc1=P.pc1 * s[0], pc2=P.pc2 * s[1])
        lo_c, hi_c, sp_c = _dense(pp, prof, q0)
        assert np.all(np.array(ex.worst_min) <= lo_c + 1e-4)
        assert np.all(np.array(ex.worst_max) >= hi_c - 1e-4)
        assert np.all(np.array(ex.worst_speed) >= sp_c * 0.98)
    assert c.to_dict()["excursion"]["worst_max"] == pytest.approx(ex.worst_max)
