"""ComfyUI nodes over the matup package: whole materials upscaled, not one image at a time.

Maps travel as ComfyUI's IMAGE tensors ([B, H, W, C] float in [0, 1], as the files' codes:
sRGB base colour, normals as colours) and alpha as a MASK ([B, H, W]) in ComfyUI's meaning,
1 − alpha (masks.py). A folder travels as a MATUP_MATERIAL, which keeps its files' names,
packing and formats for "matup: Save material"; folders are read within ComfyUI's input
folder and written within its output folder (folders.py).

The network: an UPSCALE_MODEL where one is given; else, where ComfyUI's device is a GPU, matup's
own networks (models/*.safetensors through spandrel) on it, each where matup would run it;
else matup's own engine on the CPU. Models go through ComfyUI's model management, tiles shrink
on out-of-memory, and progress and cancel are per tile.
"""

from __future__ import annotations

import functools
import os
import re
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np
import torch

import matup

from .folders import inside, stamp
from .masks import alpha_codes, mask_of

MAP_INPUTS = ("normal", "roughness", "metallic", "height", "occlusion", "emission")
GREY = ("roughness", "metallic", "height", "occlusion")
# What stands in for a map not given, in the output (as matup's renders assume).
STAND_INS = {
    "normal": (0.5, 0.5, 1.0),
    "roughness": (0.5,) * 3,
    "metallic": (0.0,) * 3,
    "height": (0.5,) * 3,
    "occlusion": (1.0,) * 3,
    "emission": (0.0,) * 3,
}
SCALES = ["4", "2", "3", "8", "16"]


# matup's own networks as files spandrel opens (models/README.md), which the default node runs
# through torch where ComfyUI's device is a GPU; matup chooses between them per material.
MODELS = Path(__file__).resolve().parents[1] / "models"
OWN_NETWORKS = ("span_x4_materials", "span_x4_degraded", "span_x4_jpeg")
# The tile matup's networks run in (their sidecars' `tile`), halved on out-of-memory down to
# the smallest.
TILE, SMALLEST_TILE = 256, 32
# Bytes a tile's activations take beside the weights, per input texel, as ComfyUI budgets its
# upscale node's: about eight 48-channel float32 feature maps of SPAN ×4 at the input's size,
# and four copies of the ×4 RGB output.
TILE_BYTES_PER_TEXEL = 48 * 4 * 8 + 3 * 4 * 16 * 4


def comfy_device() -> torch.device:
    """ComfyUI's torch device where it runs inside ComfyUI, else the CPU."""
    try:
        from comfy import model_management
    except ImportError:
        return torch.device("cpu")
    return model_management.get_torch_device()


def sidecar_overlap(name: str) -> int:
    """The context matup's network `name` runs its tiles with: its sidecar's `overlap`."""
    text = (MODELS / f"{name}.toml").read_text(encoding="utf-8")
    found = re.search(r"^overlap\s*=\s*(\d+)", text, re.MULTILINE)
    if found is None:
        raise ValueError(f"matup: {name}.toml states no overlap")
    return int(found.group(1))


@functools.lru_cache(maxsize=None)
def own_model(name: str) -> Any:
    """matup's network `name` as spandrel loads it (as "Load Upscale Model" would), on the CPU."""
    import spandrel

    return spandrel.ModelLoader().load_from_file(MODELS / f"{name}.safetensors").eval()


