"""The simulated stack (``ff_executor.bringup.stack.Stack``) for module-scoped test fixtures."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator


def running_stack(run_dir: Path | str, **options: Any) -> Iterator[Any]:
    """A started stack with its run folder at ``run_dir``, further StackOptions fields from
    ``options`` (e.g. ``namespace="arm_a"``, ``planner=False``, ``domain_id=...``) and no log
    output, stopped when the generator is closed: ``yield from running_stack(...)`` in a fixture.
    The stack is imported on use (it needs ROS)."""
    from ff_executor.bringup.stack import Stack, StackOptions

    with Stack(StackOptions(run_dir=str(run_dir), **options), log=lambda _m: None) as stack:
        yield stack
