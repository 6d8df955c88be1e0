"""The EPOS4 EDS shipped with the simulated drive (``ff_hwbridge/sim/epos4.eds``) describes the
objects the simulated EPOS4 serves: same indices, sub-indices, data types and access; maxon's
factory defaults where the drive has them at power-on."""
from __future__ import annotations

from importlib import resources

import canopen
import pytest
from canopen.objectdictionary import UNSIGNED16, ODVariable
from canopen.sdo import SdoAbortedError

from ff_hwbridge.protocol import epos_od
from ff_hwbridge.sim.drive import DriveConfig, SimEpos, build_object_dictionary, eds_objects
from tests.support.canopen_helpers import open_network

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


def test_every_object_the_simulated_drive_serves_is_in_the_eds_with_its_data_type(eds):
    """What the simulated EPOS4 serves is checked against the EDS (canopen's import), not against
    the suite's own table: an object the EDS lacks is refused by its SDO server."""
    served = eds_objects()
    assert served == {(v.index, v.subindex): v.data_type for v in _variables(eds)}
    sim = build_object_dictionary(DriveConfig(node_id=5))
    for v in _variables(sim):
        assert served.get((v.index, v.subindex)) == v.data_type, f"0x{v.index:04X}:{v.subindex:02X}"


def test_no_rxpdo_event_timer_in_the_eds_but_in_the_masters_view(eds):
    """maxon's EPOS4 EDS lists no RxPDO event timer (0x1400+n:05): neither does the simulated
    drive; the master's view keeps 0x1400:05 (written where a drive has it, optional)."""
    for n in range(4):
        assert 5 not in eds[0x1400 + n].subindices and eds[0x1400 + n][0].default == 2
        assert 5 in eds[0x1800 + n].subindices                  # TxPDO event timer: listed
    assert 5 in epos_od.build_object_dictionary("epos4", 1)[0x1400].subindices


def test_the_sdo_server_refuses_what_the_eds_lacks_even_if_the_dictionary_had_it():
    """The EDS is the gate: an object slipped into the simulated drive's dictionary but absent
    from the EDS answers abort 0x06020000 (object) / 0x06090011 (sub-index)."""
    chan = "test-eds-gate"
    net_s, net_m = open_network(chan), open_network(chan)
    drive = SimEpos(DriveConfig(node_id=5))
    extra = ODVariable("Not in the EDS", 0x2100, 0)
    extra.data_type, extra.access_type, extra.default = UNSIGNED16, "rw", 7
    drive.node.object_dictionary.add_object(extra)
    rec = drive.node.object_dictionary[0x1400]
    sub5 = ODVariable("Event timer", 0x1400, 5)
    sub5.data_type, sub5.access_type, sub5.default = UNSIGNED16, "rw", 0
    rec.add_member(sub5)
    drive.attach(net_s)
    drive.boot()
    node = canopen.RemoteNode(5, canopen.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = 2.0
    net_m.add_node(node)
    try:
        for (index, sub), code in (((0x2100, 0), 0x06020000), ((0x1400, 5), 0x06090011)):
            with pytest.raises(SdoAbortedError) as e:
                node.sdo.upload(index, sub)
            assert e.value.code == code
            with pytest.raises(SdoAbortedError) as e:
                node.sdo.download(index, sub, b"\x01\x00")
            assert e.value.code == code
        assert node.sdo.upload(0x1000, 0)[:2] == b"\x92\x01"      # 402: served as before
    finally:
        drive.close()
        net_m.disconnect()
        net_s.disconnect()
