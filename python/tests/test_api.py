"""The Python package against the command line: same renders bit for bit, same messages."""

import os
import pickle
import signal
import threading
import time

import numpy as np
import pytest

import volrad
from conftest import optional, read_pfm, run_cli

LIGHT = {"kind": "directional", "direction": [0.0, 0.0, -1.0], "irradiance": 1.0}


def test_a_loaded_solution_renders_what_the_cli_renders(cloud_scene, tmp_path):
    stored = tmp_path / "cloud.volrad"
    run_cli("solve", cloud_scene, "-o", stored)
    run_cli("render", "--solution", stored, "-o", tmp_path / "front.pfm")
    run_cli(
        "render", "--solution", stored, "--eye", "30,-10,20", "--target", "7,6,5",
        "--up", "0,0,1", "--width", "40", "--height", "24", "-o", tmp_path / "custom.pfm",
    )
    solution = volrad.Solution.load(stored)
    front = solution.render("front")
    assert front.dtype == np.float32 and front.shape == (36, 48)
    assert front.max() > 0
    np.testing.assert_array_equal(front, read_pfm(tmp_path / "front.pfm"))
    custom = solution.render(eye=[30, -10, 20], target=[7, 6, 5], up=[0, 0, 1], width=40, height=24)
    np.testing.assert_array_equal(custom, read_pfm(tmp_path / "custom.pfm"))
    # A camera as a dict is the same request as keyword arguments.
    as_dict = solution.render(
        {"eye": [30, -10, 20], "target": [7, 6, 5], "up": [0, 0, 1], "width": 40, "height": 24}
    )
    np.testing.assert_array_equal(as_dict, custom)


def test_a_python_solve_matches_the_cli_solution(cloud_scene, tmp_path):
    stored = tmp_path / "cloud.volrad"
    run_cli("solve", cloud_scene, "-o", stored)
    cli = volrad.Solution.load(stored)
    solved = volrad.Scene.from_file(cloud_scene).solve()
    assert solved.scene_hash == cli.scene_hash
    np.testing.assert_array_equal(solved.render(), cli.render())
    np.testing.assert_array_equal(solved.field("fluence"), cli.field("fluence"))


def test_an_array_scene_is_the_scene_file_with_the_same_values(tmp_path):
    rng = np.random.default_rng(5)
    sigma_t = rng.uniform(0.0, 1.5, size=(6, 7, 8)).astype(np.float32)  # (nz, ny, nx)
    sigma_t.tofile(tmp_path / "vol.f32")  # C order: x fastest, as volrad's raw files
    (tmp_path / "scene.toml").write_text(
        """
[volume]
file = "vol.f32"
dims = [8, 7, 6]
cell_size = 0.5
[medium]
albedo = 0.8
phase = { kind = "henyey-greenstein", g = 0.3 }
[[light]]
kind = "directional"
direction = [0.0, 0.0, -1.0]
irradiance = 1.0
[solve]
method = "zonal"
"""
    )
    from_file = volrad.Scene.from_file(tmp_path / "scene.toml")
    from_arrays = volrad.Scene(
        sigma_t.astype(np.float64),  # converted to float32, as the file holds
        cell_size=0.5,
        albedo=0.8,
        phase={"kind": "henyey-greenstein", "g": 0.3},
        lights=[LIGHT],
        method="zonal",
    )
    assert from_arrays.dims == (8, 7, 6)
    assert from_arrays.scene_hash == from_file.scene_hash
    solution = from_arrays.solve()
    np.testing.assert_array_equal(solution.field("sigma-t"), sigma_t)
    assert solution.field("fluence").shape == (6, 7, 8)


def test_bad_input_raises_the_cli_message(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[volume]\ngenerator = { kind = "cloud" }\ndims = [8, 8, 8]\n'
        "[medium]\nalbedo = 1.5\n"
        '[[light]]\nkind = "directional"\ndirection = [0, 0, -1]\nirradiance = 1\n'
    )
    cli = run_cli("solve", bad, "-o", tmp_path / "x.volrad", check=False)
    assert cli.returncode != 0
    with pytest.raises(volrad.VolradError) as raised:
        volrad.Scene.from_file(bad)
    assert cli.stderr.strip() == f"error: {raised.value}"
    assert "medium.albedo" in str(raised.value)

    garbage = tmp_path / "garbage.volrad"
    garbage.write_bytes(b"not a solution at all")
    cli = run_cli("render", "--solution", garbage, "-o", tmp_path / "x.png", check=False)
    with pytest.raises(volrad.VolradError) as raised:
        volrad.Solution.load(garbage)
    assert cli.stderr.strip() == f"error: {raised.value}"


