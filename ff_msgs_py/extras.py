"""Which pip extra of the suite provides a missing module: one clear line instead of a traceback.

    try:
        ...
    except ModuleNotFoundError as exc:
        sys.exit(f"ff-record: {missing_extra(exc)}")

Standard library only.
"""
from __future__ import annotations

from typing import Optional

#: top-level module -> (pip extra of ff-suite, what needs it); None: not an extra, a plain package
EXTRAS: dict[str, tuple[Optional[str], str]] = {
    "numba": ("planner", "planning and the simulated arm"),
    "scipy": ("planner", "planning and identification"),
    "pebble": ("planner", "the planner node's worker pool"),
    "dask": ("cluster", "motion-library builds on Dask"),
    "distributed": ("cluster", "motion-library builds on Dask"),
    "matplotlib": ("plot", "plots"),
    "rosbags": ("record", "recording rosbag2 bags"),
    "mcap": (None, "reading MCAP files (pip install mcap mcap-ros2-support)"),
    "mcap_ros2": (None, "decoding MCAP ROS 2 messages (pip install mcap-ros2-support)"),
}


def missing_extra(exc: ModuleNotFoundError) -> str:
    """One line: which module is missing and what to install for it."""
    name = (exc.name or str(exc)).split(".")[0]
    extra = EXTRAS.get(name)
    if extra is None:
        return f"the Python module {name!r} is not installed ({exc}); reinstall the suite"
    pip_extra, what = extra
    if pip_extra is None:
        return f"{what}: the module {name!r} is not installed"
    return (f"{what} needs the [{pip_extra}] extra, which is not installed (module {name!r} missing): "
            f"pip install 'ff-suite[{pip_extra}]'")