def network_of(upscale_model: Any, device: torch.device, tile: int = TILE, overlap: int = 16) -> matup.Network:
    """A spandrel model (ComfyUI's UPSCALE_MODEL) as matup's network, run on `device` (where
    the caller has put it) in `tile`-texel tiles."""
    dtype = next(upscale_model.model.parameters()).dtype

    def run(batch: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            x = torch.from_numpy(batch).permute(0, 3, 1, 2).to(device=device, dtype=dtype)
            y = upscale_model(x).float().clamp(0, 1)
            return y.permute(0, 2, 3, 1).cpu().numpy()

    name = type(upscale_model.model).__name__
    return matup.Network(run, scale=int(upscale_model.scale), name=name, tile=tile, overlap=overlap)


def on_device(models: List[Any], device: torch.device, run: Callable[[], Any]) -> Any:
    """`run()` with `models` on `device`, as ComfyUI's upscale node runs its model: ComfyUI's
    model management first frees what they and a tile need there, and they go back to the CPU
    afterwards, so other models get the memory."""
    if not models:
        return run()
    try:
        from comfy import model_management
    except ImportError:
        model_management = None
    if model_management is not None:
        required = sum(model_management.module_size(m.model) for m in models)
        required += TILE * TILE * TILE_BYTES_PER_TEXEL
        model_management.free_memory(required, device)
    try:
        for model in models:
            model.to(device)
        return run()
    finally:
        for model in models:
            model.to("cpu")


def out_of_memory(e: BaseException) -> bool:
    """Whether `e` is the GPU running out of memory (ComfyUI's own test where it runs)."""
    try:
        from comfy import model_management
    except ImportError:
        return isinstance(e, torch.cuda.OutOfMemoryError)
    return isinstance(e, model_management.OOM_EXCEPTION)


def with_smaller_tiles(run: Callable[[int], Any], tile: int = TILE) -> Any:
    """`run(tile)`, run again with half the tile while the GPU runs out of memory, as ComfyUI's
    upscale node retries, down to SMALLEST_TILE."""
    while True:
        try:
            return run(tile)
        except Exception as e:
            if tile <= SMALLEST_TILE or not out_of_memory(e):
                raise
            tile //= 2
            if torch.cuda.is_available():
                torch.cuda.empty_cache()


class Networks:
    """What runs a node's network: the UPSCALE_MODEL given, else matup's own networks through
    torch where ComfyUI's device is a GPU, else matup's own engine (on the CPU, the CLI's maps
    exactly)."""

    def __init__(self, upscale_model: Any = None, through_torch: Optional[bool] = None):
        self.device = comfy_device()
        self.given = upscale_model
        if through_torch is None:
            through_torch = self.device.type != "cpu"
        own = upscale_model is None and through_torch
        self.own = {name: own_model(name) for name in OWN_NETWORKS} if own else {}

    def run(self, upscale: Callable[..., Any]) -> Any:
        """`upscale(upsampler=..., networks=...)` with the models on the device, in smaller
        tiles on out-of-memory."""
        models = [self.given] if self.given is not None else list(self.own.values())

        def attempt(tile: int) -> Any:
            given = None if self.given is None else network_of(self.given, self.device, tile)
            own = {
                name: network_of(model, self.device, tile, sidecar_overlap(name))
                for name, model in self.own.items()
            }
            return upscale(upsampler=given or "auto", networks=own or None)

        return on_device(models, self.device, lambda: with_smaller_tiles(attempt, TILE))


def to_codes(image: torch.Tensor, grey: bool) -> np.ndarray:
    """One image of a [B, H, W, C] tensor as 16-bit codes (H×W for grey maps)."""
    array = image.detach().float().clamp(0, 1).cpu().numpy()
    if grey:
        array = array[:, :, 0]
    return np.round(array * 65535.0).astype(np.uint16)


def to_image(codes: np.ndarray) -> torch.Tensor:
    """16-bit (or 8-bit) codes as one [H, W, 3] float image."""
    scale = 65535.0 if codes.dtype == np.uint16 else 255.0
    array = codes.astype(np.float32) / scale
    if array.ndim == 2:
        array = array[:, :, None]
    if array.shape[2] == 1:
        array = np.repeat(array, 3, axis=2)
    return torch.from_numpy(np.ascontiguousarray(array[:, :, :3]))


def settings_of(tileable: str, normal_convention: str) -> Dict[str, Any]:
    return {
        "tileable": {"auto": None, "yes": True, "no": False}[tileable],
        "normal_convention": None if normal_convention == "auto" else normal_convention.lower(),
    }


class UpscaleMaterial:
    """matup: Upscale material — every map of a material at once, back-projected, wrapped
    where it tiles, by matup's tuned network or the UPSCALE_MODEL given."""

    CATEGORY = "image/upscaling"
    FUNCTION = "upscale"
    RETURN_TYPES = ("IMAGE",) * 7 + ("MASK",)
    RETURN_NAMES = ("base_color",) + MAP_INPUTS + ("alpha",)

    @classmethod
    def INPUT_TYPES(cls) -> Dict[str, Any]:
        optional = {name: ("IMAGE",) for name in MAP_INPUTS}
        optional["alpha"] = ("MASK",)
        optional["upscale_model"] = ("UPSCALE_MODEL",)
        optional["size"] = ("INT", {"default": 0, "min": 0, "max": 16384, "step": 1})
        return {
            "required": {
                "base_color": ("IMAGE",),
                "scale": (SCALES,),
                "tileable": (["auto", "yes", "no"],),
                "normal_convention": (["auto", "OpenGL", "DirectX"],),
            },
            "optional": optional,
        }

    def upscale(
        self,
        base_color: torch.Tensor,
        scale: str = "4",
        tileable: str = "auto",
        normal_convention: str = "auto",
        upscale_model: Any = None,
        size: int = 0,
        alpha: Optional[torch.Tensor] = None,
        **maps: Optional[torch.Tensor],
    ) -> Tuple[torch.Tensor, ...]:
        given = {"base_color": base_color, **{k: v for k, v in maps.items() if v is not None}}
        unknown = set(given) - {"base_color", *MAP_INPUTS}
        if unknown:
            raise ValueError(f"matup: no such map input: {sorted(unknown)}")
        networks = Networks(upscale_model)
        settings = settings_of(tileable, normal_convention)
        outputs: Dict[str, list] = {name: [] for name in self.RETURN_NAMES}
        progress = comfy_progress()
        for b in range(base_color.shape[0]):
            arrays = {
                name: to_codes(image[min(b, image.shape[0] - 1)], name in GREY)
                for name, image in given.items()
            }
            if alpha is not None:
                mask = alpha[min(b, alpha.shape[0] - 1)].detach().float().cpu().numpy()
                codes = alpha_codes(mask, arrays["base_color"].shape[:2])
                if codes is not None:
                    arrays["alpha"] = codes
            big = networks.run(
                functools.partial(
                    matup.upscale,
                    arrays,
                    scale=None if size else int(scale),
                    size=size or None,
                    progress=progress,
                    **settings,
                )
            )
            side = big["base_color"].shape[:2]
            for name in self.RETURN_NAMES:
                if name == "alpha":
                    outputs[name].append(torch.from_numpy(mask_of(big.get("alpha"), side)))
                elif name in big:
                    outputs[name].append(to_image(big[name]))
                else:
                    outputs[name].append(torch.tensor(STAND_INS[name]).expand(*side, 3).clone())
        return tuple(torch.stack(outputs[name]) for name in self.RETURN_NAMES)


def comfy_progress() -> Any:
    """matup's progress callback inside ComfyUI: each network call's tiles on ComfyUI's
    progress bar, and ComfyUI's cancel checked at every event, so a cancel stops the run at
    the next tile (the exception it raises ends the run and reaches ComfyUI). Outside ComfyUI,
    no progress."""
    try:
        import comfy.utils
        from comfy import model_management
    except ImportError:
        return False
    bar = comfy.utils.ProgressBar(1)

    def callback(kind: str, text: str, count: int, number: Any) -> None:
        if kind == "tiles":
            bar.update_absolute(count, int(number))
        model_management.throw_exception_if_processing_interrupted()

    return callback


class LoadMaterial:
    """matup: Load material — a folder in any layout matup reads (exporters' names, packed
    channels, DirectX or OpenGL normals), as a MATUP_MATERIAL and its maps as images."""

    CATEGORY = "image/upscaling"
    FUNCTION = "load"
    RETURN_TYPES = ("MATUP_MATERIAL", "IMAGE", "IMAGE", "IMAGE", "IMAGE", "IMAGE", "STRING")
    RETURN_NAMES = ("material", "base_color", "normal", "roughness", "metallic", "height", "sources")

    @classmethod
    def INPUT_TYPES(cls) -> Dict[str, Any]:
        return {"required": {"folder": ("STRING", {"default": ""})}}

    @classmethod
    def IS_CHANGED(cls, folder: str) -> str:
        """A new stamp when a file of the folder changes, so ComfyUI does not reuse the cache."""
        return stamp(inside(comfy_folder("input"), folder, "Load material"))

    def load(self, folder: str) -> Tuple[Any, ...]:
        material = matup.read_material(inside(comfy_folder("input"), folder, "Load material"))
        maps = material.maps
        linear = maps["base_color"][:, :, :3]
        srgb = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)
        images = [
            srgb,
            maps["normal"] * 0.5 + 0.5,
            maps["roughness"],
            maps["metallic"],
            maps.get("height", np.full(material.size[::-1] + (1,), 0.5, np.float32)),
        ]
        tensors = [
            torch.from_numpy(np.ascontiguousarray(np.repeat(i, 3 // i.shape[2], axis=2).clip(0, 1)))[None]
            for i in images
        ]
        return (material, *tensors, "\n".join(material.sources))


class UpscaleMaterialFolder:
    """matup: Upscale loaded material — a MATUP_MATERIAL upscaled whole: every file back
    under its own name, packing and format."""

    CATEGORY = "image/upscaling"
    FUNCTION = "upscale"
    RETURN_TYPES = ("MATUP_MATERIAL",)
    RETURN_NAMES = ("material",)

    @classmethod
    def INPUT_TYPES(cls) -> Dict[str, Any]:
        return {
            "required": {
                "material": ("MATUP_MATERIAL",),
                "scale": (SCALES,),
                "tileable": (["auto", "yes", "no"],),
                "normal_convention": (["auto", "OpenGL", "DirectX"],),
            },
            "optional": {"upscale_model": ("UPSCALE_MODEL",)},
        }

    def upscale(self, material, scale="4", tileable="auto", normal_convention="auto", upscale_model=None):
        big = Networks(upscale_model).run(
            functools.partial(
                matup.upscale,
                material,
                scale=int(scale),
                progress=comfy_progress(),
                **settings_of(tileable, normal_convention),
            )
        )
        return (big,)


class SaveMaterial:
    """matup: Save material — a MATUP_MATERIAL written to a folder under its own names and
    formats (or one format for every file)."""

    CATEGORY = "image/upscaling"
    FUNCTION = "save"
    OUTPUT_NODE = True
    RETURN_TYPES = ("STRING",)
    RETURN_NAMES = ("written",)
    FORMATS = ["as loaded", "png", "png16", "jpg", "exr-half", "exr-float", "tiff", "tga", "webp", "dds"]

    @classmethod
    def INPUT_TYPES(cls) -> Dict[str, Any]:
        return {
            "required": {
                "material": ("MATUP_MATERIAL",),
                "folder": ("STRING", {"default": "matup"}),
                "format": (cls.FORMATS,),
            }
        }

    def save(self, material, folder: str, format: str = "as loaded"):
        folder = inside(comfy_folder("output"), folder, "Save material")
        written = matup.write_material(material, folder, None if format == "as loaded" else format)
        return {"ui": {"text": written}, "result": ("\n".join(written),)}


def comfy_folder(kind: str) -> str:
    """ComfyUI's input or output folder (`folder_paths`), or the working folder outside
    ComfyUI."""
    try:
        import folder_paths
    except ImportError:
        return os.getcwd()
    if kind == "input":
        return folder_paths.get_input_directory()
    return folder_paths.get_output_directory()


NODE_CLASS_MAPPINGS = {
    "MatupUpscaleMaterial": UpscaleMaterial,
    "MatupLoadMaterial": LoadMaterial,
    "MatupUpscaleLoadedMaterial": UpscaleMaterialFolder,
    "MatupSaveMaterial": SaveMaterial,
}
NODE_DISPLAY_NAME_MAPPINGS = {
    "MatupUpscaleMaterial": "matup: Upscale material",
    "MatupLoadMaterial": "matup: Load material",
    "MatupUpscaleLoadedMaterial": "matup: Upscale loaded material",
    "MatupSaveMaterial": "matup: Save material",
}
