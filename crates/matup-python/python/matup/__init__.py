"""matup: upscale physically based materials (SVBRDF map stacks) ×2 to ×16.

The same libraries as the ``matup`` command line, from Python::

    import matup
    maps = {"base_color": albedo_u8, "normal": normal_u8, "roughness": rough_u8}
    big = matup.upscale(maps, scale=4)                 # same keys, same dtypes, 4× the size
    report = matup.upscale_folder("wood/", "wood_4x/")  # run.json as a dict
    big = matup.upscale(maps, upsampler=lambda x: my_net(x))  # any network, as a callable

Settings are the TOML keys of a configuration (``docs/configuration.md``), given as keywords:
by name where the name is one setting (``self_ensemble=8``, ``epochs=0``, ``window=9``), or a
section as a dict (``filter={"window": 9}``). Values are what the flags take.

While matup works the GIL is released; Ctrl-C (``KeyboardInterrupt``) stops a run between
its maps and network calls, leaving no partial output. Errors are :class:`MatupError`
(:class:`InvalidInput` is also a ``ValueError``, :class:`FileError` an ``OSError``) with the
command line's messages; an exception raised by your callable or progress callback reaches
you as itself.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Union

import numpy as np

from . import _matup
from .errors import FileError, InvalidInput, MatupError

__all__ = [
    "upscale",
    "upscale_folder",
    "upscale_model",
    "read_material",
    "write_material",
    "read_image",
    "write_image",
    "render",
    "evaluate",
    "list",
    "settings",
    "Network",
    "Material",
    "MatupError",
    "InvalidInput",
    "FileError",
]
__version__ = _matup.__version__

log = logging.getLogger("matup")

PathLike = Union[str, "os.PathLike[str]"]
#: ``progress(kind, text, count, number)``: ``("stage", name, total, None)``,
#: ``("advance", "", done, loss)``, ``("tiles", "", done, total)`` (the tiles of the network's
#: call in progress, after each batch of them) or ``("note", message, 0, None)``. An exception
#: it raises stops the run at the next tile and reaches the caller.
ProgressCallback = Callable[[str, str, int, Optional[float]], Any]

_list = list  # `list` is also one of this module's functions


class Network:
    """A Python callable as matup's network.

    ``function(batch)`` takes an N×H×W×3 float32 NumPy array of RGB tiles in [0, 1] and returns
    N×(s·H)×(s·W)×3 (a NumPy array, or anything ``numpy.asarray`` takes). matup encodes each
    map for it, tiles with ``overlap`` texels of context (wrapped for tileable materials),
    runs its self-ensemble, blends the tiles, back-projects and clamps chroma around it.

    ``scale`` is read from the output of one probe call when not given. ``tile`` is the side
    of the tiles in input texels, ``batch`` the tiles a call. A PyTorch module is one line
    away::

        net = matup.Network(lambda x: model(torch.from_numpy(x).permute(0, 3, 1, 2).to(dev))
                            .permute(0, 2, 3, 1).clamp(0, 1).cpu().numpy())
    """

    def __init__(
        self,
        function: Callable[[np.ndarray], Any],
        scale: Optional[int] = None,
        tile: int = 256,
        overlap: int = 16,
        batch: int = 4,
        name: Optional[str] = None,
    ):
        if not callable(function):
            raise InvalidInput(f"a Network needs a callable, not {type(function).__name__}")
        for what, value in (("tile", tile), ("batch", batch)):
            if int(value) < 1:
                raise InvalidInput(f"{what} must be at least 1, not {value}")
        if int(overlap) < 0:
            raise InvalidInput(f"overlap must not be negative, not {overlap}")
        self.function = function
        self.scale = int(scale) if scale is not None else _probe_scale(function)
        if self.scale < 1:
            raise InvalidInput(f"scale must be at least 1, not {scale}")
        self.tile, self.overlap, self.batch = int(tile), int(overlap), int(batch)
        self.name = name or getattr(function, "__qualname__", None) or type(function).__name__
        self._native = _matup.Network(
            function, self.name, self.scale, self.tile, self.overlap, self.batch
        )

    def __call__(self, batch: np.ndarray) -> Any:
        return self.function(batch)

    def __repr__(self) -> str:
        return repr(self._native)


def _probe_scale(function: Callable[[np.ndarray], Any]) -> int:
    """The factor ``function`` upsamples by: its output's size over a 32×32 probe's."""
    side = 32
    out = np.asarray(function(np.full((1, side, side, 3), 0.5, np.float32)))
    if out.ndim != 4 or out.shape[0] != 1 or out.shape[3] != 3:
        raise InvalidInput(
            f"the network returned shape {out.shape} for a (1, {side}, {side}, 3) batch: "
            "want (N, H·s, W·s, 3)"
        )
    scale = out.shape[1] // side
    if scale < 1 or out.shape[1] != side * scale or out.shape[2] != side * scale:
        raise InvalidInput(
            f"the network returned {out.shape[1]}×{out.shape[2]} for {side}×{side}: "
            "not a whole scale"
        )
    return scale


def _as_network(upsampler: Any) -> Optional[Network]:
    if isinstance(upsampler, Network):
        return upsampler
    if callable(upsampler):
        return Network(upsampler)
    if not isinstance(upsampler, str):
        raise InvalidInput(
            f"upsampler must be a name (see matup.list()) or a callable, not "
            f"{type(upsampler).__name__}"
        )
    return None


class _Bars:
    """Progress as tqdm bars (notes to the ``matup`` logger)."""

    def __init__(self, tqdm: Any):
        self.tqdm, self.bar = tqdm, None

    def __call__(self, kind: str, text: str, count: int, loss: Optional[float]) -> None:
        if kind == "stage":
            self.close()
            self.bar = self.tqdm(total=count or None, desc=text, leave=False)
        elif kind == "advance" and self.bar is not None:
            self.bar.update(count)
            if loss is not None:
                self.bar.set_postfix(loss=f"{loss:.5f}")
        elif kind == "note":
            log.info(text)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _notes_to_log(kind: str, text: str, count: int, loss: Optional[float]) -> None:
    if kind == "note":
        log.info(text)


class _Progress:
    """The callback a run reports to: the caller's, tqdm's bars where tqdm is installed, or
    the logger alone (``progress=False``)."""

    def __init__(self, progress: Union[None, bool, ProgressCallback]):
        self.bars = None
        if callable(progress):
            self.callback = progress
        elif progress is False:
            self.callback = _notes_to_log
        else:
            try:
                from tqdm.auto import tqdm
            except ImportError:
                self.callback = _notes_to_log
            else:
                self.bars = self.callback = _Bars(tqdm)

    def __enter__(self) -> ProgressCallback:
        return self.callback

    def __exit__(self, *exc: Any) -> None:
        if self.bars is not None:
            self.bars.close()


def _settings_json(settings: Dict[str, Any], **given: Any) -> str:
    merged = dict(settings)
    for key, value in given.items():
        if value is not None or key == "tileable":
            merged[key] = value
    try:
        return json.dumps(merged)
    except TypeError as e:
        raise InvalidInput(f"settings: {e}") from None


def _run_settings(
    settings: Dict[str, Any], scale: Any, size: Any, tileable: Any, device: Any, upsampler: Any
) -> tuple:
    """A run's native network (or None, for a named upsampler) and its settings as JSON."""
    network = _as_network(upsampler)
    text = _settings_json(
        settings,
        scale=scale,
        size=None if size is None else str(size),
        tileable=tileable,
        device=device,
        upsampler=None if network else upsampler,
    )
    return (network._native if network else None), text


