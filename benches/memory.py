#!/usr/bin/env python3
"""Peak memory and time of `volrad solve` against `volrad info`'s predictions, method by method.

    cargo build --release --bin volrad
    python3 benches/memory.py [--volrad target/release/volrad] [--quick] [--only METHOD]

For each case it writes a scene (Max's cloud generator, about 12 % of cells non-empty, or a
uniform medium filling every cell), asks `volrad info --json` for the predicted peak, runs
`volrad solve` under /usr/bin/time and prints a Markdown table of predicted and measured peak
resident memory and wall-clock time (docs/performance.md, "Memory" and "Time"); beside each
predicted time, the machine's speed `volrad info` measured and scaled it by. Needs only the
standard library.
"""

import argparse
import json
import os
import pathlib
import struct
import subprocess
import sys
import tempfile

CASES = [
    # (method, dims, medium, extra [solve] lines, quick)
    ("none", (64, 64, 48), "cloud", "", True),
    ("single-scatter", (64, 64, 48), "cloud", "", False),
    ("zonal", (16, 16, 12), "cloud", "", True),
    ("zonal", (32, 32, 24), "cloud", "", True),
    ("zonal", (40, 40, 30), "cloud", "", False),
    ("zonal", (16, 16, 16), "uniform", "", False),
    ("zonal", (20, 20, 20), "uniform", "", False),
    ("zonal-hierarchical", (32, 32, 24), "cloud", "", True),
    ("zonal-hierarchical", (64, 64, 48), "cloud", "", False),
    ("zonal-hierarchical", (24, 24, 24), "uniform", "", True),
    ("zonal-hierarchical", (40, 40, 40), "uniform", "", False),
    ("zonal-hierarchical", (32, 32, 24), "cloud-rgb", "", False),
    ("discrete-ordinates", (32, 32, 24), "cloud", "bins = 24", True),
    ("discrete-ordinates", (32, 32, 24), "cloud", "", True),
    ("discrete-ordinates", (32, 32, 24), "cloud", "bins = 384", False),
    ("discrete-ordinates", (64, 64, 48), "cloud", "", False),
    ("discrete-ordinates", (32, 32, 32), "uniform", "", False),
    ("discrete-ordinates", (32, 32, 24), "cloud-rgb", "", False),
    ("discrete-ordinates", (32, 32, 24), "cloud", 'iteration = "gmres:8"\ntolerance = 1e-12', False),
    # Large grids: multiple scattering on the transport grid `auto` chooses (64³-class).
    ("discrete-ordinates", (192, 192, 144), "cloud", 'transport_scale = "auto"', False),
    ("zonal-hierarchical", (192, 192, 144), "cloud", 'transport_scale = "auto"', False),
    ("discrete-ordinates", (384, 384, 288), "cloud", 'transport_scale = "auto"', False),
    ("two-pass", (16, 16, 12), "cloud", "", True),
    ("two-pass", (48, 48, 36), "cloud", "", False),
    ("two-pass", (32, 32, 24), "cloud", "photons = 100000", False),
    ("two-pass", (32, 32, 32), "uniform", "", False),
    # The sample scenes as they are (their own methods, lights, skies, grounds, emission and
    # iteration limits): what the time model's iteration counts are checked on.
    ("scene", "data/cloud.toml", "", "", True),
    ("scene", "data/cloud-sky.toml", "", "", False),
    ("scene", "data/cloud-backlit.toml", "", "", False),
    ("scene", "data/dipole.toml", "", "", False),
    ("scene", "data/fire.toml", "", "", False),
    ("scene", "data/fire-scattering.toml", "", "", False),
    ("scene", "data/smoke-emission.toml", "", "", False),
]


def scene_text(method, dims, medium, extra, folder, volume_extra=""):
    nx, ny, nz = dims
    if medium == "uniform":
        raw = folder / f"uniform{nx}x{ny}x{nz}.f32"
        raw.write_bytes(struct.pack("<f", 0.05) * (nx * ny * nz))
        volume = f'file = "{raw.name}"'
    else:
        volume = 'generator = { kind = "cloud", seed = 2 }'
    albedo = "[0.95, 0.9, 0.8]" if medium == "cloud-rgb" else "0.9"
    return f"""
[volume]
{volume}
dims = [{nx}, {ny}, {nz}]
{volume_extra}
[medium]
albedo = {albedo}
phase = {{ kind = "henyey-greenstein", g = 0.6 }}
[[light]]
kind = "directional"
direction = [-0.4, -1.0, -0.3]
irradiance = 1.0
[solve]
method = "{method}"
max_iterations = 30
{extra}
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--volrad", default=os.environ.get("VOLRAD_BIN", "target/release/volrad"))
    parser.add_argument("--quick", action="store_true", help="the small cases only")
    parser.add_argument("--only", help="one method")
    parser.add_argument("--match", help="cases whose settings or medium contain this text")
    args = parser.parse_args()
    print("| method | grid | medium | settings | memory predicted | measured | error "
          "| time predicted | measured | error |")
    print("|---|---|---|---|---:|---:|---:|---:|---:|---:|")
    worst = 0.0
    worst_time = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        folder = pathlib.Path(tmp)
        for method, dims, medium, extra, quick in CASES:
            if (args.quick and not quick) or (args.only and method != args.only):
                continue
            if args.match and args.match not in extra + medium + (dims if isinstance(dims, str) else ""):
                continue
            if method == "scene":
                scene = pathlib.Path(dims).resolve()
            else:
                scene = folder / "scene.toml"
                scene.write_text(scene_text(method, dims, medium, extra, folder))
            info = json.loads(
                subprocess.run(
                    [args.volrad, "info", "--json", scene], check=True, capture_output=True, text=True
                ).stdout
            )
            predicted = info["peak_memory_bytes"] / 2**20
            predicted_seconds = info["predicted_seconds"]
            # The machine's measured speed the prediction was scaled by (None: not measured).
            machine = info["time"].get("machine")
            speed = f" (×{machine:.2f})" if machine else ""
            timed = subprocess.run(
                ["/usr/bin/time", "-f", "%M %e", args.volrad, "--quiet", "solve", scene,
                 "-o", folder / "s.volrad"],
                capture_output=True, text=True,
            )
            if timed.returncode != 0:
                sys.exit(f"{method} {dims}: {timed.stderr}")
            rss, seconds = timed.stderr.strip().splitlines()[-1].split()
            measured = int(rss) / 1024
            seconds = max(float(seconds), 0.01)
            error = predicted / measured - 1
            worst = max(worst, abs(error))
            time_error = predicted_seconds / seconds - 1
            worst_time = max(worst_time, abs(time_error))
            settings = extra.replace("\n", ", ").replace("|", "\\|") or "defaults"
            if method == "scene":
                method, medium, settings = info["method"], dims, "the scene's"
                dims = info["dims"]
            print(
                f"| {method} | {dims[0]}×{dims[1]}×{dims[2]} | {medium} | {settings} | "
                f"{predicted:.0f} MiB | {measured:.0f} MiB | {100 * error:+.0f} % | "
                f"{predicted_seconds:.2f} s{speed} | {seconds:.2f} s | {100 * time_error:+.0f} % |",
                flush=True,
            )
    print(f"\nworst |error|: memory {100 * worst:.0f} %, time {100 * worst_time:.0f} %")


if __name__ == "__main__":
    main()
