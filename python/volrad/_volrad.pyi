"""Type stubs of volrad's Rust extension (python/src/lib.rs)."""

from os import PathLike
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

__version__: str

_Path = Union[str, "PathLike[str]"]
_Vec3 = Sequence[float]
_Value = Union[float, int, str, bool, Sequence[Any], Mapping[str, Any]]

class VolradError(Exception):
    """A scene, volume, solution file or request volrad refuses; the message is the CLI's."""

class Scene:
    def __init__(
        self,
        sigma_t: npt.ArrayLike,
        *,
        cell_size: Optional[float] = None,
        albedo: Optional[_Value] = None,
        phase: Optional[_Value] = None,
        emission: Optional[_Value] = None,
        lights: Optional[Sequence[Mapping[str, Any]]] = None,
        background: Optional[_Value] = None,
        ground: Optional[Mapping[str, Any]] = None,
        method: Optional[str] = None,
        solve: Optional[Mapping[str, Any]] = None,
        render: Optional[Mapping[str, Any]] = None,
        cameras: Optional[Sequence[Mapping[str, Any]]] = None,
        interpolation: Optional[str] = None,
        base_dir: Optional[_Path] = None,
    ) -> None: ...
    @staticmethod
    def from_file(path: _Path) -> "Scene": ...
    @staticmethod
    def from_toml(text: str, base_dir: Optional[_Path] = None) -> "Scene": ...
    @staticmethod
    def builtin() -> "Scene": ...
    @property
    def dims(self) -> tuple[int, int, int]: ...
    @property
    def cell_size(self) -> float: ...
    @property
    def channels(self) -> int: ...
    @property
    def method(self) -> str: ...
    @property
    def cameras(self) -> list[str]: ...
    @property
    def scene_hash(self) -> str: ...
    def info(self) -> str: ...
    def solve(
        self,
        method: Optional[str] = None,
        *,
        iteration: Optional[str] = None,
        tolerance: Optional[float] = None,
        max_iterations: Optional[int] = None,
        progress: bool = False,
        max_memory: Union[None, int, str] = None,
        transport_scale: Union[None, int, str] = None,
    ) -> "Solution": ...

class Solution:
    @staticmethod
    def load(path: _Path) -> "Solution": ...
    @staticmethod
    def from_bytes(data: bytes) -> "Solution": ...
    def save(self, path: _Path) -> None: ...
    def to_bytes(self) -> bytes: ...
    def render(
        self,
        camera: Union[None, str, Mapping[str, Any]] = None,
        *,
        eye: Optional[_Vec3] = None,
        target: Optional[_Vec3] = None,
        up: Optional[_Vec3] = None,
        fov_y_degrees: Optional[float] = None,
        width: Optional[int] = None,
        height: Optional[int] = None,
        spp: Optional[int] = None,
        extinction_scale: Optional[float] = None,
    ) -> npt.NDArray[np.float32]: ...
    def orbit(
        self, n: int, camera: Union[None, str, Mapping[str, Any]] = None
    ) -> list[dict[str, Any]]: ...
    def field(self, name: str, channel: Optional[int] = None) -> npt.NDArray[np.float32]: ...
    def to_xarray(self) -> Any: ...
    def report(self) -> dict[str, Any]: ...
    @property
    def dims(self) -> tuple[int, int, int]: ...
    @property
    def cell_size(self) -> float: ...
    @property
    def channels(self) -> int: ...
    @property
    def method(self) -> str: ...
    @property
    def cameras(self) -> list[str]: ...
    @property
    def scene_hash(self) -> str: ...

def write_image(
    image: npt.ArrayLike, path: _Path, exposure: Optional[float] = None
) -> None: ...
