"""The planner's command-line tools, one module each, entry point ``main``:

``ff-plan`` (``plan``), ``ff-library`` (``library``), ``ff-reproduce`` (``reproduce``) and
``python -m ff_planner.cli.warmup`` (``warmup``). The modules are not imported here, so that each
command loads only what it needs.
"""

__all__ = ["library", "plan", "reproduce", "warmup"]
