"""pofvr: volume rendering of numpy arrays with Plenoptic Opacity Function culling."""

import os
from typing import Any, Callable, Dict, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

PathLike = Union[str, "os.PathLike[str]"]
Family = Union[PathLike, Dict[str, Any]]

class Error(Exception):
    """Base of every error pofvr reports; its message is the library's."""

class InputError(Error, ValueError):
    """A bad value, file content or setting."""

class FileError(Error, OSError):
    """A file that could not be read or written (errno set when known)."""

class Frame:
    """A rendered frame."""

    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def rgba(self) -> npt.NDArray[np.uint8]:
        """(height, width, 4) uint8 RGBA, straight alpha: the PNG's pixels."""
    @property
    def rgba_float(self) -> npt.NDArray[np.float32]:
        """(height, width, 4) float32 RGBA, premultiplied: what --out-raw writes."""
    @property
    def stats(self) -> Dict[str, Any]:
        """The keys `pofvr render --stats` writes for one frame."""
    @property
    def camera(self) -> Dict[str, Any]:
        """The camera JSON (--camera-out); Scene.render(camera=...) takes it back."""
    def save(self, path: PathLike) -> None:
        """Writes a PNG, or with a .raw extension the float image."""
    def _repr_png_(self) -> bytes: ...

class Scene:
    """A volume ready to render.

    `volume` is a C-contiguous (z, y, x) numpy array of uint8, uint16, int16 or float32,
    borrowed (not copied) and marked read-only; `spacing` is (sx, sy, sz), the reverse of
    the array's axes, as --spacing.
    """

    def __init__(
        self,
        volume: npt.NDArray[Any],
        spacing: Tuple[float, float, float] = (1.0, 1.0, 1.0),
        *,
        tf: Family,
        weights: Optional[Sequence[float]] = None,
        brick: int = 16,
        step: float = 1.0,
        ert: float = 0.99,
        jitter: Optional[int] = None,
    ) -> None: ...
    @property
    def dims(self) -> Tuple[int, int, int]:
        """Voxel counts (x, y, z)."""
    @property
    def shape(self) -> Tuple[int, int, int]:
        """The array shape (z, y, x)."""
    @property
    def spacing(self) -> Tuple[float, float, float]: ...
    @property
    def dtype(self) -> str: ...
    @property
    def bases(self) -> list[str]: ...
    @property
    def default_weights(self) -> list[float]: ...
    @property
    def bricks(self) -> int: ...
    @property
    def has_pofs(self) -> bool: ...
    @property
    def _voxel_address(self) -> int: ...
    def build_pofs(
        self,
        views: Tuple[int, int] = (36, 36),
        *,
        method: Optional[str] = None,
        encoding: Optional[str] = None,
        sets: bool = False,
        core_length: Optional[float] = None,
        progress: Union[bool, Callable[[int, int], None], None] = None,
    ) -> None:
        """Builds and attaches POFs; Ctrl-C stops it (KeyboardInterrupt)."""
    def load_pofs(self, path: PathLike) -> None: ...
    def render(
        self,
        view: Tuple[float, float] = (30.0, 20.0),
        size: Tuple[int, int] = (512, 512),
        *,
        camera: Optional[Dict[str, Any]] = None,
        projection: str = "orthographic",
        weights: Optional[Sequence[float]] = None,
        shade: bool = False,
        cull: Optional[str] = None,
        whole: bool = False,
        threshold: float = 0.95,
        ranks: int = 1,
        curve: str = "hilbert",
        replicas: int = 1,
        engine: Optional[str] = None,
        threads: Optional[int] = None,
    ) -> Frame:
        """One frame; `size` is (width, height); releases the GIL."""

def open(
    path: PathLike,
    tf: Optional[Family] = None,
    *,
    weights: Optional[Sequence[float]] = None,
    brick: int = 16,
    step: float = 1.0,
    ert: float = 0.99,
    jitter: Optional[int] = None,
    dims: Optional[Tuple[int, int, int]] = None,
    dtype: Optional[str] = None,
    spacing: Optional[Tuple[float, float, float]] = None,
    endian: str = "little",
    header_bytes: int = 0,
) -> Scene:
    """Opens a volume file (NRRD, MetaImage, NIfTI, raw) or a phantom spec as a Scene."""