def _instead(networks: Optional[Mapping[str, Any]]) -> List[tuple]:
    """``networks`` (matup's network names → callables or :class:`Network` s) as the native
    side registers them."""
    if not networks:
        return []
    if not isinstance(networks, Mapping):
        raise InvalidInput("networks must be a dict of matup's network names to callables")
    return [(str(name), _as_network(fn)._native) for name, fn in networks.items()]


def settings(**settings: Any) -> str:
    """The configuration a run would use, as TOML: matup's defaults with ``settings`` over
    them (the keywords :func:`upscale` takes)."""
    return _matup.settings_toml(_settings_json(settings))


def upscale_folder(
    src: PathLike,
    out: PathLike,
    *,
    scale: Optional[int] = None,
    size: Optional[Union[int, str]] = None,
    tileable: Optional[bool] = None,
    normal_convention: Optional[str] = None,
    device: Optional[str] = None,
    upsampler: Union[str, Callable[[np.ndarray], Any], Network] = "auto",
    networks: Optional[Mapping[str, Any]] = None,
    format: Optional[str] = None,
    names: Optional[str] = None,
    block_quality: Optional[str] = None,
    memory_limit: Optional[int] = None,
    resume: bool = False,
    progress: Union[None, bool, ProgressCallback] = None,
    **settings: Any,
) -> Dict[str, Any]:
    """Upscales the material in the folder ``src`` into ``out`` (created; never ``src``), as
    ``matup upscale SRC -o OUT`` does: every map back under its own name and format (or
    ``format``: png, png16, jpg, exr-half, exr-float, tiff, tga, webp, dds, ...), with
    ``preview.png`` and ``run.json``. Returns the run's report (run.json) as a dict.

    ``scale`` is 2, 3, 4, 8 or 16 (default 4); ``size`` an output side instead (4096, "4K",
    "4096x2048"). ``tileable`` True or False decides wrapping (None: decided from the maps).
    ``normal_convention`` is "opengl" or "directx" where the files do not say. ``device`` says
    where the networks run: "auto" (the default: the first hardware GPU adapter, discrete
    before integrated, through Vulkan, Metal or DirectX 12, else the CPU), "cpu", "gpu" (the
    first adapter), "gpu:N" or "gpu:NAME" (an adapter ``matup list`` shows, by index or a part
    of its name, as "gpu:llvmpipe"); the report's ``network_devices`` says where each ran and
    why. ``upsampler``
    is a registered name (``matup.list()``), a callable or a :class:`Network`. ``networks``
    runs matup's own networks through callables, by name (``{"span_x4_materials": fn}``):
    where the run chooses that network, ``fn`` runs in its place (the same network on a GPU
    through PyTorch), the run's choices unchanged. ``memory_limit`` is in bytes.
    ``progress``: a callback, ``False`` for none, or by default tqdm's bars when tqdm is
    installed.
    """
    network, text = _run_settings(settings, scale, size, tileable, device, upsampler)
    with _Progress(progress) as callback:
        report = _matup.upscale_folder(
            os.fspath(src),
            os.fspath(out),
            text,
            network=network,
            networks=_instead(networks),
            format=format,
            names=names,
            block_quality=block_quality,
            normal_convention=normal_convention,
            memory_limit=memory_limit,
            resume=resume,
            progress=callback,
        )
    return json.loads(report)


