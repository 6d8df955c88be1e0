"""The player process converts currents on the base the master resolved at configure."""
from __future__ import annotations

import dataclasses
from types import SimpleNamespace

from ff_hwbridge.drive.player_process import ProcessPlayer
from tests.support.canopen_helpers import mini_config


def test_the_child_gets_the_units_the_master_took_from_the_drive():
    """scaling_source: drive on a drive whose nominal current is 4 A where the config says 3 A:
    the child's config carries the drive's 4 A base, so 1 A is 250 per mille as the master sends
    it, and the limit's raw clamp is the master's (10 A = 2500 per mille, not 3333)."""
    cfg = mini_config("unused", scaling_source="drive")
    drive_units = dataclasses.replace(cfg.joints[0].units, nominal_current=4.0)
    master = SimpleNamespace(config=cfg, units=(drive_units,))
    child_cfg = ProcessPlayer._resolved_config(SimpleNamespace(master=master))  # type: ignore[arg-type]
    u = child_cfg.joints[0].units
    assert u == drive_units and cfg.joints[0].units.nominal_current == 3.0
    assert u.amps_to_setpoint(1.0) == drive_units.amps_to_setpoint(1.0) == 250
    assert u.setpoint_limit(child_cfg.joints[0].current_limit) == 2500
    # everything else as configured
    assert dataclasses.replace(child_cfg, joints=cfg.joints) == cfg
