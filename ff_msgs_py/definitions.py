"""Message definitions as text (``ros2msg``, with dependencies) for bag files: ff_msgs and ROS's own.

A rosbag2/MCAP file carries, per topic, the definition of its type so that any reader can decode
it: the type's own fields, then each type it uses, one section each, separated by a line of 80
``=`` and headed ``MSG: pkg/Type`` (the layout rosbag2 writes: its local message definition
source names each dependency as the ``.msg`` field names it, without the ``msg``/``action``
folder; Foxglove's decoder and ``rosbags`` resolve fields against exactly these headers). ROS's standard types come from
the ``rosbags`` package's Jazzy type store (the [record] extra); the ff_msgs texts from this
package's interface files, split the way rosidl splits them (``.srv`` → ``_Request`` /
``_Response``, ``.action`` → ``_Goal`` / ``_Result`` / ``_Feedback`` and the feedback topic's
``_FeedbackMessage`` = goal id + feedback). ``rosbags`` cannot generate those itself: its
generator accepts nested types only under ``pkg/msg/``, and the action feedback message nests
``ff_msgs/action/ExecuteProfile_Feedback``. Fields name nested message types in the short form
``pkg/Type`` and the action's own types in full, each exactly as its section header names it.
"""
from __future__ import annotations

import re
import sys
from functools import lru_cache
from pathlib import Path
from typing import Any

SEPARATOR = "=" * 80
PACKAGE = "ff_msgs"
PRIMITIVES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
                        "int32", "uint32", "int64", "uint64", "string", "wstring"})
_FIELD = re.compile(r"^\s*([A-Za-z][\w/]*)(?:\[[^\]]*\])?\s+([A-Za-z]\w*)")


def interface_dir() -> Path:
    """The folder holding ff_msgs' msg/, srv/, action/ files (this package, else the install's share/)."""
    here = Path(__file__).resolve().parent
    if (here / "msg").is_dir():
        return here
    return Path(sys.prefix) / "share" / PACKAGE


def _split(text: str, parts: int, path: Path) -> list[str]:
    out = re.split(r"^---[ \t]*$", text, flags=re.MULTILINE)
    if len(out) != parts:
        raise ValueError(f"{path} has {len(out)} parts separated by '---', expected {parts}")
    return [s.strip("\n") + "\n" for s in out]


@lru_cache(maxsize=1)
def ff_definitions() -> dict[str, str]:
    """Own text (no dependencies) of every ff_msgs type, by full name, e.g. ``ff_msgs/msg/CurrentSetpoint``."""
    root = interface_dir()
    out: dict[str, str] = {}
    for f in sorted((root / "msg").glob("*.msg")):
        out[f"{PACKAGE}/msg/{f.stem}"] = f.read_text(encoding="utf-8")
    for f in sorted((root / "srv").glob("*.srv")):
        req, res = _split(f.read_text(encoding="utf-8"), 2, f)
        out[f"{PACKAGE}/srv/{f.stem}_Request"] = req
        out[f"{PACKAGE}/srv/{f.stem}_Response"] = res
    for f in sorted((root / "action").glob("*.action")):
        goal, result, feedback = _split(f.read_text(encoding="utf-8"), 3, f)
        base = f"{PACKAGE}/action/{f.stem}"
        out[f"{base}_Goal"], out[f"{base}_Result"], out[f"{base}_Feedback"] = goal, result, feedback
        # the feedback topic's message (rosidl's action wrapper): goal id + the feedback
        out[f"{base}_FeedbackMessage"] = ("unique_identifier_msgs/UUID goal_id\n"
                                          f"{base}_Feedback feedback\n")
    if not out:
        raise FileNotFoundError(f"no ff_msgs interface files under {root}")
    return out


@lru_cache(maxsize=1)
def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore   # optional dependency ([record] extra)

    return get_typestore(Stores.ROS2_JAZZY)


def _standard_sections(name: str) -> dict[str, str]:
    """{full name: own text} for a standard type and everything it uses (rosbags' Jazzy store)."""
    store = _typestore()
    if name not in store.fielddefs:
        raise KeyError(f"no definition known for message type {name!r}")
    text, _digest = store.generate_msgdef(name, ros_version=2)
    sections = re.split(rf"^{SEPARATOR}$", text, flags=re.MULTILINE)
    out = {name: sections[0].strip("\n") + "\n"}
    for sec in sections[1:]:
        head, _, body = sec.strip("\n").partition("\n")
        sub = head.removeprefix("MSG:").strip()
        if sub.count("/") == 1:
            sub = sub.replace("/", "/msg/")
        out[sub] = body.strip("\n") + "\n"
    return out


def _resolve(short: str, owner: str) -> str:
    """Field type ``pkg/Type`` (or ``Type`` of the owner's package) -> the full name."""
    pkg, _, typ = short.rpartition("/")
    pkg = pkg or owner.split("/")[0]
    if "/" in pkg:       # already full: pkg/sub/Type
        return short
    if pkg == PACKAGE:
        for sub in ("msg", "action", "srv"):
            if f"{PACKAGE}/{sub}/{typ}" in ff_definitions():
                return f"{PACKAGE}/{sub}/{typ}"
    return f"{pkg}/msg/{typ}"


def _used_types(text: str, owner: str) -> list[str]:
    """Full names of the non-primitive field types in a definition (constants are primitives)."""
    used = []
    for line in text.splitlines():
        m = _FIELD.match(line.split("#", 1)[0])
        if m and m.group(1).split("<=")[0] not in PRIMITIVES:
            used.append(_resolve(m.group(1), owner))
    return used


def message_definition(name: str) -> str:
    """The ``ros2msg`` text of message type ``name`` (e.g. ``sensor_msgs/msg/JointState``) with every
    type it uses; KeyError for a type neither ff_msgs nor rosbags' Jazzy store defines."""
    ff = ff_definitions()
    if not name.startswith(PACKAGE + "/"):
        sections = _standard_sections(name)
    else:
        if name not in ff:
            raise KeyError(f"ff_msgs defines no message {name!r}")
        sections, todo = {}, [name]
        while todo:
            cur = todo.pop(0)
            if cur in sections:
                continue
            if cur in ff:
                sections[cur] = ff[cur]
                todo += _used_types(ff[cur], cur)
            else:
                sections.update({k: v for k, v in _standard_sections(cur).items() if k not in sections})
    own = sections.pop(name)
    return own + "".join(f"{SEPARATOR}\nMSG: {section_name(k)}\n{v}" for k, v in sections.items())


def section_name(full: str) -> str:
    """The header of a dependency's section: ``pkg/msg/Type`` -> ``pkg/Type``, as rosbag2 writes
    it; an action's own message (``pkg/action/X_Feedback``, nested in the feedback topic's
    message) keeps its full name, as the field that uses it names it: rosidl hashes the type
    under that name, and a reader that checks the recorded type hash (``rosbags``) must see it."""
    pkg, sub, typ = full.split("/")
    return full if sub == "action" else f"{pkg}/{typ}"