def upscale_model(
    path: PathLike,
    out: PathLike,
    *,
    scale: Optional[int] = None,
    size: Optional[Union[int, str]] = None,
    tileable: Optional[bool] = None,
    device: Optional[str] = None,
    upsampler: Union[str, Callable[[np.ndarray], Any], Network] = "auto",
    networks: Optional[Mapping[str, Any]] = None,
    format: Optional[str] = None,
    names: Optional[str] = None,
    block_quality: Optional[str] = None,
    memory_limit: Optional[int] = None,
    progress: Union[None, bool, ProgressCallback] = None,
    **settings: Any,
) -> Dict[str, Any]:
    """Upscales every texture of a glTF model (``.gltf`` or ``.glb``) into ``out`` in its role,
    as ``matup upscale MODEL -o OUT`` does; the model is written beside them with its geometry
    as it was. Returns ``{"materials": {label: report}, "notes": [...], "written": [...]}``."""
    network, text = _run_settings(settings, scale, size, tileable, device, upsampler)
    with _Progress(progress) as callback:
        report = _matup.upscale_model(
            os.fspath(path),
            os.fspath(out),
            text,
            network=network,
            networks=_instead(networks),
            format=format,
            names=names,
            block_quality=block_quality,
            memory_limit=memory_limit,
            progress=callback,
        )
    return json.loads(report)


