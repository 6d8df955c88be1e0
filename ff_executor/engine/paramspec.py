"""One declaration per node parameter (:class:`ParamSpec`), and what follows from a table of them.

A :class:`ParamTable` is the single source of a node's parameters: its default values (what the
node declares), units, ranges, allowed values and descriptions. From it follow

- :meth:`ParamTable.defaults`: name -> default, as ROS parameters and YAML hold them (lists);
- :meth:`ParamTable.yaml_file`: a ``<node>: ros__parameters:`` YAML file of the defaults, one
  commented line per parameter (``--params-file`` ready);
- :meth:`ParamTable.markdown`: a Markdown table for the docs.

Plain Python: the ROS node turns each spec into a ParameterDescriptor itself. Units are SI
(s, A, rad, rad/s, Hz); ``unit`` is empty for counts, names and switches.
"""
from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass, field
from typing import Any, Iterator, Mapping, Optional, Sequence, Union

Scalar = Union[bool, int, float, str]
Value = Union[Scalar, tuple[str, ...], tuple[float, ...], tuple[int, ...]]


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of a node.

    name:          the ROS parameter name.
    default:       its value when no parameters file sets it (a tuple for a list parameter).
    unit:          SI unit of the value (per element for lists), "" when it has none.
    description:   what it does, in one sentence, without the unit.
    range:         (from, to), inclusive, for numbers; None = no range.
    choices:       the allowed strings, for a string parameter with a fixed set; () = any.
    read_at_start: True = read once when the node starts (read-only at runtime); False = read at
                   each use, so a runtime change applies at once.
    """

    name: str
    default: Value
    unit: str
    description: str
    range: Optional[tuple[float, float]] = None
    choices: tuple[str, ...] = ()
    read_at_start: bool = True

    def __post_init__(self) -> None:
        v = self.default
        if isinstance(v, list):
            object.__setattr__(self, "default", tuple(v))
        if self.range is not None:
            lo, hi = self.range
            if isinstance(v, (bool, str, tuple)) or not lo <= v <= hi:
                raise ValueError(f"{self.name}: default {v!r} is not a number within {self.range}")
        if self.choices and v not in self.choices:
            raise ValueError(f"{self.name}: default {v!r} is not one of {list(self.choices)}")

    @property
    def ros_default(self) -> Any:
        """The default as a ROS parameter / YAML value (a list for a list parameter)."""
        return list(self.default) if isinstance(self.default, tuple) else self.default

    def text(self) -> str:
        """``"<unit>, <description>"`` (just the description without a unit)."""
        return f"{self.unit}, {self.description}" if self.unit else self.description

    def allowed(self) -> str:
        """The range as ``"from .. to"`` or the choices as ``"a, b"``; "" when any value goes."""
        if self.range is not None:
            return f"{_number(self.range[0])} .. {_number(self.range[1])}"
        return ", ".join(self.choices)

    def check(self, value: Any) -> None:
        """Raise ValueError, saying what to change, when ``value`` breaks the range or choices."""
        if self.choices and value not in self.choices:
            raise ValueError(f"{self.name} must be one of {list(self.choices)}, got {value!r}")
        if self.range is not None and not isinstance(value, bool) and isinstance(value, (int, float)):
            lo, hi = self.range
            if not lo <= value <= hi:
                raise ValueError(f"{self.name} must be within [{lo}, {hi}] {self.unit}, got {value!r}")


def yaml_value(value: Any) -> str:
    """``value`` written as YAML that rcl and PyYAML both read back with the same type (a float
    always with a '.', so that it never reads as an integer or, as '1e-05', as a string)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isinf(value):
            return ".inf" if value > 0 else "-.inf"
        if math.isnan(value):
            return ".nan"
        text = repr(value)
        if "e" in text and "." not in text.split("e")[0]:
            mantissa, exp = text.split("e")
            text = f"{mantissa}.0e{exp}"
        return text
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(yaml_value(v) for v in value) + "]"
    raise TypeError(f"no YAML form for {value!r}")


def _number(x: float) -> str:
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return str(int(x)) if x == int(x) and abs(x) < 1e15 else f"{x:g}"


@dataclass(frozen=True)
class ParamTable:
    """The parameters of node ``node`` in declaration order; ``table[name]`` is one spec."""

    node: str
    specs: tuple[ParamSpec, ...]
    _index: dict[str, ParamSpec] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        index = {s.name: s for s in self.specs}
        if len(index) != len(self.specs):
            raise ValueError(f"{self.node}: a parameter is declared twice")
        object.__setattr__(self, "_index", index)

    def __getitem__(self, name: str) -> ParamSpec:
        return self._index[name]

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __iter__(self) -> Iterator[ParamSpec]:
        return iter(self.specs)

    def names(self) -> list[str]:
        """Parameter names in declaration order."""
        return [s.name for s in self.specs]

    def default(self, name: str) -> Any:
        """The default of ``name`` as the engine holds it (a tuple for a list parameter)."""
        return self._index[name].default

    def defaults(self) -> dict[str, Any]:
        """name -> default as ROS parameters and YAML hold them (lists for list parameters)."""
        return {s.name: s.ros_default for s in self.specs}

    def yaml_file(self, header: Sequence[str] = (), width: int = 100) -> str:
        """A ``--params-file`` of the defaults: ``header`` lines as comments, then
        ``<node>: ros__parameters:`` with each ``name: value`` under a comment giving its unit,
        description, range or choices (wrapped at ``width`` columns)."""
        lines = [f"# {h}".rstrip() for h in header]
        lines += [f"{self.node}:", "  ros__parameters:"]
        for s in self.specs:
            note = s.text()
            allowed = s.allowed()
            if allowed:
                note += f"; {'one of' if s.choices else 'range'} {allowed}"
            if not s.read_at_start:
                note += "; changeable at runtime"
            lines += textwrap.wrap(note, width, initial_indent="    # ", subsequent_indent="    #   ",
                                   break_on_hyphens=False)
            lines.append(f"    {s.name}: {yaml_value(s.ros_default)}")
        return "\n".join(lines) + "\n"

    def markdown(self) -> str:
        """A Markdown table: parameter, default, unit, range or choices, when read, description."""
        rows = ["| parameter | default | unit | range | read | description |",
                "|---|---|---|---|---|---|"]
        for s in self.specs:
            allowed = ", ".join(f"`{c}`" for c in s.choices) if s.choices else s.allowed()
            read = "at start" if s.read_at_start else "each use"
            desc = s.description.replace("|", "\\|")
            rows.append(f"| `{s.name}` | `{yaml_value(s.ros_default)}` | {s.unit} | {allowed} | {read} | {desc} |")
        return "\n".join(rows) + "\n"

    def differences(self, values: Mapping[str, Any]) -> dict[str, tuple[Any, Any]]:
        """name -> (default, value) for each entry of ``values`` that differs from the default
        (numbers compared as numbers, lists element-wise); names not in the table too
        (default ``None``)."""
        out: dict[str, tuple[Any, Any]] = {}
        for name, value in values.items():
            default = self._index[name].ros_default if name in self._index else None
            if not same_value(default, value):
                out[name] = (default, value)
        return out


def same_value(a: Any, b: Any) -> bool:
    """True when two parameter values are equal: a bool only equals a bool, other numbers compare
    as numbers (1.0 == 1), lists and tuples element by element."""
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same_value(x, y) for x, y in zip(a, b))
    if isinstance(a, bool) or isinstance(b, bool):
        return isinstance(a, bool) and isinstance(b, bool) and a == b
    return bool(a == b)
