"""volrad: volume radiosity from Python.

Solve multiple scattering in a participating medium once, store the solution, and render any
number of views from it — the same engine, messages and results as the ``volrad`` command line.

    >>> import numpy as np, volrad
    >>> sigma_t = np.full((16, 16, 16), 0.5, dtype=np.float32)      # (nz, ny, nx)
    >>> scene = volrad.Scene(sigma_t, albedo=0.9, phase={"kind": "henyey-greenstein", "g": 0.6},
    ...                      lights=[{"kind": "directional", "direction": [0, 0, -1], "irradiance": 1.0}],
    ...                      method="discrete-ordinates")
    >>> solution = scene.solve()
    >>> image = solution.render(eye=[8, -30, 8], target=[8, 8, 8], up=[0, 0, 1], width=64, height=48)
    >>> image.shape
    (48, 64)

Arrays are in numpy's C order with x fastest, as volrad numbers its cells: a volume is
``(nz, ny, nx)``, an image ``(H, W)`` or ``(H, W, 3)``, top row first.
"""

from ._volrad import Scene, Solution, VolradError, __version__, write_image

__all__ = ["Scene", "Solution", "VolradError", "write_image", "__version__"]
