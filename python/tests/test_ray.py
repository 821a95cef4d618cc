"""Many views of one solution across a local Ray cluster, checked against one process."""

import numpy as np
import pytest

import volrad
from conftest import optional


@pytest.fixture(scope="module")
def ray_cluster():
    ray = optional("ray")
    # A local cluster of two CPUs: two single-threaded workers, as on two machines.
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def solution(tmp_path_factory):
    from conftest import CLOUD_SCENE

    scene = volrad.Scene.from_toml(CLOUD_SCENE.format(method="discrete-ordinates"))
    return scene.solve()


def test_sixteen_views_on_two_workers_are_the_single_process_renders(ray_cluster, solution):
    from volrad.distributed import render_views

    cameras = solution.orbit(16, "front")
    images = render_views(solution, cameras, workers=2)
    assert len(images) == 16
    for camera, image in zip(cameras, images):
        np.testing.assert_array_equal(image, solution.render(camera))
    # Views differ from one another, so the order is checked, not only the content.
    assert not np.array_equal(images[0], images[4])


def test_workers_can_load_the_solution_from_a_shared_path(ray_cluster, solution, tmp_path):
    from volrad.distributed import render_views

    path = tmp_path / "cloud.volrad"
    solution.save(path)
    cameras = solution.orbit(4, "front")
    images = render_views(str(path), cameras, workers=2, spp=2)
    for camera, image in zip(cameras, images):
        np.testing.assert_array_equal(image, solution.render(camera, spp=2))


def test_a_bad_camera_raises_the_cli_message_from_the_worker(ray_cluster, solution):
    from volrad.distributed import render_views

    with pytest.raises(Exception, match="no camera named `side`"):
        render_views(solution, ["front", "side"], workers=2)


def test_a_pool_renders_batch_after_batch(ray_cluster, solution):
    from volrad.distributed import ViewPool

    cameras = solution.orbit(4, "front")
    with ViewPool(solution, workers=2) as pool:
        first = pool.render(cameras[:2])
        second = pool.render(cameras[2:])
    for camera, image in zip(cameras, first + second):
        np.testing.assert_array_equal(image, solution.render(camera))
