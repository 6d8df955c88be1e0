"""The EPOS4 EDS shipped with the simulated drive (``ff_hwbridge/sim/epos4.eds``) describes the
objects the simulated EPOS4 serves: same indices, sub-indices, data types and access; maxon's
factory defaults where the drive has them at power-on."""
from __future__ import annotations

from importlib import resources

import canopen
import pytest
from canopen.objectdictionary import ODVariable

from ff_hwbridge.sim.drive import DriveConfig, build_object_dictionary

EDS = resources.files("ff_hwbridge.sim") / "epos4.eds"


def _variables(od):
    for obj in od.values():
        if isinstance(obj, ODVariable):
            yield obj
        else:
            yield from obj.values()


@pytest.fixture(scope="module")
def eds():
    return canopen.import_od(str(EDS), 5)


def test_eds_and_simulated_drive_have_the_same_objects(eds):
    sim = build_object_dictionary(DriveConfig(node_id=5))
    assert sorted(eds.indices) == sorted(sim.indices)
    eds_vars = {(v.index, v.subindex): v for v in _variables(eds)}
    sim_vars = {(v.index, v.subindex): v for v in _variables(sim)}
    assert eds_vars.keys() == sim_vars.keys()
    for key, v in sim_vars.items():
        e = eds_vars[key]
        assert (e.data_type, e.access_type, bool(e.pdo_mappable)) == \
            (v.data_type, v.access_type, bool(v.pdo_mappable)), f"0x{key[0]:04X}:{key[1]:02X}"


def test_eds_carries_maxons_factory_defaults(eds):
    assert eds[0x1000].default & 0xFFFF == 402 and eds[0x1018][1].default == 0xFB
    assert (eds[0x605A].default, eds[0x605E].default, eds[0x6007].default,
            eds[0x1029][1].default) == (6, 2, 3, 0)
    assert eds[0x6085].default == 10000
    assert (eds[0x60C2][1].default, eds[0x60C2][2].default) == (0, -3)
    assert eds[0x6076].default == 0 and eds[0x3001][5].default == 0     # set them on the drive
    assert eds[0x1400][1].default == 0x205                               # $NODEID + 0x200
    assert eds[0x1800][1].default == 0x40000185                          # bit 30: no RTR
    assert eds[0x1801][1].default == 0xC0000285                          # not valid
    assert eds[0x6502].default & (1 << 9)                                # CST


def test_the_simulated_drive_powers_on_with_the_eds_reactions(eds):
    sim = build_object_dictionary(DriveConfig(node_id=5))
    for index, sub in ((0x605A, 0), (0x605E, 0), (0x6007, 0), (0x1029, 1), (0x6085, 0),
                       (0x60C2, 1), (0x60C2, 2), (0x1800, 1), (0x1400, 1), (0x1017, 0)):
        s, e = (sim[index] if sub == 0 and isinstance(sim[index], ODVariable) else sim[index][sub],
                eds[index] if sub == 0 and isinstance(eds[index], ODVariable) else eds[index][sub])
        assert s.default == e.default, f"0x{index:04X}:{sub:02X}"
