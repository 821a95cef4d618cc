"""Many views of one stored solution on many machines, with Ray.

Rendering views of a solved scene is embarrassingly parallel and the solution file is the unit
of exchange: each worker loads the solution once and renders its share of the views. The same
code runs on a laptop's local Ray cluster and on a real one (``ray.init(address="auto")``).

    >>> import ray, volrad
    >>> from volrad.distributed import render_views
    >>> ray.init(num_cpus=2)
    >>> solution = volrad.Solution.load("cloud.volrad")
    >>> images = render_views(solution, solution.orbit(64), workers=2)

``ray`` is imported only here: ``pip install ray`` (or ``pip install ./python[ray]``).
"""

from __future__ import annotations

import os
from typing import Any, Iterable, List, Mapping, Optional, Sequence, Union

import numpy as np

from ._volrad import Solution

__all__ = ["ViewPool", "render_views"]

Camera = Union[None, str, Mapping[str, Any]]


class ViewPool:
    """``workers`` Ray actors, each holding the solution loaded once, rendering views on
    request; use as a context manager (or call ``close``) to free the workers.

    ``solution`` is a ``Solution`` or a solution file's bytes, shipped once to the cluster's
    object store, or the path of a solution file every node can read (a shared store). Each
    actor reserves ``threads_per_worker`` CPUs and renders with as many threads, so workers on
    one machine do not oversubscribe its cores. Ray must be initialised (``ray.init``) or will
    start a local cluster on first use.
    """

    def __init__(
        self,
        solution: Union[Solution, bytes, str, os.PathLike],
        *,
        workers: int,
        threads_per_worker: int = 1,
    ) -> None:
        import ray
        from ray.util import ActorPool

        if workers < 1:
            raise ValueError("workers must be at least 1")
        if threads_per_worker < 1:
            raise ValueError("threads_per_worker must be at least 1")
        if isinstance(solution, Solution):
            source: Any = ray.put(solution.to_bytes())
        elif isinstance(solution, (bytes, bytearray)):
            source = ray.put(bytes(solution))
        else:
            source = os.fspath(solution)
        renderer = ray.remote(_ViewRenderer).options(num_cpus=threads_per_worker)
        self._actors = [renderer.remote(source, threads_per_worker) for _ in range(workers)]
        self._pool = ActorPool(self._actors)

    def render(self, cameras: Iterable[Camera], *, spp: Optional[int] = None) -> List[np.ndarray]:
        """The views of ``cameras`` (each as ``Solution.render``'s ``camera`` argument), in
        their order; a worker's refusal is raised here with the command line's message."""
        return list(self._pool.map(lambda actor, cam: actor.render.remote(cam, spp), cameras))

    def close(self) -> None:
        import ray

        for actor in self._actors:
            ray.kill(actor)
        self._actors = []

    def __enter__(self) -> "ViewPool":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def render_views(
    solution: Union[Solution, bytes, str, os.PathLike],
    cameras: Iterable[Camera],
    *,
    workers: int,
    threads_per_worker: int = 1,
    spp: Optional[int] = None,
) -> List[np.ndarray]:
    """Renders ``cameras`` on a ``ViewPool`` of ``workers`` and returns the images in the
    cameras' order."""
    with ViewPool(solution, workers=workers, threads_per_worker=threads_per_worker) as pool:
        return pool.render(cameras, spp=spp)


class _ViewRenderer:
    """One worker: the solution loaded once, views rendered on request."""

    def __init__(self, source: Union[bytes, str], threads: int) -> None:
        # The render's thread pool starts on first use and reads this then; the actor owns its
        # process, so nothing has used it yet.
        os.environ["RAYON_NUM_THREADS"] = str(threads)
        if isinstance(source, str):
            self.solution = Solution.load(source)
        else:
            self.solution = Solution.from_bytes(source)

    def render(self, camera: Camera, spp: Optional[int]) -> np.ndarray:
        return self.solution.render(camera, spp=spp)