# The file stem each role of `upscale`'s dict is written under: names matup's folder reader
# recognises. Any other key is written under its own name and carried as the folder's other
# maps are.
_ROLE_STEMS = {
    "base_color": "basecolor",
    "basecolor": "basecolor",
    "albedo": "basecolor",
    "normal": "normal",
    "roughness": "roughness",
    "metallic": "metallic",
    "height": "height",
    "displacement": "height",
    "occlusion": "ao",
    "ao": "ao",
    "emission": "emissive",
    "emissive": "emissive",
    "alpha": "opacity",
    "opacity": "opacity",
}
_EXTENSIONS = {np.dtype(np.uint8): ".png", np.dtype(np.uint16): ".png", np.dtype(np.float32): ".exr"}
_FORMATS = {np.dtype(np.uint8): "png", np.dtype(np.uint16): "png16", np.dtype(np.float32): "exr-float"}
# Float arrays of other widths (NumPy's default float64, half floats) are worked on as float32,
# matup's own precision, and given back in their own dtype.
_AS_FLOAT32 = (np.dtype(np.float16), np.dtype(np.float64))


def _checked_maps(maps: Mapping[str, Any]) -> Dict[str, np.ndarray]:
    if not isinstance(maps, Mapping) or not maps:
        raise InvalidInput("maps must be a non-empty dict of arrays by role")
    checked: Dict[str, np.ndarray] = {}
    size = None
    for key, value in maps.items():
        if not isinstance(key, str) or not key or any(c in key for c in "/\\:\0") or key[0] == ".":
            raise InvalidInput(f"map name {key!r} cannot name a file")
        array = np.asarray(value)
        if array.dtype in _AS_FLOAT32:
            if np.isfinite(array).all() and np.abs(array).max(initial=0) > np.finfo(np.float32).max:
                raise InvalidInput(f"maps[{key!r}] holds values beyond float32's range")
            array = array.astype(np.float32)
        if array.dtype not in _EXTENSIONS:
            raise InvalidInput(
                f"maps[{key!r}]: dtype {array.dtype} is not uint8, uint16 or a float "
                "(float16, float32, float64)"
            )
        if not (array.ndim == 2 or (array.ndim == 3 and 1 <= array.shape[2] <= 4)):
            raise InvalidInput(
                f"maps[{key!r}]: shape {array.shape}; want H×W or H×W×C with C from 1 to 4"
            )
        if array.shape[0] == 0 or array.shape[1] == 0:
            raise InvalidInput(f"maps[{key!r}]: shape {array.shape} holds no texels")
        if array.dtype == np.float32 and not np.isfinite(array).all():
            raise InvalidInput(f"maps[{key!r}] holds NaN or infinity")
        if size is None:
            size = (key, array.shape[:2])
        elif array.shape[:2] != size[1]:
            raise InvalidInput(
                f"maps[{key!r}] is {array.shape[1]}×{array.shape[0]} and maps[{size[0]!r}] "
                f"{size[1][1]}×{size[1][0]}: every map must be one size"
            )
        checked[key] = np.ascontiguousarray(array)
    stems = [_ROLE_STEMS.get(k.lower(), k) for k in checked]
    if len(set(s.lower() for s in stems)) != len(stems):
        raise InvalidInput(f"two maps name one role: {sorted(checked)}")
    return checked


