"""ROS messages by type name, as plain data and back (what ``ros2 topic echo`` / ``ros2 service
call`` do with rosidl_runtime_py, which is not among the PyPI wheels), for the suite's own
interfaces and the standard ones its nodes use.

    cls = interface_type("ff_msgs/msg/DriveGroupStatus")
    to_data(msg)                       # nested dicts / lists / numbers / strings
    fill(checked(Request), {"action": 0, "client": "/me"})   # ValueError: unknown field, bad value
"""
from __future__ import annotations

from typing import Any, Mapping


def _modules() -> dict[str, Any]:
    """The interface modules the suite's nodes use, by ``pkg/kind`` (imported by name here so that
    the import contracts see them; an interface type named at run time picks one of these)."""
    import action_msgs.msg
    import builtin_interfaces.msg
    import diagnostic_msgs.msg
    import lifecycle_msgs.msg
    import lifecycle_msgs.srv
    import rcl_interfaces.msg
    import rcl_interfaces.srv
    import sensor_msgs.msg
    import std_msgs.msg
    import std_srvs.srv

    import ff_msgs.action
    import ff_msgs.msg
    import ff_msgs.srv

    mods = (action_msgs.msg, builtin_interfaces.msg, diagnostic_msgs.msg, lifecycle_msgs.msg,
            lifecycle_msgs.srv, rcl_interfaces.msg, rcl_interfaces.srv, sensor_msgs.msg, std_msgs.msg,
            std_srvs.srv, ff_msgs.action, ff_msgs.msg, ff_msgs.srv)
    return {m.__name__.replace(".", "/"): m for m in mods}


def interface_type(name: str) -> Any:
    """The Python class of ``pkg/msg/Type`` (or ``pkg/srv/Type``, ``pkg/action/Type``) among the
    interfaces the suite uses (its own ff_msgs and the standard ones its nodes speak)."""
    parts = name.split("/")
    if len(parts) != 3 or parts[1] not in ("msg", "srv", "action") or not all(parts):
        raise ValueError(f"interface type {name!r}: expected pkg/msg/Type, pkg/srv/Type or pkg/action/Type")
    modules = _modules()
    module = modules.get(f"{parts[0]}/{parts[1]}")
    if module is None:
        raise ValueError(f"interface type {name!r} is not one the suite knows ({', '.join(sorted(modules))})")
    try:
        return getattr(module, parts[2])
    except AttributeError:
        raise ValueError(f"{parts[0]}/{parts[1]} has no type {parts[2]!r}") from None


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
