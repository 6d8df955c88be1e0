"""The simulation behind the master, for tests and demos: the loopback CAN hub (``can_hub``),
its SYNC timer (``sync``), the emulated EPOS (``drive``), the arm plant on the planner's model
(``arm``), arm + drives on one bus (``rig``) and that rig as a child process (``rig_process``)."""
from ff_hwbridge.sim.arm import ArmState, JointPort, SimArm, joint_param, planner_advance
from ff_hwbridge.sim.can_hub import CanHub, start_hub
from ff_hwbridge.sim.drive import DriveConfig, NullPlant, SetpointRecord, SimConfigError, SimEpos
from ff_hwbridge.sim.rig import RigConfig, SimRig, run_command, write_record
from ff_hwbridge.sim.rig_process import RigError, RigProcess, free_port, rig_master_config
from ff_hwbridge.sim.sync import SyncSource, SyncSourceStats

__all__ = [
    "ArmState", "CanHub", "DriveConfig", "JointPort", "NullPlant", "RigConfig", "RigError",
    "RigProcess", "SetpointRecord", "SimArm", "SimConfigError", "SimEpos", "SimRig", "SyncSource",
    "SyncSourceStats", "free_port",
    "joint_param", "planner_advance", "rig_master_config", "run_command", "start_hub", "write_record",
]