def upscale(
    maps: Union[Mapping[str, Any], "Material"],
    scale: Optional[int] = 4,
    size: Optional[Union[int, str]] = None,
    tileable: Optional[bool] = None,
    normal_convention: Optional[str] = None,
    device: Optional[str] = None,
    upsampler: Union[str, Callable[[np.ndarray], Any], Network] = "auto",
    networks: Optional[Mapping[str, Any]] = None,
    progress: Union[None, bool, ProgressCallback] = None,
    **settings: Any,
) -> Union[Dict[str, np.ndarray], "Material"]:
    """Upscales a material given as arrays; returns the same keys, dtypes and conventions.

    ``maps`` holds NumPy arrays by role, as files would hold them: H×W or H×W×C, uint8,
    uint16 or float (float16, float32 or float64, worked on as float32; float colour is
    linear, as in EXR). Roles: ``base_color`` (RGB, or RGBA
    with alpha), ``normal`` (tangent-space, OpenGL unless ``normal_convention="directx"``),
    ``roughness``, ``metallic``, ``height``, ``occlusion``, ``emission``, ``alpha``; any other
    key is carried as a folder's other maps are (upsampled on its own). Every map is one
    size. A :class:`Material` (from :func:`read_material`) is upscaled with its own files'
    layout, and a :class:`Material` comes back.

    The other arguments and ``settings`` are :func:`upscale_folder`'s. The arrays go to matup
    in memory, and no file is written: the result holds exactly the samples ``matup upscale``
    writes for the same files (for a :class:`Material`'s JPEG, WebP or DDS files, the samples
    before that format's lossy encoding, which :func:`write_material` applies).
    """
    network, text = _run_settings(settings, scale, size, tileable, device, upsampler)
    if isinstance(maps, Material):
        images = [
            (name, np.ascontiguousarray(array), maps.formats.get(name) or _FORMATS[array.dtype])
            for name, array in maps.files.items()
        ]
    else:
        checked = _checked_maps(maps)
        stems = {key: _ROLE_STEMS.get(key.lower(), key) for key in checked}
        images = [
            (stems[key] + _EXTENSIONS[array.dtype], array, _FORMATS[array.dtype])
            for key, array in checked.items()
        ]
    with _Progress(progress) as callback:
        _, written = _matup.upscale_images(
            images,
            text,
            network=network,
            networks=_instead(networks),
            names="keep",
            normal_convention=normal_convention,
            progress=callback,
        )
    if isinstance(maps, Material):
        return _material_of_images(written, maps, normal_convention)
    by_stem = {Path(name).stem.lower(): array for name, array, _ in written}
    result = {}
    for key, stem in stems.items():
        array = by_stem.get(stem.lower())
        if array is None:
            raise MatupError(f"the run made no file for maps[{key!r}]")
        array = array[:, :, 0] if checked[key].ndim == 2 else array
        result[key] = array.astype(np.asarray(maps[key]).dtype, copy=False)
    return result


def _material_of_images(written: List[tuple], given: "Material", normal_convention: Optional[str]) -> "Material":
    """The upscaled :class:`Material`: its files those of ``written`` (``(name, array,
    format)``) that ``given`` has (by stem: a resolution tag is rewritten), read as matup reads
    a folder of them."""
    text, arrays = _matup.read_material_images(written, normal_convention)
    description = json.loads(text)
    stems = {Path(name).stem.lower() for name in given.files}
    kept = [(n, a, f) for n, a, f in written if Path(n).stem.lower() in stems]
    return Material(
        folder="",
        size=tuple(description["size"]),
        maps=dict(arrays),
        files={name: array for name, array, _ in kept},
        formats={name: format for name, _, format in kept},
        sources=description["sources"],
        notes=description["notes"],
        normal_convention=description["normal_convention"],
        normal_evidence=description["normal_evidence"],
        stand_ins=description["stand_ins"],
    )


