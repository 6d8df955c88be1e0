"""Write ``ff_hwbridge/sim/epos4.eds`` from the simulated EPOS4's object table
(``ff_hwbridge.protocol.epos_od``) with maxon's factory defaults, after a change of that table:
``.venv/bin/python tests/ff_hwbridge/sim/write_eds.py`` (``test_eds.py`` checks the two agree)."""
from pathlib import Path

from canopen.objectdictionary import ODRecord, ODVariable

from ff_hwbridge.protocol import epos_od

od = epos_od.build_object_dictionary("epos4", 1, drive=True, device_name="EPOS4")

def nid(base):  # a $NODEID expression
    return f"$NODEID+0x{base:X}"

FACTORY = {  # (index, sub) -> DefaultValue text (maxon EPOS4 EDS 50/5, fw 0x0170; DESIGN notes)
    (0x1014, 0): nid(0x80),
    (0x1018, 4): "0x0", (0x1018, 2): "0x0", (0x1018, 3): "0x0",
    (0x3001, 1): "5000", (0x3001, 2): "15000", (0x3001, 5): "0", (0x6076, 0): "0",
    (0x3000, 5): "0",
    (0x605A, 0): "6", (0x605E, 0): "2", (0x6007, 0): "3", (0x1029, 1): "0",
    (0x6085, 0): "10000", (0x60C2, 1): "0", (0x60C2, 2): "-3",
    (0x1008, 0): "EPOS4",
}
for n in range(4):
    FACTORY[(0x1400 + n, 1)] = nid((0x200 + 0x100 * n) | (0 if n == 0 else 0x80000000))
    FACTORY[(0x1800 + n, 1)] = nid((0x180 + 0x100 * n) | 0x40000000 | (0 if n == 0 else 0x80000000))
    FACTORY[(0x1800 + n, 3)] = "10" if n == 0 else "0"

ACCESS = {"rw": "rw", "ro": "ro", "const": "const", "wo": "wo"}

def var_lines(v: ODVariable, name=None):
    d = FACTORY.get((v.index, v.subindex))
    if d is None:
        d = v.default
        if isinstance(d, str):
            pass
        elif d is None:
            d = 0
        else:
            d = f"0x{d:X}" if d >= 0 and (v.data_type in (7, 6, 5) and d > 9) else str(d)
    lines = [f"ParameterName={name or v.name}", "ObjectType=0x7",
             f"DataType=0x{v.data_type:04X}", f"AccessType={ACCESS[v.access_type]}",
             f"DefaultValue={d}", f"PDOMapping={int(bool(v.pdo_mappable))}"]
    return lines

out = []
mand, opt, manu = [], [], []
for idx in sorted(od.indices):
    (mand if idx in (0x1000, 0x1001, 0x1018) else manu if 0x2000 <= idx < 0x6000 else opt).append(idx)
out.append("; Maxon EPOS4 (CANopen, CiA 402) object dictionary as the suite's simulated EPOS4 implements it.")
out.append("; Written for the suite (not maxon's file): indices, data types, access and factory defaults as in")
out.append("; maxon's EPOS4 EDS (50/5 module, firmware 0x0170) and the EPOS4 Firmware Specification (rel8234),")
out.append("; limited to the objects ff_hwbridge.sim.drive serves (written by tests/ff_hwbridge/sim/write_eds.py).")
out.append("; Motor data defaults are the factory values")
out.append("; (0x6076, 0x3001:05 = 0): read them from the drive, never assume them.")
out.append("")
out += ["[FileInfo]", "FileName=epos4.eds", "FileVersion=1", "FileRevision=0", "EDSVersion=4.0",
        "Description=maxon EPOS4 (objects of the ff suite's simulated drive)", "CreatedBy=ff suite",
        "", "[DeviceInfo]", "VendorName=maxon motor ag", "VendorNumber=0x000000FB",
        "ProductName=EPOS4", "ProductNumber=0x60500000", "RevisionNumber=0x00010000",
        "BaudRate_10=0", "BaudRate_20=0", "BaudRate_50=1", "BaudRate_125=1", "BaudRate_250=1",
        "BaudRate_500=1", "BaudRate_800=1", "BaudRate_1000=1", "SimpleBootUpMaster=0",
        "SimpleBootUpSlave=1", "Granularity=8", "DynamicChannelsSupported=0", "GroupMessaging=0",
        "NrOfRXPDO=4", "NrOfTXPDO=4", "LSS_Supported=1", "", "[DummyUsage]"]
out += [f"Dummy000{i}=0" for i in range(1, 8)] + [""]
for title, idxs in (("MandatoryObjects", mand), ("OptionalObjects", opt), ("ManufacturerObjects", manu)):
    out.append(f"[{title}]")
    out.append(f"SupportedObjects={len(idxs)}")
    out += [f"{i + 1}=0x{x:04X}" for i, x in enumerate(idxs)]
    out.append("")
    for idx in idxs:
        obj = od[idx]
        if isinstance(obj, ODVariable):
            out.append(f"[{idx:04X}]")
            out += var_lines(obj)
            out.append("")
            continue
        out.append(f"[{idx:04X}]")
        out += [f"ParameterName={obj.name}", f"ObjectType=0x{9 if isinstance(obj, ODRecord) else 8:X}",
                f"SubNumber={len(obj.subindices)}", ""]
        for sub in sorted(obj.subindices):
            v = obj[sub]
            out.append(f"[{idx:04X}sub{sub:X}]")
            out += var_lines(v)
            out.append("")
target = Path(__file__).resolve().parents[3] / "ff_hwbridge" / "sim" / "epos4.eds"
target.write_text("\n".join(out))
print(f"{target}: {len(od.indices)} objects")
