#!/usr/bin/env python3
"""The hierarchical operator's far links and build time against `volrad info`'s time model.

    cargo build --release --bin volrad
    python3 benches/far_links.py [--volrad target/release/volrad] [--quick]

For each case (the generated clouds and uniform blocks of benches/memory.py, with
zonal-hierarchical, at several thicknesses and on the transport grids of large clouds; and
data/cloud-large.toml) it reads the model's counts from `volrad info`'s debug log (`the
hierarchy's links, predicted`: non-empty transport cells, fill, mean optical side, far links)
and its predicted build (`the hierarchical operator` part of `volrad info --json`), solves
with `RUST_LOG=info` and reads the build's own `hierarchy built` line (`links_per_level`,
`seconds`), and prints a Markdown table (docs/performance.md, *Time*, "The hierarchy's far
links"). `--quick` leaves out the 384-class cloud. Standard library only; about 3 minutes.
"""

import argparse
import json
import os
import pathlib
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from memory import scene_text  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parent.parent

CASES = [
    # (dims, medium, [volume] lines, [solve] lines, quick)
    ((32, 32, 24), "cloud", "", "", True),
    ((48, 48, 36), "cloud", "", "", True),
    ((64, 64, 48), "cloud", "", "", True),
    ((64, 64, 48), "cloud", "sigma_t_scale = 0.25", "", True),
    ((64, 64, 48), "cloud", "sigma_t_scale = 4.0", "", True),
    ((32, 32, 24), "cloud", "sigma_t_scale = 4.0", "", True),
    ((24, 24, 24), "uniform", "", "", True),
    ((40, 40, 40), "uniform", "", "", True),
    ((96, 96, 72), "cloud", "", 'transport_scale = "auto"', True),
    ((192, 192, 144), "cloud", "", 'transport_scale = "auto"', True),
    ((384, 384, 288), "cloud", "", 'transport_scale = "auto"', False),
    ("data/cloud-large.toml", "", "", "", True),
]


def field(text, name):
    m = re.search(rf"\b{name}=([0-9.e+-]+)", text)
    if not m:
        sys.exit(f"far_links: no `{name}=` in the log:\n{text[-2000:]}")
    return float(m.group(1))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--volrad", default=os.environ.get("VOLRAD_BIN", "target/release/volrad"))
    parser.add_argument("--quick", action="store_true", help="without the 384-class cloud")
    args = parser.parse_args()
    volrad = str(pathlib.Path(args.volrad).resolve())
    print("| case | non-empty cells | fill | mean σt h | far links per cell | predicted | error "
          "| build predicted | measured | error |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        folder = pathlib.Path(tmp)
        for dims, medium, volume_extra, extra, quick in CASES:
            if args.quick and not quick:
                continue
            if isinstance(dims, str):
                scene, name, overrides = ROOT / dims, dims, ["--method", "zonal-hierarchical"]
            else:
                scene = folder / "scene.toml"
                scene.write_text(scene_text("zonal-hierarchical", dims, medium, extra, folder,
                                            volume_extra))
                name = "×".join(map(str, dims)) + f" {medium}" + (
                    f", {volume_extra}" if volume_extra else "") + (f", {extra}" if extra else "")
                overrides = []
            env = dict(os.environ, RUST_LOG="volrad=debug")
            info = subprocess.run([volrad, "info", str(scene), "--json", *overrides],
                                  capture_output=True, text=True, env=env, cwd=folder)
            if info.returncode != 0:
                sys.exit(f"far_links: volrad info failed on {name}:\n{info.stderr}")
            line = next(l for l in info.stderr.splitlines() if "the hierarchy's links, predicted" in l)
            occupied, fill = field(line, "occupied"), field(line, "fill")
            side, far_predicted = field(line, "mean_optical_side"), field(line, "far_links")
            parts = json.loads(info.stdout)["time"]["parts"]
            build_predicted = sum(p["seconds"] for p in parts if p["what"] == "the hierarchical operator")
            solve = subprocess.run([volrad, "-q", "solve", str(scene), "-o", str(folder / "s.volrad"),
                                    *overrides], capture_output=True, text=True,
                                   env=dict(os.environ, RUST_LOG="info"), cwd=folder)
            if solve.returncode != 0:
                sys.exit(f"far_links: volrad solve failed on {name}:\n{solve.stderr}")
            built = next(l for l in solve.stderr.splitlines() if "hierarchy built" in l)
            levels = re.search(r"links_per_level=\[([0-9, ]*)\]", built).group(1)
            far = sum(int(v) for v in levels.split(",") if v.strip())
            seconds = field(built, "seconds")
            print(f"| {name} | {occupied:,.0f} | {fill:.2f} | {side:.2f} | {far / occupied:.0f} "
                  f"| {far_predicted / occupied:.0f} | {100 * (far_predicted / far - 1):+.0f} % "
                  f"| {build_predicted:.2f} s | {seconds:.2f} s "
                  f"| {100 * (build_predicted / seconds - 1):+.0f} % |", flush=True)


if __name__ == "__main__":
    main()
