#!/usr/bin/env python3
"""Writes the NIfTI test files of volrad's medium crate with nibabel (a real NIfTI library),
and next to each NAME.nii[.gz] the values nibabel reads back from it (NAME.f32, raw
little-endian float32, x fastest, after scl_slope/scl_inter) and NAME.json (dims, pixdim).

Run from anywhere: `python3 make_nifti.py` (needs numpy and nibabel). The files are small
(a few KB) and committed, so the tests need neither.
"""
import json
import pathlib

import nibabel as nib
import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
rng = np.random.default_rng(20)


def save(name, img, ext=".nii"):
    path = HERE / (name + ext)
    nib.save(img, path)
    back = nib.load(path)
    # nibabel's own reading: scaled in float64, then rounded once to float32 as volrad does.
    values = np.asarray(back.get_fdata(dtype=np.float64)).astype("<f4")
    dims = list(values.shape[:3])
    # NIfTI is x fastest (Fortran order), as volrad is.
    values.reshape(dims, order="F").ravel(order="F").tofile(HERE / (name + ".f32"))
    hdr = back.header
    # The header as written (nibabel's loaded header has the scaling taken out).
    raw = nib.load(path).header.__class__.from_fileobj(
        nib.openers.ImageOpener(path, "rb")
    )
    meta = {
        "file": path.name,
        "dims": dims,
        "pixdim": [float(x) for x in hdr["pixdim"][1:4]],
        "datatype": str(hdr.get_data_dtype()),
        "big_endian": hdr.endianness == ">",
        "nifti_version": 2 if isinstance(hdr, nib.Nifti2Header) else 1,
        "scl_slope": float(raw["scl_slope"]),
        "scl_inter": float(raw["scl_inter"]),
        "vox_offset": int(raw["vox_offset"]),
    }
    (HERE / (name + ".json")).write_text(json.dumps(meta, indent=1) + "\n")


def image(data, zooms=(1.0, 1.0, 1.0), cls=nib.Nifti1Image, endian=None, dtype=None):
    """`dtype` other than the data's: nibabel stores the data as `dtype` with the
    scl_slope/scl_inter it chooses (the way scanners' int16 files carry real values)."""
    hdr = cls.header_class(endianness=endian) if endian else cls.header_class()
    hdr.set_data_dtype(dtype or data.dtype)
    img = cls(data, np.diag([*zooms, 1.0]), header=hdr)
    img.header.set_zooms(tuple(zooms) + (1.0,) * (data.ndim - 3))
    return img


shape = (7, 5, 4)  # different on every axis, so an x/z mix-up cannot pass
f32 = rng.uniform(0.0, 3.0, shape).astype(np.float32)
save("float32", image(f32, zooms=(0.5, 0.5, 0.5)))
real = rng.uniform(-3.0, 40.0, shape)
save("int16_scaled", image(real, zooms=(2.0, 2.0, 2.0), dtype=np.int16))
u8 = rng.integers(0, 256, shape).astype(np.uint8)
save("uint8", image(u8))
f64 = rng.uniform(-1.0, 1.0, shape) * 1e3
save("float64", image(f64, zooms=(0.25, 0.25, 0.25)))
save("float32_big", image(f32, zooms=(0.5, 0.5, 0.5), endian=">"))
save("uint16_big_scaled", image(real + 100.0, endian=">", dtype=np.uint16))
save("float32_gz", image(f32, zooms=(0.5, 0.5, 0.5)), ext=".nii.gz")
save("nonuniform", image(f32, zooms=(0.7, 0.7, 2.5)))
i8 = rng.integers(-128, 128, shape).astype(np.int8)
save("int8_4d", image(i8[..., None]))  # dim[0] = 4 with dim[4] = 1
i32 = rng.integers(-(2**31), 2**31 - 1, shape).astype(np.int32)
save("int32_nifti2", image(i32, cls=nib.Nifti2Image))
u32 = rng.integers(0, 2**32 - 1, shape, dtype=np.uint64).astype(np.uint32)
save("uint32_nifti2_big_gz", image(u32, cls=nib.Nifti2Image, endian=">"), ext=".nii.gz")
