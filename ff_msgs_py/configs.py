"""The suite's shipped configuration files (``config/*.yaml``), found wherever the suite runs.

In a source checkout they are the repository's ``config/`` folder (the source of truth: edits
there take effect at once); in an installed wheel they are package data, ``ff_msgs_py/config/``
(copied from ``config/`` when the wheel is built), found with :mod:`importlib.resources`.

    config_dir()                   # the folder (a real directory: node --params-file paths)
    available()                    # ['bridge_epos4_1dof.yaml', ..., 'planner.yaml', ...]
    config_path("planner")         # its path ("planner" or "planner.yaml")
    load_config("planner.yaml")    # the parsed YAML (a dict)
    node_parameters("planner.yaml", "ff_planner")   # its ``ros__parameters``

An unknown name raises :class:`ConfigNotFound` naming the available files. ``ff-config`` (the
:func:`main` here) lists them, prints one, or copies them into a folder to edit. Standard library
and PyYAML only (cheap to import).
"""
from __future__ import annotations

import argparse
import shutil
import sys
from importlib import resources
from pathlib import Path
from typing import Any, Optional, Sequence

import yaml

PACKAGE = "ff_msgs_py"
DATA_FOLDER = "config"              # ff_msgs_py/config in the wheel
SUFFIXES = (".yaml", ".yml")
PROJECT = 'name = "ff-suite"'       # how the checkout's pyproject.toml names the distribution


class ConfigNotFound(FileNotFoundError):
    """A configuration name that is not shipped; the message lists the ones that are."""


def _source_dir() -> Optional[Path]:
    """The checkout's config/ when this module runs from a source tree of the suite, else None."""
    root = Path(__file__).resolve().parents[1]
    try:
        ours = PROJECT in (root / "pyproject.toml").read_text(encoding="utf-8")
    except OSError:
        return None
    folder = root / DATA_FOLDER
    return folder if ours and folder.is_dir() else None


def _package_dir() -> Optional[Path]:
    """The installed package data folder (ff_msgs_py/config), or None when there is none."""
    try:
        folder = resources.files(PACKAGE) / DATA_FOLDER
    except (ModuleNotFoundError, TypeError):
        return None
    path = Path(str(folder))
    return path if path.is_dir() else None


def config_dir() -> Path:
    """The folder of the shipped configuration files (source checkout first, then the package)."""
    for folder in (_source_dir(), _package_dir()):
        if folder is not None:
            return folder
    raise ConfigNotFound(f"no shipped configuration folder: neither a source checkout's config/ nor the "
                         f"package data {PACKAGE}/{DATA_FOLDER} exists; reinstall the suite")


def available() -> list[str]:
    """File names of the shipped configuration files, sorted."""
    return sorted(p.name for p in config_dir().iterdir() if p.is_file() and p.suffix in SUFFIXES)


def config_path(name: str) -> Path:
    """Path of the shipped configuration ``name`` ("planner.yaml" or "planner")."""
    folder = config_dir()
    candidates = [name] if Path(name).suffix in SUFFIXES else [name + s for s in SUFFIXES]
    for c in candidates:
        p = folder / c
        if Path(c).name == c and p.is_file():
            return p
    raise ConfigNotFound(f"no shipped configuration {name!r} in {folder}; available: {', '.join(available())}")


def load_config(name: str) -> dict[str, Any]:
    """The parsed YAML of the shipped configuration ``name`` ({} for an empty file)."""
    path = config_path(name)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping at the top, got {type(data).__name__}")
    return data


def node_parameters(name: str, node: str) -> dict[str, Any]:
    """``ros__parameters`` of ``node`` in the shipped configuration ``name`` ({} if it has none)."""
    data = load_config(name)
    return dict(((data.get(node) or {}).get("ros__parameters") or {}))


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Console script ``ff-config``: list, print or copy the shipped configuration files."""
    ap = argparse.ArgumentParser(prog="ff-config", description="The suite's shipped configuration files "
                                 "(node parameters, bridge/drive settings, plan and grid files).")
    ap.add_argument("name", nargs="?", help="print this file (e.g. planner.yaml); none: list them all")
    ap.add_argument("--path", action="store_true", help="print the file's (or the folder's) path instead")
    ap.add_argument("--copy", metavar="DIR", help="copy the file (or all of them) into DIR to edit; "
                    "existing files are kept")
    a = ap.parse_args(argv)
    try:
        if a.copy:
            dest = Path(a.copy).expanduser()
            dest.mkdir(parents=True, exist_ok=True)
            for n in ([config_path(a.name).name] if a.name else available()):
                target = dest / n
                if target.exists():
                    print(f"kept {target} (exists)")
                else:
                    shutil.copyfile(config_dir() / n, target)
                    print(f"wrote {target}")
            return 0
        if a.name:
            p = config_path(a.name)
            print(p if a.path else p.read_text(encoding="utf-8"), end="\n" if a.path else "")
            return 0
        if a.path:
            print(config_dir())
        else:
            print("\n".join(available()))
        return 0
    except (ConfigNotFound, OSError) as exc:
        print(f"ff-config: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
