"""A solution's per-cell fields as an xarray Dataset (``Solution.to_xarray()``)."""

import numpy as np

FIELDS = {
    "fluence": ("fluence", "radiance x steradian (integral of I over directions)"),
    "source": ("source", "radiance / length"),
    "sigma_t": ("sigma-t", "1 / length"),
}


def dataset(solution):
    try:
        import xarray as xr
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(
            "Solution.to_xarray() needs xarray: pip install xarray (or pip install 'volrad[xarray]')"
        ) from e
    nx, ny, nz = solution.dims
    h = solution.cell_size
    # Cell centres in volrad's world units (cell (0, 0, 0) spans [0, h]^3).
    coords = {
        "z": (np.arange(nz) + 0.5) * h,
        "y": (np.arange(ny) + 0.5) * h,
        "x": (np.arange(nx) + 0.5) * h,
    }
    dims = ("z", "y", "x")
    if solution.channels > 1:
        dims = dims + ("channel",)
        coords["channel"] = ["r", "g", "b"][: solution.channels]
    data_vars = {
        var: (dims, solution.field(name), {"units": units, "long_name": name})
        for var, (name, units) in FIELDS.items()
    }
    return xr.Dataset(
        data_vars,
        coords=coords,
        attrs={
            "method": solution.method,
            "scene_hash": solution.scene_hash,
            "cell_size": h,
            "source": "volrad",
        },
    )
