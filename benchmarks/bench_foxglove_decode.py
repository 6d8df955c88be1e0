"""Foxglove reads our recordings: a stack run recorded by ``ff-demo --record`` (ff-record, MCAP)
decoded message by message with the libraries Foxglove itself uses for ROS 2 channels
(``@mcap/core``, ``@foxglove/rosmsg`` with ROS 2 rules, ``@foxglove/rosmsg2-serialization``;
benchmarks/foxglove/decode_mcap.mjs), and checked against ``rosbags``' AnyReader: every message
decoded by both, the same count per topic, and the last message of each topic field for field.

Needs Node.js >= 18 and npm (the three packages are installed into benchmarks/foxglove/ on first
use, pinned in its package.json). Prints JSON; ``--out`` writes it too.

    python benchmarks/bench_foxglove_decode.py [--bag DIR] [--out benchmarks/results/foxglove_decode.json]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

from _common import log, report

HERE = Path(__file__).resolve().parent
FOX = HERE / "foxglove"


def _record(run_dir: Path) -> Path:
    """A demo run recorded into run_dir/bag (its own ROS domain, loopback only)."""
    bag = run_dir / "bag"
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_LOG_DIR": str(run_dir / "ros-log")}
    env.pop("ROS_DOMAIN_ID", None)               # ff-demo picks a free one
    log(f"recording an ff-demo run into {bag}")
    subprocess.run([str(Path(sys.executable).with_name("ff-demo")), "--record", str(bag), "--run-dir", str(run_dir),
                    "--plot", str(run_dir / "demo.png")], env=env, check=True, stdout=subprocess.DEVNULL,
                   timeout=900)
    return bag


def _foxglove(mcap: Path) -> dict[str, Any]:
    if shutil.which("node") is None or shutil.which("npm") is None:
        raise SystemExit("bench_foxglove_decode: needs node and npm on PATH")
    if not (FOX / "node_modules" / "@foxglove" / "rosmsg2-serialization").is_dir():
        log("installing Foxglove's decoders into benchmarks/foxglove (npm)")
        subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--silent"], cwd=FOX, check=True, timeout=600)
    proc = subprocess.run(["node", str(FOX / "decode_mcap.mjs"), str(mcap)], capture_output=True, text=True,
                          timeout=600)
    if not proc.stdout.strip():
        raise SystemExit(f"decode_mcap.mjs failed: {proc.stderr.strip()}")
    return dict(json.loads(proc.stdout))


def _plain(v: Any) -> Any:
    """A rosbags message as JSON-like data (dataclass fields in order, arrays as lists)."""
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        # rosbags keeps a type's constants as fields too: rosidl names constants in upper case
        # and fields in lower case, and only fields are on the wire
        return {f.name: _plain(getattr(v, f.name)) for f in dataclasses.fields(v)
                if not f.name.startswith("__") and not f.name.isupper()}
    if hasattr(v, "tolist"):
        return v.tolist()
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return math.isclose(float(a), float(b), rel_tol=0.0, abs_tol=0.0) or (math.isnan(a) and math.isnan(b))
    return bool(a == b)


def _anyreader(bag: Path) -> tuple[Counter[str], dict[str, Any]]:
    from rosbags.highlevel import AnyReader

    counts: Counter[str] = Counter()
    last: dict[str, Any] = {}
    with AnyReader([bag]) as reader:
        for conn, _t, raw in reader.messages():
            last[conn.topic] = _plain(reader.deserialize(raw, conn.msgtype))
            counts[conn.topic] += 1
    return counts, last


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bag", default=None, help="a rosbag2 folder with one .mcap (default: record an ff-demo run)")
    ap.add_argument("--out", default=None, help="also write the JSON here")
    a = ap.parse_args()
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="ff-foxglove-") as tmp:
        bag = Path(a.bag) if a.bag else _record(Path(tmp))
        mcaps = sorted(bag.glob("*.mcap"))
        if len(mcaps) != 1:
            raise SystemExit(f"{bag}: expected one .mcap, found {len(mcaps)}")
        fox = _foxglove(mcaps[0])
        counts, last = _anyreader(bag)
    topics = {}
    for topic, t in sorted(fox["topics"].items()):
        topics[topic] = {"type": t["type"], "foxglove_decoded": t["decoded"], "foxglove_failed": t["failed"],
                         "rosbags_decoded": counts.get(topic, 0), "error": t["error"],
                         "last_message_equal": (None if t["last"] is None
                                                else _same(t["last"], last.get(topic)))}
    ok = (fox["messages"] > 0 and fox["decoded"] == fox["messages"] == sum(counts.values())
          and all(v["foxglove_decoded"] == v["rosbags_decoded"] and v["last_message_equal"] is not False
                  for v in topics.values()))
    node = subprocess.run(["node", "--version"], capture_output=True, text=True).stdout.strip()
    pkg = json.loads((FOX / "package.json").read_text())["dependencies"]
    out = {"ok": ok, "messages": fox["messages"], "foxglove_decoded": fox["decoded"],
           "rosbags_decoded": sum(counts.values()), "node": node, "decoders": pkg,
           "wall_s": round(time.monotonic() - t0, 1), "topics": topics}
    report(out, a.out)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
