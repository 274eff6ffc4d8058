"""matup's native module; use the functions of the `matup` package, which give these their
friendly signatures."""

from typing import Any, Callable, List, Optional, Tuple

import numpy as np

__version__: str

class Network:
    def __init__(
        self, function: Callable[[np.ndarray], Any], name: str, scale: int, tile: int, overlap: int, batch: int
    ) -> None: ...
    @property
    def scale(self) -> int: ...
    @property
    def name(self) -> str: ...

def upscale_folder(
    src: str,
    out: str,
    settings: str,
    network: Optional[Network] = None,
    networks: List[Tuple[str, Network]] = ...,
    format: Optional[str] = None,
    names: Optional[str] = None,
    block_quality: Optional[str] = None,
    normal_convention: Optional[str] = None,
    memory_limit: Optional[int] = None,
    resume: bool = False,
    progress: Optional[Callable[[str, str, int, Optional[float]], Any]] = None,
) -> str: ...
def upscale_images(
    images: List[Tuple[str, np.ndarray, str]],
    settings: str,
    network: Optional[Network] = None,
    networks: List[Tuple[str, Network]] = ...,
    format: Optional[str] = None,
    names: Optional[str] = None,
    normal_convention: Optional[str] = None,
    memory_limit: Optional[int] = None,
    progress: Optional[Callable[[str, str, int, Optional[float]], Any]] = None,
) -> Tuple[str, List[Tuple[str, np.ndarray, str]]]: ...
def upscale_model(
    path: str,
    out: str,
    settings: str,
    network: Optional[Network] = None,
    networks: List[Tuple[str, Network]] = ...,
    format: Optional[str] = None,
    names: Optional[str] = None,
    block_quality: Optional[str] = None,
    memory_limit: Optional[int] = None,
    progress: Optional[Callable[[str, str, int, Optional[float]], Any]] = None,
) -> str: ...
def settings_toml(settings: str) -> str: ...
def read_image(path: str) -> Tuple[np.ndarray, str]: ...
def write_image(path: str, array: np.ndarray, format: Optional[str] = None) -> None: ...
def extension_of(format: str) -> str: ...
def read_material(path: str, normal_convention: Optional[str] = None) -> Tuple[str, List[Tuple[str, np.ndarray]]]: ...
def read_material_images(
    images: List[Tuple[str, np.ndarray, str]], normal_convention: Optional[str] = None
) -> Tuple[str, List[Tuple[str, np.ndarray]]]: ...
def evaluate(reference: str, candidate: str, scale: int = 1, lights: int = 16, shading: str = "ggx") -> str: ...
def render(path: str, lights: int = 16, shading: str = "ggx") -> np.ndarray: ...
def plugins() -> str: ...