def test_array_arguments_are_checked():
    with pytest.raises(volrad.VolradError, match="3-dimensional"):
        volrad.Scene(np.ones((4, 4)), albedo=0.5, lights=[LIGHT])
    with pytest.raises(volrad.VolradError, match="medium.albedo"):
        volrad.Scene(np.ones((4, 4, 4)), lights=[LIGHT])
    with pytest.raises(volrad.VolradError, match="cannot be a scene value"):
        volrad.Scene(np.ones((4, 4, 4)), albedo=object(), lights=[LIGHT])
    scene = volrad.Scene(np.ones((4, 4, 4)), albedo=0.5, lights=[LIGHT], method="zonal")
    with pytest.raises(volrad.VolradError, match="method"):
        scene.solve(method="no-such-method")
    solution = scene.solve()
    with pytest.raises(volrad.VolradError, match="unknown field"):
        solution.field("temperature")
    with pytest.raises(volrad.VolradError, match="no camera named"):
        solution.render("nowhere")
    with pytest.raises(volrad.VolradError, match="unknown key"):
        solution.render({"eyes": [0, 0, 0]})


def test_solutions_travel_as_bytes_and_pickles(tmp_path):
    scene = volrad.Scene(np.full((5, 5, 5), 0.7), albedo=0.9, lights=[LIGHT], method="zonal")
    solution = scene.solve()
    view = dict(eye=[2.5, -12, 2.5], target=[2.5, 2.5, 2.5], up=[0, 0, 1], width=20, height=16)
    reference = solution.render(**view)
    assert reference.max() > 0
    for copy in (
        volrad.Solution.from_bytes(solution.to_bytes()),
        pickle.loads(pickle.dumps(solution)),
    ):
        np.testing.assert_array_equal(copy.render(**view), reference)
    solution.save(tmp_path / "s.volrad")
    loaded = volrad.Solution.load(tmp_path / "s.volrad")
    np.testing.assert_array_equal(loaded.render(**view), reference)


def test_rgb_fields_put_the_channel_last():
    scene = volrad.Scene(
        np.full((4, 5, 6), 0.5), albedo=[0.9, 0.6, 0.3], lights=[LIGHT], method="zonal"
    )
    solution = scene.solve()
    assert solution.channels == 3
    fluence = solution.field("fluence")
    assert fluence.shape == (4, 5, 6, 3)
    for c in range(3):
        np.testing.assert_array_equal(fluence[..., c], solution.field("fluence", channel=c))
    # Less albedo, less scattered light: the channels differ in the physical order.
    assert fluence[..., 0].mean() > fluence[..., 1].mean() > fluence[..., 2].mean()
    image = solution.render(eye=[3, -15, 2], target=[3, 2.5, 2], up=[0, 0, 1], width=16, height=12)
    assert image.shape == (12, 16, 3)


def test_to_xarray_labels_the_fields_with_cell_centres():
    xr = optional("xarray")
    scene = volrad.Scene(
        np.full((3, 4, 5), 0.5), cell_size=2.0, albedo=0.9, lights=[LIGHT], method="zonal"
    )
    ds = scene.solve().to_xarray()
    assert isinstance(ds, xr.Dataset)
    assert ds["fluence"].dims == ("z", "y", "x")
    np.testing.assert_allclose(ds["x"].values, [1, 3, 5, 7, 9])
    assert float(ds["sigma_t"].max()) == pytest.approx(0.5)


def slow_scene():
    """A solve of many seconds: a thick, bright medium iterated to a tight tolerance."""
    rng = np.random.default_rng(1)
    sigma_t = rng.uniform(1.0, 3.0, size=(20, 24, 24)).astype(np.float32)
    return volrad.Scene(
        sigma_t,
        albedo=0.999,
        lights=[LIGHT],
        method="discrete-ordinates",
        solve={"tolerance": 1e-12, "max_iterations": 100000},
    )


def test_solves_release_the_gil():
    ticks = 0
    done = threading.Event()

    def count():
        nonlocal ticks
        while not done.is_set():
            ticks += 1
            time.sleep(0.001)

    scene = volrad.Scene(
        np.full((16, 16, 16), 2.0),
        albedo=0.99,
        lights=[LIGHT],
        method="discrete-ordinates",
        solve={"tolerance": 1e-9},
    )
    counter = threading.Thread(target=count)
    counter.start()
    started = time.time()
    scene.solve()
    seconds = time.time() - started
    done.set()
    counter.join()
    # With the GIL held through the solve the counter could not tick during it.
    assert seconds > 0.2
    assert ticks > 0.25 * seconds * 1000


def test_ctrl_c_cancels_a_solve():
    scene = slow_scene()
    timer = threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGINT))
    started = time.time()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        scene.solve()
    seconds = time.time() - started
    timer.cancel()
    assert seconds < 5.0, f"the solve went on for {seconds:.1f} s after Ctrl-C"


def test_an_orbit_renders_what_the_cli_orbit_renders(cloud_scene, tmp_path):
    stored = tmp_path / "cloud.volrad"
    run_cli("solve", cloud_scene, "-o", stored)
    run_cli("render", "--solution", stored, "--orbit", "3", "-o", tmp_path / "v.pfm")
    solution = volrad.Solution.load(stored)
    cameras = solution.orbit(3, "front")
    assert len(cameras) == 3
    for i, camera in enumerate(cameras):
        np.testing.assert_array_equal(
            solution.render(camera), read_pfm(tmp_path / f"v_front_{i:03}.pfm")
        )
    with pytest.raises(volrad.VolradError, match="at least 1"):
        solution.orbit(0)


