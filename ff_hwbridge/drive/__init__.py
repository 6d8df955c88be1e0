"""The real CANopen master for Maxon EPOS drives (no simulation, no ROS): the bus opener
(``bus``), the bridge configuration (``config``), the master (``epos``, composed of ``boot``,
``state_machine``, ``tpdo``, ``watchdogs`` and ``rpdo`` on the shared ``node`` state), the safety
guard (``safety``), the SYNC producer (``sync_sender``) and what the master sees of SYNC
(``sync_watch``), the feedback snapshots (``feedback``), the SYNC-cycle scheduler (``cycle``),
the one setpoint player (``player``: stamped setpoint → guard → units → RPDO of its SYNC cycle,
in this process or in its own, ``player_process``) and the real-time set-up (``realtime``)."""
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
