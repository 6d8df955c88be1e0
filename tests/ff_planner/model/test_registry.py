"""The model registry: names, joint counts, parameter classes and the models' functions."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.model import arm1dof, params, scara2
from ff_planner.model.params import ParameterError, default_params, n_joints
from ff_planner.model.profile import CurrentProfile
from ff_planner.model.registry import MODELS, ModelSpec, model_spec
from ff_planner.model.sensitivity import sensitivities
from ff_planner.model.simulate import rest_position, simulate

PROFILES = {"arm1dof": CurrentProfile.uniform([3.0, -4.0, 1.0], 1.0),
            "scara2": CurrentProfile.uniform([[3.0, 1.0], [-2.0, 0.5], [1.0, -1.0], [0.0, 0.2]], 1.0)}
Q0 = {"arm1dof": np.array([0.1]), "scara2": np.array([-0.5, 0.0])}


def test_names_joints_and_parameter_classes_agree_with_params():
    assert MODELS == tuple(params.MODELS) == ("arm1dof", "scara2")
    for name in MODELS:
        spec = model_spec(name)
        assert isinstance(spec, ModelSpec) and spec.name == name
        assert spec.params_class is params.MODELS[name] is type(default_params(name))
        assert spec.n_joints == spec.params_class.n_joints == n_joints(name)
    assert model_spec("arm1dof").n_joints == 1 and model_spec("scara2").n_joints == 2


def test_unknown_model_is_refused_with_its_error_name():
    with pytest.raises(ParameterError, match="known models: arm1dof, scara2") as e:
        model_spec("scara3")
    assert e.value.code == "UNKNOWN_MODEL"


@pytest.mark.parametrize("name", MODELS)
def test_spec_functions_are_what_simulate_and_sensitivity_call(name):
    spec, p, prof, q0 = model_spec(name), default_params(name), PROFILES[name], Q0[name]
    nj = spec.n_joints
    r = spec.simulate(p, prof, q0, np.zeros(nj))
    ref = simulate(p, prof, q0)
    assert r.q_f.shape == (nj,) and np.array_equal(r.q_f, ref.q_f)
    assert np.array_equal(r.qd_f, ref.qd_f)
    rest = spec.rest_position(p, prof, q0, np.zeros(nj))
    assert rest.shape == (nj,) and np.all(np.isfinite(rest))
    assert np.array_equal(rest, rest_position(p, prof, q0))
    assert spec.sensitivities(p, prof, q0, p.friction_keys, "exact") == sensitivities(p, prof, q0)
    q, qd = spec.advance(p, q0, np.zeros(nj), prof.currents[0], 1e-3)
    assert q.shape == qd.shape == (nj,) and np.all(qd != 0.0)


def test_arm1dof_advance_in_registry_form_equals_the_scalar_form():
    p = default_params("arm1dof")
    q, qd = model_spec("arm1dof").advance(p, [0.2], [0.5], [3.0], 0.01)
    assert (float(q[0]), float(qd[0])) == arm1dof.advance(p, 0.2, 0.5, 3.0, 0.01)
    with pytest.raises(ParameterError, match="q needs 1 value"):
        model_spec("arm1dof").advance(p, [0.2, 0.0], [0.5], [3.0], 0.01)


def test_scara2_spec_uses_the_scara2_functions():
    spec = model_spec("scara2")
    assert spec.simulate is scara2.simulate_scara2 and spec.advance is scara2.advance
    assert spec.sensitivities is scara2.sensitivities_scara2
    assert spec.rest_position is scara2.rest_position_scara2
