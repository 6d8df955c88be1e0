"""Check a URDF against its cell before Pinocchio reads it.

What the suite handles: a serial chain whose moving joints are revolute (or continuous), the
child link of every joint that moves or is held carrying an ``<inertial>`` with a positive mass.
Held joints may be of any non-floating type (they are locked). The URDF's ``<dynamics damping
friction>`` are ignored: friction comes from the cell (Eq. 9). Names in the cell must be joints
of the URDF, and every non-fixed URDF joint must be in the cell (moving or held).
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from ff_planner.arm.cell import Cell
from ff_planner.arm.errors import ArmConfigError

_MOVING_TYPES = ("revolute", "continuous")
_HOLDABLE_TYPES = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    type: str
    parent: str
    child: str


@dataclass(frozen=True)
class UrdfInfo:
    """The parts of a URDF the checks need: its text, robot name, joints and links with mass."""

    text: str
    robot: str
    joints: dict[str, UrdfJoint]
    link_mass: dict[str, Optional[float]]   # None: no <inertial>


def read_urdf(path: Path) -> UrdfInfo:
    """Parse a URDF (XML); ArmConfigError if it cannot be read or is not a URDF robot."""
    src = path.name
    try:
        text = path.read_text()
    except OSError as exc:
        raise ArmConfigError(src, None, "(file)", f"cannot be read: {exc.strerror or exc}") from None
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ArmConfigError(src, None, "(file)", f"is not valid XML: {exc}") from None
    if root.tag != "robot":
        raise ArmConfigError(src, None, "(file)", f"is not a URDF (root element <{root.tag}>, "
                                                  "expected <robot>)")
    masses: dict[str, Optional[float]] = {}
    for link in root.findall("link"):
        inert = link.find("inertial")
        mass = None
        if inert is not None:
            m = inert.find("mass")
            try:
                mass = float(m.get("value", "nan")) if m is not None else math.nan
            except ValueError:
                mass = math.nan
        masses[str(link.get("name"))] = mass
    joints: dict[str, UrdfJoint] = {}
    for j in root.findall("joint"):
        parent = j.find("parent")
        child = j.find("child")
        name = str(j.get("name"))
        if parent is None or child is None:
            raise ArmConfigError(src, name, "parent/child", "is missing")
        joints[name] = UrdfJoint(name, str(j.get("type")), str(parent.get("link")),
                                 str(child.get("link")))
    return UrdfInfo(text, str(root.get("name", path.stem)), joints, masses)


def check_urdf(info: UrdfInfo, cell: Cell, src: str) -> None:
    """Refuse a URDF / cell pair the suite cannot handle (one ArmConfigError, first problem)."""
    for name in cell.joints:
        if name not in info.joints:
            known = [n for n, j in info.joints.items() if j.type != "fixed"]
            raise ArmConfigError(cell.source, name, "(name)", f"is not a joint of {src}; its "
                                                              f"joints are {', '.join(known)}")
    for name, j in info.joints.items():
        if j.type == "fixed":
            continue
        if name not in cell.joints:
            raise ArmConfigError(cell.source, name, "(entry)", f"is missing: {src} has this "
                                                               f"{j.type} joint; list it as moving "
                                                               "or held (hold: brake, position: ...)")
        jc = cell.joints[name]
        allowed = _MOVING_TYPES if jc.moves else _HOLDABLE_TYPES
        if j.type not in allowed:
            what = "a moving joint" if jc.moves else "a held joint"
            raise ArmConfigError(src, name, "type", f"{j.type} is not supported for {what} "
                                                    f"(supported: {', '.join(allowed)})")
        mass = info.link_mass.get(j.child)
        if mass is None:
            raise ArmConfigError(src, name, f"child link '{j.child}' <inertial>",
                                 "is missing: the dynamics need the mass and inertia of every "
                                 "link a joint moves")
        if not (math.isfinite(mass) and mass > 0.0):
            raise ArmConfigError(src, name, f"child link '{j.child}' <inertial><mass>",
                                 f"must be > 0 kg, got {mass}")
    children: dict[str, list[str]] = {}
    for j in info.joints.values():
        children.setdefault(j.parent, []).append(j.name)
    for parent, names in children.items():
        movers = [n for n in names if n in cell.joints and cell.joints[n].moves]
        if len(movers) > 1:
            raise ArmConfigError(src, movers[1], "(structure)", f"shares parent link '{parent}' "
                                                                f"with moving joint '{movers[0]}': "
                                                                "only serial chains are supported")
