"""The README's tour works copy-paste: every fenced block marked ``<!-- tour: prints "..." -->`` in
the "Tour" section runs, in order, against a running simulated stack (its own ROS domain, log
folder, loopback discovery), exits 0 and prints each quoted text. Bash blocks run in ``bash -e``
with this environment's console scripts on PATH, Python blocks as a script file (the README says
to save it as ``my_client.py``), all in one fresh folder."""
from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.support.stacks import running_stack

REPO = Path(__file__).resolve().parents[1]
MARK = re.compile(r'<!-- tour(?::\s*prints(?P<prints>(?:\s+"[^"]*")+))?\s*-->\s*\n'
                  r'```(?P<lang>\w+)\n(?P<code>.*?)\n```', re.S)


@dataclass(frozen=True)
class Block:
    lang: str
    code: str
    prints: tuple[str, ...]


def tour_section() -> str:
    text = (REPO / "README.md").read_text()
    return text[text.index("## Tour\n"):text.index("### Layout\n")]


def tour_blocks() -> list[Block]:
    return [Block(m["lang"], m["code"], tuple(re.findall(r'"([^"]*)"', m["prints"] or "")))
            for m in MARK.finditer(tour_section())]


def test_the_tour_is_marked_and_says_what_each_console_script_is_for():
    blocks = tour_blocks()
    assert len(blocks) >= 5 and all(b.prints for b in blocks), blocks
    assert {b.lang for b in blocks} == {"bash", "python"}
    assert len(re.findall(r"^<!-- tour", tour_section(), re.M)) == len(blocks)   # no marker without its block
    section = tour_section()
    for heading in ("### Use it from your own code", "### On real hardware", "### Timing chain",
                    "### Console scripts"):
        assert heading in section
    assert "docs/timing.md" in section and "docs/hardware.md" in section
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    missing = [s for s in scripts if f"`{s}`" not in section]
    assert not missing, f"console scripts the tour does not mention: {missing}"


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    yield from running_stack(tmp_path_factory.mktemp("tour-stack"))


@pytest.mark.integration
def test_every_tour_block_runs_against_the_stack_and_prints_what_the_readme_says(stack, tmp_path):
    env = dict(stack.env)
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST" and env["ROS_DOMAIN_ID"] and env["ROS_LOG_DIR"]
    env["PATH"] = f"{Path(sys.executable).parent}:{env.get('PATH', '')}"
    for k, block in enumerate(tour_blocks()):
        if block.lang == "bash":
            args = ["bash", "-e", "-c", block.code]
        else:
            script = tmp_path / "my_client.py"
            script.write_text(block.code + "\n")
            args = [sys.executable, str(script)]
        proc = subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
        out = proc.stdout + proc.stderr
        where = f"tour block {k + 1} ({block.lang}):\n{block.code}\n--- output:\n{out[-3000:]}"
        assert proc.returncode == 0, f"{where}\n{stack.log_tails()}"
        for want in block.prints:
            assert want in out, f"{want!r} not printed by {where}"
