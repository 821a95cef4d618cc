#!/usr/bin/env python3
"""The 24x24x18 reference cloud with every cell split into 2x2x2 cells of half the size: the
same medium (the scenes are `nearest`) on a grid twice as fine, to tell a method's error
from the grid's resolution (docs/validation.md, "The zonal far field").

    python3 benches/refine_cloud24.py OUT [isotropic|anisotropic]
    volrad validate --scene OUT/scene.toml --methods zonal,zonal-hierarchical -o v

Standard library only.
"""
import array
import pathlib
import sys

out = pathlib.Path(sys.argv[1])
variant = sys.argv[2] if len(sys.argv) > 2 else "isotropic"
source = pathlib.Path(__file__).resolve().parent.parent / "tests/data" / f"cloud24-{variant}"
nx, ny, nz = 24, 24, 18
cells = array.array("f")
cells.frombytes((source / "cloud24.f32").read_bytes())
if sys.byteorder != "little":
    cells.byteswap()
assert len(cells) == nx * ny * nz, len(cells)
fine = array.array("f", bytes(4 * 8 * len(cells)))
for k in range(2 * nz):
    for j in range(2 * ny):
        row = (k // 2) * nx * ny + (j // 2) * nx
        base = (k * 2 * ny + j) * 2 * nx
        for i in range(2 * nx):
            fine[base + i] = cells[row + i // 2]
if sys.byteorder != "little":
    fine.byteswap()
out.mkdir(parents=True, exist_ok=True)
(out / "cloud48.f32").write_bytes(fine.tobytes())
text = (source / "scene.toml").read_text()
text = text.replace('file = "cloud24.f32"', 'file = "cloud48.f32"')
text = text.replace("dims = [24, 24, 18]", "dims = [48, 48, 36]\ncell_size = 0.5")
assert "cloud48.f32" in text and "cell_size = 0.5" in text
(out / "scene.toml").write_text(text)
print(f"wrote {out / 'scene.toml'} and {out / 'cloud48.f32'}")
