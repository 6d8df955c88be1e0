"""The bus opener refuses settings that would leave loopback."""
from __future__ import annotations

import pytest

from ff_hwbridge.drive.bus import CanConfigError, normalise_bus_config


def test_bus_config_checks():
    with pytest.raises(CanConfigError, match="udp_multicast"):
        normalise_bus_config({"interface": "udp_multicast", "channel": "239.0.0.1"})
    with pytest.raises(CanConfigError, match="loopback"):
        normalise_bus_config({"interface": "remote", "channel": "ws://10.0.0.1:54701/"})
    with pytest.raises(CanConfigError, match="ws://"):
        normalise_bus_config({"interface": "remote", "channel": "127.0.0.1:54701"})
    with pytest.raises(CanConfigError, match="interface"):
        normalise_bus_config({"channel": "vcan0"})
    assert normalise_bus_config({"interface": "virtual", "channel": "x"})["bitrate"] == 1_000_000
