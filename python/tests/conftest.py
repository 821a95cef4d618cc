"""Shared fixtures: the volrad command line the package is compared with, and small scenes."""

import os
import pathlib
import subprocess

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]


def volrad_bin():
    """The command line built from the same sources (`cargo build --release`), or $VOLRAD_BIN."""
    default = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target")) / "release" / "volrad"
    path = pathlib.Path(os.environ.get("VOLRAD_BIN", default))
    if not path.is_file():
        raise RuntimeError(
            f"{path} is missing: build it with `cargo build --release --bin volrad` "
            "or point VOLRAD_BIN at it"
        )
    return str(path)


def optional(module):
    """An optional dependency (xarray, ray): its tests are skipped where it is missing, unless
    VOLRAD_TEST_OPTIONAL=1 (CI installs them all and must run every test)."""
    if os.environ.get("VOLRAD_TEST_OPTIONAL") == "1":
        return __import__(module)
    return pytest.importorskip(module)


def run_cli(*args, check=True):
    return subprocess.run(
        [volrad_bin(), "--quiet", *map(str, args)], capture_output=True, text=True, check=check
    )


def read_pfm(path):
    """A PFM file as volrad writes it (scale -1: little-endian; rows bottom first)."""
    data = pathlib.Path(path).read_bytes()
    magic, dims, scale, rest = data.split(b"\n", 3)
    w, h = map(int, dims.split())
    channels = 3 if magic == b"PF" else 1
    assert float(scale) < 0, "volrad writes little-endian PFM"
    pixels = np.frombuffer(rest, dtype="<f4", count=w * h * channels)
    shape = (h, w) if channels == 1 else (h, w, channels)
    return pixels.reshape(shape)[::-1]


CLOUD_SCENE = """
[volume]
generator = {{ kind = "cloud", seed = 3 }}
dims = [14, 12, 10]
sigma_t_scale = 0.8

[medium]
albedo = 0.9
phase = {{ kind = "henyey-greenstein", g = 0.5 }}

[[light]]
kind = "directional"
direction = [-0.4, -1.0, 0.3]
irradiance = 1.0

[solve]
method = "{method}"

[[camera]]
name = "front"
eye = [7.0, -25.0, 5.0]
target = [7.0, 6.0, 5.0]
up = [0.0, 0.0, 1.0]
fov_y = 40.0
width = 48
height = 36
"""


@pytest.fixture
def cloud_scene(tmp_path):
    """A small generated cloud solved by discrete ordinates, as a scene file."""
    path = tmp_path / "cloud.toml"
    path.write_text(CLOUD_SCENE.format(method="discrete-ordinates"))
    return path
