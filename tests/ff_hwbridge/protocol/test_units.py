"""Unit conversions (A <-> per mille <-> mA, increments <-> rad, rpm <-> rad/s) and bridge config."""
from __future__ import annotations

import math

import pytest

from ff_hwbridge.drive.config import ConfigError, load_config
from ff_hwbridge.protocol.units import DriveUnits, UnitsError

U4 = DriveUnits(family="epos4", nominal_current=3.0, torque_constant=0.0267, counts_per_rev=2048,
                gear_ratio=54.0)
U2 = DriveUnits(family="epos2", nominal_current=3.0, torque_constant=0.0267, counts_per_rev=2000,
                gear_ratio=198.0)


def test_current_epos4_per_mille_of_rated_torque():
    assert U4.amps_to_per_mille(3.0) == 1000
    assert U4.amps_to_per_mille(-1.5) == -500
    assert U4.per_mille_to_amps(1000) == pytest.approx(3.0)
    # per mille of 0x6076 rated torque (µNm) = kt·I / (kt·I_nom): kt cancels
    assert U4.rated_torque_raw == round(0.0267 * 3.0 * 1e6)
    i = 2.2
    assert U4.amps_to_per_mille(i) == round(1000 * (0.0267 * i * 1e6) / U4.rated_torque_raw)
    assert U4.amps_to_setpoint(10.0) == 3333
    assert U4.amps_to_per_mille(1e12) == 32767 and U4.amps_to_per_mille(-1e12) == -32768
    assert U4.amps_to_per_mille(float("nan")) == 0


def test_current_epos2_milliamps():
    assert U2.amps_to_setpoint(1.234) == 1234
    assert U2.setpoint_to_amps(-2500) == pytest.approx(-2.5)
    assert U2.ma_to_amps(10000) == pytest.approx(10.0)
    assert U2.current_resolution == 0.001 and U4.current_resolution == pytest.approx(0.003)


def test_setpoint_limit_never_rounds_above_the_limit():
    for units in (U4, U2, DriveUnits(nominal_current=2.9999)):
        for limit in (0.1, 1.0, 3.0, 9.99999, 10.0, 10.0016, 7.77):
            raw = units.setpoint_limit(limit)
            assert units.setpoint_to_amps(raw) <= limit
            assert units.setpoint_to_amps(raw + 1) > limit or raw == 32767
            assert abs(units.setpoint_to_amps(units.amps_to_setpoint(1e9, limit=limit))) <= limit
            assert abs(units.setpoint_to_amps(units.amps_to_setpoint(-1e9, limit=limit))) <= limit
    assert U4.setpoint_limit(float("nan")) == 0


def test_position_and_velocity():
    # one joint revolution = gear_ratio motor revolutions
    assert U4.increments_to_rad(2048 * 54) == pytest.approx(2 * math.pi)
    assert U4.rad_to_increments(1.0) == round(54 * 2048 / (2 * math.pi))
    assert U4.increments_to_rad(U4.rad_to_increments(0.5)) == pytest.approx(0.5, abs=1e-4)
    assert U4.rpm_to_rad_s(60 * 54) == pytest.approx(2 * math.pi)
    assert U4.rad_s_to_rpm(1.0) == round(54 * 60 / (2 * math.pi))
    rev = DriveUnits(direction=-1)
    assert rev.increments_to_rad(100) == pytest.approx(-DriveUnits().increments_to_rad(100))
    assert rev.amps_to_setpoint(1.0) == -DriveUnits().amps_to_setpoint(1.0)
    assert U4.joint_torque(10.0) == pytest.approx(54 * 0.0267 * 10)


def test_from_drive_objects_uses_maxon_units():
    u = DriveUnits.from_drive_objects("epos4", 3000, 26700, 2048, 54)
    assert u.nominal_current == pytest.approx(3.0) and u.torque_constant == pytest.approx(0.0267)
    assert u.nominal_current_ma == 3000 and u.torque_constant_raw == 26700


@pytest.mark.parametrize("bad", [{"family": "epos3"}, {"gear_ratio": 0}, {"counts_per_rev": -1},
                                 {"nominal_current": float("nan")}, {"direction": 2},
                                 {"gear_ratio": "x"}, {"unknown": 1}])
def test_bad_units_are_refused(bad):
    with pytest.raises(UnitsError):
        DriveUnits.from_mapping(bad)


def test_example_configs_load():
    c1 = load_config("config/bridge_epos4_1dof.yaml")
    assert c1.joint_names == ("joint1",) and c1.joints[0].mode_of_operation == 10
    c2 = load_config("config/bridge_sim_scara2.yaml")
    assert [j.node_id for j in c2.joints] == [1, 2]
    assert c2.bus.interface == "remote"
    assert c2.joints[1].units.gear_ratio == 198


@pytest.mark.parametrize("patch,match", [
    ({"joints": []}, "joints"),
    ({"bus": {"channel": "x"}}, "interface"),
    ({"bus": {"interface": "udp_multicast"}}, "udp_multicast"),
    ({"sync_period": 0}, "sync_period"),
    ({"heartbeat_timeout": 0.005}, "heartbeat_timeout"),
    ({"bogus": 1}, "unknown"),
    ({"joints": [{"node_id": 0, "current_limit": 1}]}, "node_id"),
    ({"joints": [{"node_id": 1, "current_limit": -1}]}, "current_limit"),
    ({"joints": [{"node_id": 1, "current_limit": 1}, {"node_id": 1, "current_limit": 1}]}, "differ"),
    ({"joints": [{"node_id": 1, "current_limit": 1, "family": "epos9"}]}, "family"),
])
def test_bad_config_is_refused_with_a_clear_message(patch, match):
    data = {"bus": {"interface": "virtual", "channel": "c"},
            "joints": [{"node_id": 1, "current_limit": 10.0}]}
    data.update(patch)
    with pytest.raises(ConfigError, match=match):
        load_config(data)
