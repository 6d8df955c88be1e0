"""Write what follows from the executor's parameter table (``ff_executor.engine.config``).

    python -m ff_executor.engine.paramgen yaml                  # the shipped YAML, to stdout
    python -m ff_executor.engine.paramgen yaml -o config/executor.yaml
    python -m ff_executor.engine.paramgen markdown              # the docs' table, to stdout
    python -m ff_executor.engine.paramgen markdown -o docs/parameters.md   # between its markers
    python -m ff_executor.engine.paramgen check                 # exit 1 when either file differs

``markdown -o FILE`` replaces only the text between ``<!-- BEGIN <node> parameters -->`` and
``<!-- END <node> parameters -->`` in FILE, so the page keeps its prose (and other nodes' tables).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Optional, Sequence

from ff_executor.engine.config import EXECUTOR_PARAMETERS
from ff_executor.engine.paramspec import ParamTable

REPO = Path(__file__).resolve().parents[2]
YAML_FILE = REPO / "config" / "executor.yaml"
DOCS_FILE = REPO / "docs" / "parameters.md"
YAML_HEADER = (
    "ff_executor parameters for real hardware: every parameter at the node's own default, so the",
    "node started without this file behaves the same.",
    "  ff-executor --ros-args --params-file config/executor.yaml",
    "Written from EXECUTOR_PARAMETERS (ff_executor/engine/config.py) by",
    "  python -m ff_executor.engine.paramgen yaml -o config/executor.yaml",
    "Change a default there, not here. For one robot, copy this file (ff-config) and edit the copy.",
)


def executor_yaml(table: ParamTable = EXECUTOR_PARAMETERS) -> str:
    """The text of ``config/executor.yaml``."""
    return table.yaml_file(YAML_HEADER)


def markers(table: ParamTable) -> tuple[str, str]:
    """The lines around ``table``'s generated section in a Markdown page."""
    return f"<!-- BEGIN {table.node} parameters -->", f"<!-- END {table.node} parameters -->"


def generated_section(page: str, table: ParamTable) -> Optional[str]:
    """The text between ``table``'s markers in ``page`` (None when the markers are missing)."""
    begin, end = markers(table)
    i, j = page.find(begin), page.find(end)
    if i < 0 or j < i:
        return None
    return page[i + len(begin):j].strip("\n") + "\n"


def with_section(page: str, table: ParamTable) -> str:
    """``page`` with ``table``'s section replaced by its Markdown table (appended when missing)."""
    begin, end = markers(table)
    block = f"{begin}\n{table.markdown()}{end}"
    i, j = page.find(begin), page.find(end)
    if i < 0 or j < i:
        return (page.rstrip("\n") + "\n\n" if page.strip() else "") + block + "\n"
    return page[:i] + block + page[j + len(end):]


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Console entry: write or check the YAML and the docs' table; returns the exit code."""
    ap = argparse.ArgumentParser(prog="python -m ff_executor.engine.paramgen", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("yaml", "markdown", "check"))
    ap.add_argument("-o", "--output", type=Path, help="write into this file instead of stdout")
    args = ap.parse_args(argv)
    table = EXECUTOR_PARAMETERS
    if args.what == "check":
        stale = []
        if not YAML_FILE.is_file() or YAML_FILE.read_text(encoding="utf-8") != executor_yaml(table):
            stale.append(str(YAML_FILE))
        page = DOCS_FILE.read_text(encoding="utf-8") if DOCS_FILE.is_file() else ""
        if generated_section(page, table) != table.markdown():
            stale.append(str(DOCS_FILE))
        for path in stale:
            print(f"{path} differs from the table; run: python -m ff_executor.engine.paramgen "
                  f"{'yaml' if path.endswith('.yaml') else 'markdown'} -o {path}", file=sys.stderr)
        return 1 if stale else 0
    if args.what == "yaml":
        text = executor_yaml(table)
    else:
        if args.output is None:
            text = table.markdown()
        else:
            old = args.output.read_text(encoding="utf-8") if args.output.is_file() else ""
            text = with_section(old, table)
    if args.output is None:
        sys.stdout.write(text)
    else:
        args.output.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
