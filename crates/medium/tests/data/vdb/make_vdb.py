#!/usr/bin/python3
"""Writes small .vdb files with the OpenVDB library itself, and beside each the values volrad
must read from it, so that volrad's own reader (crates/medium/src/vdb.rs) is checked against
the library's writer and the library's reader.

    make_vdb.py OUTDIR [--seed N] [--quick] [--large]
    make_vdb.py --from-raw RAW NX NY NZ OUT.vdb [--voxel-size H] [--name density]
    make_vdb.py --describe FILE.vdb OUTDIR

`--describe` writes the manifest and values of an existing file (say, a sample model from
openvdb.org) into OUTDIR, beside a link to the file, so that volrad's reader is checked on
files other programs wrote (`VOLRAD_REAL_VDB` in crates/medium/tests/it/vdb.rs).

For every case `NAME` it writes `NAME.vdb` and `NAME.json`:
    {"file": "NAME.vdb", "grids": [{"name", "dims", "bbox_min", "bbox_max", "voxel_size",
      "translation", "values": "NAME.GRID.f32"}, ...]}
and per grid `NAME.GRID.f32`: the dense values over the grid's active-voxel bounding box as
little-endian f32, x fastest, as the OpenVDB library reads them back from the file (so a
half-float file's values are the halves the library decodes, and inactive voxels and tiles
inside the box carry their stored value or the background).

Debian's binding (`pyopenvdb`, python3-openvdb) writes float grids only and cannot choose
the compression; `--quick` stops there. Without it, the script also builds vdb_rewrite.cc
(g++ and libopenvdb-dev, libboost-dev, libtbb-dev, libimath-dev) and rewrites some files
with zip, no compression or as double grids. Run with Debian's /usr/bin/python3, which is
the interpreter the binding is built for.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

try:
    import openvdb as vdb
except ImportError:
    import pyopenvdb as vdb

HERE = os.path.dirname(os.path.abspath(__file__))


def expected(path, outdir, stem):
    """What the library reads back from `path`: per grid, its active bbox and dense values."""
    grids = []
    for grid in vdb.readAll(path)[0]:
        lo, hi = grid.evalActiveVoxelBoundingBox()
        dims = [hi[a] - lo[a] + 1 for a in range(3)]
        dense = np.zeros(dims, dtype=np.float32)
        grid.copyToArray(dense, ijk=lo)
        values = "%s.%s.f32" % (stem, grid.name)
        # dense[i, j, k]; volrad's order is x fastest, so k is the slowest axis.
        dense.transpose(2, 1, 0).astype("<f4").tofile(os.path.join(outdir, values))
        t = grid.transform
        origin = t.indexToWorld((0, 0, 0))
        grids.append({
            "name": grid.name,
            "dims": dims,
            "bbox_min": list(lo),
            "bbox_max": list(hi),
            "voxel_size": [t.indexToWorld(e)[a] - origin[a]
                           for a, e in enumerate([(1, 0, 0), (0, 1, 0), (0, 0, 1)])],
            "translation": list(origin),
            "values": values,
        })
    return grids


def save(outdir, stem, grids):
    path = os.path.join(outdir, stem + ".vdb")
    vdb.write(path, grids=grids)
    manifest(outdir, stem)


def manifest(outdir, stem, like=None):
    """`like`: a file with the same values (the binding cannot read double grids)."""
    path = os.path.join(outdir, (like or stem) + ".vdb")
    with open(os.path.join(outdir, stem + ".json"), "w") as f:
        json.dump({"file": stem + ".vdb", "grids": expected(path, outdir, stem)}, f, indent=1)
        f.write("\n")


def cloudlet(rng, shape, threshold=0.35):
    """Random values in (0, 1], zero (so inactive: copyFromArray drops background values)
    where below `threshold`, so leaves hold active and inactive voxels."""
    v = rng.random(shape).astype(np.float32)
    v[v < threshold] = 0.0
    return v


def float_grid(name, values, ijk, transform=None, background=0.0):
    g = vdb.FloatGrid(background)
    g.name = name
    g.copyFromArray(values, ijk=ijk)
    if transform is not None:
        g.transform = transform
    return g


def quick_cases(outdir, rng):
    """Cases the binding alone can write (float and half grids, its default compression)."""
    # Negative index coordinates: the box straddles x = 0, so two root children.
    save(outdir, "float_negative", [
        float_grid("density", cloudlet(rng, (13, 9, 11)), (-7, 3, 2))])

    # saveFloatAsHalf: values are stored as 16-bit halves.
    g = float_grid("density", cloudlet(rng, (10, 12, 9)) * 3.1, (2, -5, 1),
                   vdb.createLinearTransform(voxelSize=0.25))
    g.saveFloatAsHalf = True
    save(outdir, "half", [g])

    # Voxel size 0.5 and a translation (a uniform-scale-translate map).
    t = vdb.createLinearTransform([[0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 0.5, 0],
                                   [1.25, -2.0, 3.5, 1]])
    save(outdir, "scale_translate", [
        float_grid("density", cloudlet(rng, (9, 7, 8)), (3, 4, -2), t)])

    # Non-uniform voxel size with a translation (a scale-translate map).
    t = vdb.createLinearTransform([[0.5, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 2.0, 0],
                                   [-1.0, 0.5, 4.0, 1]])
    save(outdir, "nonuniform", [
        float_grid("density", cloudlet(rng, (6, 5, 4)), (0, 0, 0), t)])

    # Active tiles: fills that cover whole leaf (8^3) and internal-4 (128^3 would be too big)
    # nodes become tiles; an inactive tile with a non-background value inside the box; voxels.
    g = vdb.FloatGrid(0.0)
    g.name = "density"
    g.fill((0, 0, 0), (15, 15, 7), 0.75, True)       # two 8^3 leaf-sized active tiles
    g.fill((16, 0, 0), (23, 7, 7), 2.5, False)       # an inactive tile inside the bbox
    g.copyFromArray(cloudlet(rng, (5, 6, 4)) + 1.0, ijk=(20, 10, 5))
    acc = g.getAccessor()
    acc.setValueOn((30, 17, 9), 4.0)
    save(outdir, "tiles", [g])

    # Two grids; a non-zero background; inactive voxels with one, two or many distinct values
    # so that every per-node mask-compression mode is written.
    d = float_grid("density", cloudlet(rng, (12, 10, 9)), (-4, 0, 2))
    t = vdb.FloatGrid(300.0)
    t.name = "temperature"
    t.copyFromArray(cloudlet(rng, (8, 8, 16)) * 900.0 + 300.0, ijk=(0, 0, 0))
    acc = t.getAccessor()
    for (i, j, k), value in [((1, 1, 1), -300.0), ((2, 1, 1), 300.0),     # ±background
                             ((1, 1, 9), 55.0),                            # one other value
                             ((0, 0, 9), -300.0)]:
        acc.setValueOff((i, j, k), value)
    for k in range(8, 16):                                                 # many values
        acc.setValueOff((5, 5, k), float(k) * 1.5)
    save(outdir, "multi", [d, t])

    # Background -bg voxels only (NO_MASK_AND_MINUS_BG) and two non-background inactive
    # values (MASK_AND_TWO_INACTIVE_VALS), each in a leaf of its own.
    g = float_grid("density", np.full((8, 8, 8), 2.0, dtype=np.float32), (0, 0, 0),
                   background=1.0)
    acc = g.getAccessor()
    acc.setValueOff((1, 2, 3), -1.0)
    g.copyFromArray(np.full((8, 8, 8), 3.0, dtype=np.float32), ijk=(8, 0, 0))
    acc.setValueOff((9, 2, 3), 7.0)
    acc.setValueOff((10, 2, 3), 8.0)
    g.copyFromArray(np.full((8, 8, 8), 4.0, dtype=np.float32), ijk=(16, 0, 0))
    acc.setValueOff((17, 2, 3), -1.0)
    acc.setValueOff((18, 2, 3), 1.0)
    acc.setValueOff((19, 2, 3), 6.0)
    g.copyFromArray(np.full((8, 8, 8), 5.0, dtype=np.float32), ijk=(24, 0, 0))
    acc.setValueOff((25, 2, 3), 6.0)                                       # one other value
    acc.setValueOff((26, 2, 3), 6.0)
    save(outdir, "mask_modes", [g])

    # An instance: a second grid sharing the first one's tree, with its own transform (the
    # file stores the tree once; the instance's descriptor names its parent).
    g = float_grid("density", cloudlet(rng, (5, 4, 6)), (1, -2, 3))
    h = g.copy()
    h.name = "instance"
    h.transform = vdb.createLinearTransform(voxelSize=0.5)
    save(outdir, "instance", [g, h])

    # A rotated transform (an AffineMap with off-diagonal terms): volrad refuses it, naming
    # the map. No manifest: there is nothing to compare.
    g = float_grid("density", np.ones((2, 2, 2), dtype=np.float32), (0, 0, 0))
    t = vdb.createLinearTransform(voxelSize=1.0)
    t.rotate(0.3, vdb.Axis.Z)
    g.transform = t
    vdb.write(os.path.join(outdir, "rotated.vdb"), grids=[g])


def large_cases(outdir, rng):
    """A 128³ active tile of an internal node 5 and a voxel beside it (16 MiB of expected
    values: written only on request, by the round-trip test, never committed)."""
    g = vdb.FloatGrid(0.0)
    g.name = "density"
    g.fill((128, 0, 0), (255, 127, 127), 0.5, True)
    g.copyFromArray(cloudlet(rng, (3, 4, 5)) + 1.0, ijk=(-2, 60, 70))
    save(outdir, "node5_tile", [g])


def rewrites(outdir):
    """Files the binding cannot write: zip, no compression and double grids (vdb_rewrite.cc)."""
    tmp = tempfile.mkdtemp()
    try:
        exe = os.path.join(tmp, "vdb_rewrite")
        subprocess.check_call(["g++", "-std=c++17", "-O1", os.path.join(HERE, "vdb_rewrite.cc"),
                               "-o", exe, "-lopenvdb", "-ltbb", "-lImath-3_1"])
        for src, stem, args in [("multi", "zip", ["zip"]),
                                ("multi", "uncompressed", ["none"]),
                                ("tiles", "double", ["blosc", "double"]),
                                ("mask_modes", "double_zip", ["zip", "double"]),
                                ("float_negative", "blosc", ["blosc"])]:
            subprocess.check_call([exe, os.path.join(outdir, src + ".vdb"),
                                   os.path.join(outdir, stem + ".vdb")] + args)
            manifest(outdir, stem, like=src)
    finally:
        shutil.rmtree(tmp)


def from_raw(raw, dims, out, voxel_size, name):
    """A raw little-endian f32 volume (x fastest) as one float grid: zero voxels inactive,
    index (0, 0, 0) at the raw volume's first value, Blosc (the library's default)."""
    nx, ny, nz = dims
    v = np.fromfile(raw, dtype="<f4").reshape(nz, ny, nx).transpose(2, 1, 0).copy()
    g = float_grid(name, v.astype(np.float32), (0, 0, 0),
                   vdb.createLinearTransform(voxelSize=voxel_size))
    vdb.write(out, grids=[g])


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--from-raw", nargs=5, metavar=("RAW", "NX", "NY", "NZ", "OUT"),
                   help="write one raw f32 volume as a .vdb instead of the test files")
    p.add_argument("--describe", metavar="FILE",
                   help="write the manifest of an existing .vdb into OUTDIR instead")
    p.add_argument("--voxel-size", type=float, default=1.0)
    p.add_argument("--name", default="density")
    p.add_argument("outdir", nargs="?")
    p.add_argument("--seed", type=int, default=20)
    p.add_argument("--quick", action="store_true",
                   help="only what the Python binding writes (no C++ build)")
    p.add_argument("--large", action="store_true",
                   help="also a grid with a 128^3 tile (16 MiB of expected values)")
    args = p.parse_args()
    if args.from_raw:
        raw, nx, ny, nz, out = args.from_raw
        from_raw(raw, (int(nx), int(ny), int(nz)), out, args.voxel_size, args.name)
        return
    if not args.outdir:
        p.error("OUTDIR is required")
    os.makedirs(args.outdir, exist_ok=True)
    vdb.initialize() if hasattr(vdb, "initialize") else None
    if args.describe:
        stem = os.path.splitext(os.path.basename(args.describe))[0]
        link = os.path.join(args.outdir, stem + ".vdb")
        if not os.path.exists(link):
            os.symlink(os.path.abspath(args.describe), link)
        manifest(args.outdir, stem)
        return
    rng = np.random.default_rng(args.seed)
    quick_cases(args.outdir, rng)
    if args.large:
        large_cases(args.outdir, rng)
    if not args.quick:
        rewrites(args.outdir)
    print("wrote %s (OpenVDB %s, file format %d)"
          % (args.outdir, ".".join(map(str, vdb.LIBRARY_VERSION)), vdb.FILE_FORMAT_VERSION))


if __name__ == "__main__":
    sys.exit(main())
