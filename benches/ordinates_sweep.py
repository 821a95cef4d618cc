#!/usr/bin/env python3
"""Seconds per discrete-ordinates sweep: measured against `volrad info`'s model.

    cargo build --release --bin volrad
    python3 benches/ordinates_sweep.py [--volrad target/release/volrad]

For each case (the scenes of benches/memory.py: Max's cloud generator or a uniform block,
albedo 0.9, g = 0.6) it takes the model's seconds per sweep from `volrad info --json` (the
iterations' part over the iterations it expects) and the measured ones from `volrad solve`'s
`solved` log line (its seconds over its iterations), and prints a Markdown table
(docs/performance.md, "Time"; `src/engine/timing.rs` fits its sweep constants to these and to
Kobayashi's shield, `examples/source_in_void.rs --case ii`). Needs only the standard library.
"""

import argparse
import json
import os
import pathlib
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from memory import scene_text  # noqa: E402

CASES = [
    # (dims, medium, extra [solve] lines)
    ((32, 32, 24), "cloud", "bins = 24"),
    ((32, 32, 24), "cloud", ""),
    ((32, 32, 24), "cloud", "bins = 384"),
    ((64, 64, 48), "cloud", ""),
    ((32, 32, 32), "uniform", ""),
    ((32, 32, 32), "uniform", "bins = 216"),
    ((48, 48, 48), "uniform", ""),
]

SOLVED = re.compile(r"solved .*?iterations=(\d+) .*?seconds=([0-9.eE+-]+)")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--volrad", default=os.environ.get("VOLRAD_BIN", "target/release/volrad"))
    args = parser.parse_args()
    print("| grid | medium | settings | model per sweep | measured | error |")
    print("|---|---|---|---:|---:|---:|")
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        folder = pathlib.Path(tmp)
        for dims, medium, extra in CASES:
            scene = folder / "scene.toml"
            scene.write_text(scene_text("discrete-ordinates", dims, medium, extra, folder))
            info = json.loads(
                subprocess.run(
                    [args.volrad, "info", "--json", scene], check=True, capture_output=True, text=True
                ).stdout
            )
            time = info["time"]
            iterating = sum(p["seconds"] for p in time["parts"] if "iteration" in p["what"])
            model = iterating / (time["iterations"] * info["channels"])
            solved = subprocess.run(
                [args.volrad, "solve", scene, "-o", folder / "s.volrad"],
                capture_output=True, text=True, env={**os.environ, "RUST_LOG": "info"},
            )
            found = SOLVED.findall(re.sub(r"\x1b\[[0-9;]*m", "", solved.stderr + solved.stdout))
            if solved.returncode != 0 or not found:
                sys.exit(f"{dims} {medium} {extra}: {solved.stderr}")
            iterations = sum(int(i) for i, _ in found)
            measured = sum(float(s) for _, s in found) / max(iterations, 1)
            error = model / measured - 1
            worst = max(worst, abs(error))
            grid = "×".join(map(str, dims))
            print(f"| {grid} | {medium} | {extra or 'defaults'} | {model * 1e3:.1f} ms "
                  f"| {measured * 1e3:.1f} ms | {error:+.0%} |")
    print(f"\nworst |error| {worst:.0%}")


if __name__ == "__main__":
    main()
