"""ROS messages by type name, as plain data and back (what ``ros2 topic echo`` / ``ros2 service
call`` do with rosidl_runtime_py, which is not among the PyPI wheels).

    cls = interface_type("ff_msgs/msg/DriveGroupStatus")
    to_data(msg)                       # nested dicts / lists / numbers / strings
    fill(checked(Request), {"action": 0, "client": "/me"})   # ValueError: unknown field, bad value
"""
from __future__ import annotations

import importlib
from typing import Any, Mapping


def interface_type(name: str) -> Any:
    """The Python class of ``pkg/msg/Type`` (or ``pkg/srv/Type``, ``pkg/action/Type``)."""
    parts = name.split("/")
    if len(parts) != 3 or parts[1] not in ("msg", "srv", "action") or not all(parts):
        raise ValueError(f"interface type {name!r}: expected pkg/msg/Type, pkg/srv/Type or pkg/action/Type")
    pkg, kind, typ = parts
    try:
        # an interface type named at run time (ros2 topic echo does the same): no contract to see
        module = importlib.import_module(f"{pkg}.{kind}")  # noqa: TID251
    except ImportError:
        raise ValueError(f"interface package {pkg!r} is not installed in this Python") from None
    try:
        return getattr(module, typ)
    except AttributeError:
        raise ValueError(f"{pkg}/{kind} has no type {typ!r}") from None


def _is_message(value: Any) -> bool:
    return hasattr(type(value), "get_fields_and_field_types")


def to_data(msg: Any) -> Any:
    """A message as nested dicts (fields in their order), lists, numbers and strings."""
    if _is_message(msg):
        return {f: to_data(getattr(msg, f)) for f in type(msg).get_fields_and_field_types()}
    if isinstance(msg, (bytes, bytearray)):
        return list(msg)
    if isinstance(msg, (list, tuple)) or hasattr(msg, "tolist"):
        seq = msg.tolist() if hasattr(msg, "tolist") else msg
        return [to_data(v) for v in seq]
    return msg


def checked(cls: Any) -> Any:
    """A new message of ``cls`` whose fields check their values' types when set."""
    return cls(check_fields=True)


def fill(msg: Any, data: Mapping[str, Any]) -> Any:
    """Set ``msg``'s fields from ``data`` (nested mappings for nested messages); returns ``msg``.
    ValueError naming the field for an unknown field or a value of the wrong type (give ``msg``
    as :func:`checked` makes it; rclpy checks nothing otherwise)."""
    if not isinstance(data, Mapping):
        raise ValueError(f"expected a mapping of field values for {type(msg).__name__}, got {data!r}")
    fields = type(msg).get_fields_and_field_types()
    for key, value in data.items():
        if key not in fields:
            raise ValueError(f"{type(msg).__name__} has no field {key!r}; fields: {', '.join(fields)}")
        current = getattr(msg, key)
        try:
            if _is_message(current) and isinstance(value, Mapping):
                setattr(msg, key, fill(checked(type(current)), value))
            else:
                setattr(msg, key, value)
        except (AssertionError, TypeError, ValueError) as exc:
            raise ValueError(f"field {key!r} ({fields[key]}): {value!r} does not fit ({exc})") from None
    return msg
