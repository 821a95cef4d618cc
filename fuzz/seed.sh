#!/usr/bin/env bash
# Fills fuzz/corpus/<target>/ (not committed) with seeds from the project's sample files:
# data/ and crates/medium/tests/data/ for the volume formats, data/*.toml (and their JSON form)
# for scenes, the golden solution files, a few render queries, and small NRRD / .vol files
# written here (the repository holds no .vol sample). Run from anywhere; needs python3 ≥ 3.11.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
c="$root/fuzz/corpus"
mkdir -p "$c"/{scene_toml,scene_json,nrrd,mitsuba_vol,vdb,nifti,solution,render_query,environment_map}
# Scenes at 8×8×6 cells: the fuzz checks skip grids over 2^16 cells (volrad::fuzzing).
for f in "$root"/data/*.toml; do
    sed -E "s/^dims = \[[0-9, ]+\]/dims = [8, 8, 6]/" "$f" >"$c/scene_toml/$(basename "$f")"
done
cp "$root"/data/smoke32.nrrd "$c/nrrd/"
cp "$root"/data/cloud24.vdb "$root"/crates/medium/tests/data/vdb/*.vdb "$c/vdb/"
cp "$root"/crates/medium/tests/data/nifti/*.nii* "$c/nifti/"
cp "$root"/tests/data/solution-golden/*.volrad "$c/solution/"
python3 - "$root" "$c" <<'PY'
import gzip, json, pathlib, struct, sys, tomllib
root, c = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
for t in sorted((c / "scene_toml").glob("*.toml")):
    scene = tomllib.loads(t.read_text())
    (c / "scene_json" / (t.stem + ".json")).write_text(json.dumps(scene, indent=1))
# Small NRRDs: raw and gzip, big-endian shorts, a detached header.
vals = struct.pack("<6f", *[0.5 * i for i in range(6)])
head = "NRRD0004\ntype: float\ndimension: 3\nsizes: 3 2 1\nendian: little\n"
(c / "nrrd" / "raw.nrrd").write_bytes((head + "encoding: raw\n\n").encode() + vals)
(c / "nrrd" / "gzip.nrrd").write_bytes((head + "encoding: gzip\n\n").encode() + gzip.compress(vals))
(c / "nrrd" / "short.nrrd").write_bytes(
    b"NRRD0005\n# a comment\ntype: short\ndimension: 3\nsizes: 2 1 1\nendian: big\n"
    b"byte skip: 2\nencoding: raw\nkey:=value\n\n\x00\x00" + struct.pack(">2h", -3, 7))
(c / "nrrd" / "detached.nhdr").write_bytes((head + "encoding: raw\ndata file: d.raw\n").encode())
# Mitsuba .vol: 2×2×1 float32 grid, one channel.
vol = b"VOL" + bytes([3]) + struct.pack("<i3ii6f", 1, 2, 2, 1, 1, 0, 0, 0, 2, 2, 1)
(c / "mitsuba_vol" / "small.vol").write_bytes(vol + struct.pack("<4f", 0.0, 0.25, 0.5, 1.0))
queries = [
    "", "camera=front", "eye=1,2,3&target=2,2,2&up=0,0,1&fov=30&width=64&height=48",
    "spp=4&exposure=1.5&format=pfm", "format=png&width=1&height=1", "eye=%31,2,3&camera=front",
]
for i, q in enumerate(queries):
    (c / "render_query" / f"q{i}").write_text(q)
# Environment maps: small PFMs, RGB little-endian and grey big-endian, one with a bright texel.
rgb = [0.2, 0.3, 0.5] * 8
rgb[9:12] = [500.0, 480.0, 450.0]
(c / "environment_map" / "sky.pfm").write_bytes(b"PF\n4 2\n-1.0\n" + struct.pack("<24f", *rgb))
(c / "environment_map" / "grey.pfm").write_bytes(b"Pf\n2 2\n1.0\n" + struct.pack(">4f", 1, 2, 3, 4))
PY
du -sh "$c"/*