def test_a_solve_that_cannot_fit_raises_before_it_starts():
    scene = volrad.Scene(
        np.full((24, 32, 32), 0.5, dtype=np.float32),
        albedo=0.9,
        phase={"kind": "henyey-greenstein", "g": 0.85},
        lights=[LIGHT],
        method="discrete-ordinates",
        solve={"bins": 384},
    )
    # What the refusal is measured against, and the time the solve would take, before it.
    assert "solve peak" in scene.info() and "time             solve about" in scene.info()
    started = time.monotonic()
    with pytest.raises(volrad.VolradError, match=r"needs about .*--max-memory.*bins = "):
        scene.solve(max_memory="256M")
    assert time.monotonic() - started < 5
    with pytest.raises(volrad.VolradError, match="max_memory"):
        scene.solve(max_memory="lots")


def test_the_report_is_what_volrad_solve_json_prints(cloud_scene, tmp_path):
    import json

    stored = tmp_path / "cloud.volrad"
    cli = json.loads(run_cli("solve", cloud_scene, "-o", stored, "--json").stdout)
    report = volrad.Solution.load(stored).report()
    assert report["seconds"] is None  # a loaded file does not know how long its solve took
    for key in ("method", "scene_hash", "channels"):
        assert report[key] == cli[key], key
    assert report["channels"][0]["iterations"] > 0


def test_an_image_too_large_for_memory_is_refused_before_rendering(cloud_scene, tmp_path):
    stored = tmp_path / "cloud.volrad"
    run_cli("solve", cloud_scene, "-o", stored)
    solution = volrad.Solution.load(stored)
    started = time.monotonic()
    # 10⁶ × 10⁶ pixels: terabytes, more than any machine has.
    with pytest.raises(volrad.VolradError, match="smaller image"):
        solution.render("front", width=1_000_000, height=1_000_000)
    assert time.monotonic() - started < 5


def test_transport_scale_solves_on_blocks_of_cells_and_refuses_bad_values():
    # A ball of 16³ cells: its multiple scattering on 8³ blocks of 2³ cells.
    z, y, x = np.mgrid[0:16, 0:16, 0:16]
    ball = ((x - 7.5) ** 2 + (y - 7.5) ** 2 + (z - 7.5) ** 2 < 49).astype(np.float32) * 0.4
    scene = volrad.Scene(ball, albedo=0.9, lights=[LIGHT], method="zonal-hierarchical")
    fine = scene.solve()
    coarse = scene.solve(transport_scale=2)
    f, c = fine.field("fluence"), coarse.field("fluence")
    assert c.shape == f.shape == (16, 16, 16)
    inside = ball > 0
    # The lights' unscattered light per data cell is the same; the scattered light is close.
    assert abs(c[inside].mean() / f[inside].mean() - 1) < 0.08
    np.testing.assert_array_equal(scene.solve(transport_scale="auto").field("fluence"), f)
    for bad in (0, 17, "coarse", 1.5):
        with pytest.raises(volrad.VolradError, match="transport_scale"):
            scene.solve(transport_scale=bad)


def test_a_ground_under_an_array_scene_is_lit_and_lights_the_blob():
    """`ground=` is the scene file's `[ground]`: the ground shows in the picture, lit by the
    sun, and a brighter ground brightens the blob's underside."""
    z, y, x = np.mgrid[0:8, 0:8, 0:8]
    blob = np.where((x - 3.5) ** 2 + (y - 3.5) ** 2 + (z - 3.5) ** 2 < 9, 2.0, 0.0)
    camera = {"name": "low", "eye": [3.5, -14.0, 1.0], "target": [3.5, 4.0, 0.0],
              "up": [0, 0, 1], "fov_y": 60.0, "width": 48, "height": 36}

    def solved(albedo):
        return volrad.Scene(
            blob.astype(np.float32), albedo=0.9, method="discrete-ordinates",
            lights=[{"kind": "directional", "direction": [0.0, 0.0, -1.0], "irradiance": 1.0}],
            ground={"height": -2.0, "albedo": albedo}, cameras=[camera],
        ).solve()

    bright, dark = solved(0.8), solved(0.1)
    image = bright.render()
    # The bottom row is open ground near the camera: A E / π with E = 1, and a little more.
    lit_ground = image[-1].mean()
    assert lit_ground > 0.8 * 1.0 / np.pi * 0.9
    below = {"eye": [3.5, 3.5, -1.5], "target": [3.5, 3.5, 4.0], "up": [0, 1, 0],
             "width": 8, "height": 8}
    assert bright.render(below).mean() > 1.5 * dark.render(below).mean()
