"""The real CANopen master for Maxon EPOS drives (no simulation, no ROS): the bus opener
(``bus``), the bridge configuration (``config``), the master (``epos``), the safety guard
(``safety``), what the master sees of SYNC (``sync_watch``), the stamp scheduler (``scheduler``),
the SYNC-cycle scheduler (``cycle``) and the setpoint player that composes them (``player``:
stamped setpoint → guard → units → RPDO for its SYNC cycle, or at its stamp)."""
from ff_hwbridge.drive.bus import CanConfigError, normalise_bus_config, open_bus, open_network
from ff_hwbridge.drive.cycle import CycleScheduler
from ff_hwbridge.drive.config import (BridgeConfig, BusConfig, ConfigError, JointConfig, config_from_mapping,
                                      load_config, with_bus)
from ff_hwbridge.drive.epos import EposError, EposMaster, JointFeedback, PreparedCommand
from ff_hwbridge.drive.player import AppliedSetpoint, PlayerConfig, SetpointPlayer, SetpointRejected
from ff_hwbridge.drive.safety import SafeCommand, SafetyConfigError, SafetyGuard
from ff_hwbridge.drive.scheduler import StampScheduler, SwitchStats
from ff_hwbridge.drive.sync_watch import SyncStats, SyncWatch

__all__ = [
    "AppliedSetpoint", "BridgeConfig", "BusConfig", "CanConfigError", "ConfigError", "CycleScheduler",
    "EposError",
    "EposMaster", "JointConfig", "JointFeedback", "PlayerConfig", "PreparedCommand", "SafeCommand",
    "SafetyConfigError", "SafetyGuard", "SetpointPlayer", "SetpointRejected", "StampScheduler",
    "SwitchStats", "SyncStats", "SyncWatch", "config_from_mapping", "load_config", "normalise_bus_config", "open_bus",
    "open_network", "with_bus",
]