@dataclass
class Material:
    """A material folder as matup reads it.

    ``maps`` holds matup's working encoding, float32 H×W×C: linear base colour, unit
    tangent-space normals (OpenGL), roughness, metallic, height and the carried maps by name.
    ``files`` holds each file it was read from as stored (uint8, uint16 or float32, by file
    name) and ``formats`` their formats: :func:`write_material` writes them back so, names,
    packing and formats kept. ``sources`` says which file and channel gave each map.
    """

    folder: str
    size: tuple
    maps: Dict[str, np.ndarray]
    files: Dict[str, np.ndarray] = field(default_factory=dict)
    formats: Dict[str, str] = field(default_factory=dict)
    sources: List[str] = field(default_factory=_list)
    notes: List[str] = field(default_factory=_list)
    normal_convention: Optional[str] = None
    normal_evidence: Optional[str] = None
    stand_ins: List[str] = field(default_factory=_list)


def read_material(path: PathLike, normal_convention: Optional[str] = None) -> Material:
    """Reads the material in the folder ``path`` as ``matup upscale`` would: any layout matup
    knows (exporters' names, packed channels, gloss, DirectX or OpenGL normals)."""
    text, arrays = _matup.read_material(os.fspath(path), normal_convention)
    description = json.loads(text)
    folder = Path(path)
    files, formats = {}, {}
    for entry in sorted(folder.iterdir()):
        if not entry.is_file() or entry.name in ("preview.png", "run.json"):
            continue
        try:
            files[entry.name], formats[entry.name] = _matup.read_image(os.fspath(entry))
        except FileError:
            continue  # not an image matup reads
    return Material(
        folder=os.fspath(folder),
        size=tuple(description["size"]),
        maps=dict(arrays),
        files=files,
        formats=formats,
        sources=description["sources"],
        notes=description["notes"],
        normal_convention=description["normal_convention"],
        normal_evidence=description["normal_evidence"],
        stand_ins=description["stand_ins"],
    )


def write_material(material: Material, out: PathLike, format: Optional[str] = None) -> List[str]:
    """Writes ``material``'s files into the folder ``out`` (created; never the folder it was
    read from) under their names, in their formats or ``format``. Returns the paths."""
    out = Path(out)
    if material.folder and out.resolve() == Path(material.folder).resolve():
        raise FileError(f"{out}: the output folder is the material's own; choose another")
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, array in material.files.items():
        target = out / name
        chosen = format or material.formats.get(name)
        if format:
            extension = _matup.extension_of(format)
            target = target.with_suffix("." + extension)
        write_image(target, array, chosen)
        written.append(os.fspath(target))
    return written


def read_image(path: PathLike) -> np.ndarray:
    """An image file's samples as stored: H×W×C uint8, uint16 or float32 (any format matup
    reads: PNG, JPEG, EXR, TIFF, TGA, BMP, WebP, DDS)."""
    array, _ = _matup.read_image(os.fspath(path))
    return array


def write_image(path: PathLike, array: Any, format: Optional[str] = None) -> None:
    """Writes an H×W or H×W×C array (uint8, uint16 or float32) atomically; ``format`` as
    :func:`upscale_folder` takes it, by default PNG (16-bit for uint16) or EXR for float32."""
    _matup.write_image(os.fspath(path), np.ascontiguousarray(array), format)


def render(path: PathLike, lights: int = 16, shading: str = "ggx") -> np.ndarray:
    """The material in the folder ``path`` rendered under ``lights`` held-out lights (the set
    ``matup eval`` judges under): N×H×W×3 float32 linear radiance."""
    return _matup.render(os.fspath(path), lights, shading)


def evaluate(
    reference: PathLike, candidate: PathLike, scale: int = 1, lights: int = 16, shading: str = "ggx"
) -> Dict[str, Any]:
    """How close the material in ``candidate`` is to the one in ``reference`` (same size),
    as ``matup eval`` measures: render PSNR and FLIP under held-out lights, and each map's
    error. ``scale`` is the factor the candidate was upscaled by (for its texel grid)."""
    return json.loads(_matup.evaluate(os.fspath(reference), os.fspath(candidate), scale, lights, shading))


def list() -> Dict[str, Any]:  # noqa: A001 - matup list
    """The registered upsamplers and shading models, with their options, and the ONNX models
    found: what ``matup list`` prints."""
    return json.loads(_matup.plugins())
