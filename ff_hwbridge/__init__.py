"""ff_hwbridge: CiA 402 / Maxon EPOS CANopen master, bridge node and simulated drive.

Layers: ``protocol`` (CiA 402, object dictionary, units) < ``drive`` (the real master, safety
guard, setpoint player) < ``sim`` (CAN hub, simulated EPOS and arm) < ``cli`` < ``ros`` (the
nodes; only they import rclpy). This package exports the master's API (drive + protocol).
"""
from ff_hwbridge.drive import (AppliedSetpoint, BridgeConfig, CanConfigError, ConfigError, EposError,
                               EposMaster, JointFeedback, PlayerConfig, SafetyGuard, SetpointPlayer,
                               SetpointRejected, load_config, open_bus)
from ff_hwbridge.protocol import DriveUnits, State

__all__ = [
    "AppliedSetpoint", "BridgeConfig", "CanConfigError", "ConfigError", "DriveUnits", "EposError",
    "EposMaster", "JointFeedback", "PlayerConfig", "SafetyGuard", "SetpointPlayer",
    "SetpointRejected", "State", "load_config", "open_bus",
]
