"""The package with PyTorch: a module as the callable, and the ComfyUI nodes called as ComfyUI
calls them (torch tensors in, a spandrel-loaded model as UPSCALE_MODEL). Needs torch and
spandrel: scripts/python-torch-tests.sh installs them and runs this file."""

import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="scripts/python-torch-tests.sh installs torch")
spandrel = pytest.importorskip("spandrel", reason="scripts/python-torch-tests.sh installs spandrel")

import matup  # noqa: E402

REPO = Path(__file__).resolve().parents[3]
SAMPLE = REPO / "samples" / "victorian_wood"
sys.path.insert(0, str(REPO))
from comfyui import nodes  # noqa: E402


def sample(name, grey=False):
    array = matup.read_image(SAMPLE / name)
    return array[:, :, 0] if grey else array


def as_comfy(array):
    """A file's codes as ComfyUI's IMAGE: [1, H, W, 3] float."""
    image = array.astype(np.float32) / 255.0
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    return torch.from_numpy(image)[None]


def span_model():
    """A SPAN ×4 (random weights) loaded by spandrel from its state dict, as ComfyUI's
    "Load Upscale Model" loads one."""
    from spandrel.architectures.SPAN import SPAN

    torch.manual_seed(0)
    net = SPAN(num_in_ch=3, num_out_ch=3, feature_channels=48, upscale=4)
    model = spandrel.ModelLoader().load_from_state_dict(net.state_dict()).eval()
    assert isinstance(model, spandrel.ImageModelDescriptor) and model.scale == 4
    return model


def box_back(hr, scale):
    h, w = hr.shape[0] // scale, hr.shape[1] // scale
    return hr.astype(float).reshape(h, scale, w, scale, *hr.shape[2:]).mean(axis=(1, 3))


def test_a_pytorch_module_is_the_network_and_its_output_box_filters_back():
    torch.manual_seed(0)
    module = torch.nn.Sequential(
        torch.nn.Conv2d(3, 48, 3, padding=1), torch.nn.PixelShuffle(4)
    ).eval()

    def network(x):
        with torch.no_grad():
            y = module(torch.from_numpy(x).permute(0, 3, 1, 2))
            return y.clamp(0, 1).permute(0, 2, 3, 1).numpy()

    maps = {"base_color": sample("baseColor.png"), "roughness": sample("roughness.png", grey=True)}
    big = matup.upscale(maps, upsampler=network, progress=False)
    assert big["base_color"].shape == (512, 512, 3)
    # Back-projection: whatever the module draws, each 4×4 block keeps its input texel.
    assert np.abs(box_back(big["roughness"], 4) - maps["roughness"]).max() <= 1.0


def test_the_upscale_node_takes_comfyui_tensors_and_a_spandrel_model():
    node = nodes.UpscaleMaterial()
    assert "upscale_model" in node.INPUT_TYPES()["optional"]
    base = as_comfy(sample("baseColor.png"))
    normal = as_comfy(sample("normal.png"))
    rough = as_comfy(sample("roughness.png", grey=True))
    # LoadImage's mask of an image without alpha: 64×64 zeros, meaning opaque.
    mask = torch.zeros(1, 64, 64)
    out = node.upscale(
        base, "4", "auto", "auto", upscale_model=span_model(), normal=normal, roughness=rough, alpha=mask
    )
    names = dict(zip(node.RETURN_NAMES, out))
    assert names["base_color"].shape == (1, 512, 512, 3) and names["base_color"].dtype == torch.float32
    assert names["normal"].shape == (1, 512, 512, 3)
    # Opaque out as ComfyUI means it: a zero mask, which JoinImageWithAlpha reads as alpha 1.
    assert names["alpha"].shape == (1, 512, 512) and not names["alpha"].any()
    # A map not given comes back as its stand-in; a given one box-filters back to its input.
    assert torch.allclose(names["metallic"], torch.zeros(1, 512, 512, 3))
    back = box_back(names["roughness"][0, :, :, 0].numpy(), 4)
    assert np.abs(back - rough[0, :, :, 0].numpy()).max() < 1.5 / 255


def test_the_built_in_network_runs_without_a_model_and_matches_the_package():
    node = nodes.UpscaleMaterial()
    base = as_comfy(sample("baseColor.png"))
    out = node.upscale(base, "2", "yes", "auto")
    assert out[0].shape == (1, 256, 256, 3)
    # On the CPU the node gives the maps of the package (the CLI's files), within a level.
    maps = {"base_color": sample("baseColor.png"), "normal": sample("normal.png"),
            "roughness": sample("roughness.png", grey=True)}
    out = node.upscale(*[as_comfy(maps["base_color"]), "4", "auto", "auto"],
                       normal=as_comfy(maps["normal"]), roughness=as_comfy(maps["roughness"]))
    want = matup.upscale(maps, progress=False)
    for name, image in zip(node.RETURN_NAMES, out):
        if name in want:
            got = image[0].numpy() * 255.0
            got = got[:, :, 0] if want[name].ndim == 2 else got
            assert np.abs(got - want[name]).max() <= 1.0, name


def test_load_upscale_save_keeps_the_folders_names(tmp_path, monkeypatch):
    # Outside ComfyUI the working folder stands for its input and output folders.
    monkeypatch.chdir(REPO)
    material, base, normal, rough, metal, height, sources = nodes.LoadMaterial().load(str(SAMPLE))
    assert base.shape == (1, 128, 128, 3) and "baseColor.png" in sources
    (big,) = nodes.UpscaleMaterialFolder().upscale(material, "2", "auto", "auto", span_model())
    monkeypatch.chdir(tmp_path)
    result = nodes.SaveMaterial().save(big, "saved", "as loaded")
    written = result["result"][0].splitlines()
    assert sorted(Path(p).name for p in written) == sorted(p.name for p in SAMPLE.glob("*.png"))
    assert matup.read_image(tmp_path / "saved" / "baseColor.png").shape == (256, 256, 3)


def test_the_shipped_network_for_spandrel_is_matups_own():
    """models/span_x4_materials.safetensors (what "Load Upscale Model" opens) as the callable
    gives the maps matup's own ONNX network gives, tiled as its sidecar says."""
    model = spandrel.ModelLoader().load_from_file(REPO / "models/span_x4_materials.safetensors").eval()
    assert type(model.model).__name__ == "SPAN" and model.scale == 4

    def run(x):
        with torch.no_grad():
            y = model(torch.from_numpy(x).permute(0, 3, 1, 2))
            return y.clamp(0, 1).permute(0, 2, 3, 1).numpy()

    maps = {"base_color": sample("baseColor.png"), "normal": sample("normal.png"),
            "roughness": sample("roughness.png", grey=True)}
    own = matup.upscale(maps, upsampler="onnx:span_x4_materials", progress=False)
    torch_net = matup.Network(run, scale=4, tile=256, overlap=22)
    called = matup.upscale(maps, upsampler=torch_net, progress=False)
    for role in maps:
        diff = np.abs(own[role].astype(int) - called[role].astype(int))
        assert diff.max() <= 1, (role, diff.max())


class Counted:
    """A spandrel model that counts its calls."""

    def __init__(self, model):
        self.inner, self.model, self.scale, self.calls = model, model.model, model.scale, 0

    def __call__(self, x):
        self.calls += 1
        return self.inner(x)

    def to(self, device):
        self.inner.to(device)
        return self


def test_the_default_node_through_torch_runs_matups_own_networks_where_matup_chooses_them(
    tmp_path, monkeypatch
):
    """The node's GPU path, forced here on the CPU: matup's two networks through spandrel give
    the maps matup's own engine gives, within a level, each where the route chooses it (a JPEG
    base colour takes the degraded network)."""
    counted = {name: Counted(nodes.own_model(name)) for name in nodes.OWN_NETWORKS}
    monkeypatch.setattr(nodes, "own_model", lambda name: counted[name])
    base = as_comfy(sample("baseColor.png"))
    rough = as_comfy(sample("roughness.png", grey=True))
    # A web texture's JPEG colour, which takes the degraded network.
    folder = tmp_path / "web"
    folder.mkdir()
    for name in ("normal.png", "roughness.png"):
        (folder / name).write_bytes((SAMPLE / name).read_bytes())
    matup.write_image(folder / "baseColor.jpg", sample("baseColor.png"), "jpg")
    material = matup.read_material(folder)

    def both_nodes():
        maps = nodes.UpscaleMaterial().upscale(base, "4", "auto", "auto", roughness=rough)
        after_maps = {name: model.calls for name, model in counted.items()}
        (folder_out,) = nodes.UpscaleMaterialFolder().upscale(material, "4")
        return maps, folder_out, after_maps

    own_maps, own_folder, _ = both_nodes()
    assert all(model.calls == 0 for model in counted.values())
    networks = nodes.Networks
    monkeypatch.setattr(nodes, "Networks", lambda model=None: networks(model, through_torch=True))
    torch_maps, torch_folder, after_maps = both_nodes()
    # The clean maps ran the material network; the JPEG folder, the one for JPEG maps.
    assert after_maps["span_x4_materials"] > 0 and after_maps["span_x4_jpeg"] == 0
    assert counted["span_x4_jpeg"].calls > 0 and counted["span_x4_degraded"].calls == 0
    for name, a, b in zip(nodes.UpscaleMaterial.RETURN_NAMES, own_maps, torch_maps):
        assert a.shape == b.shape, name
        assert (a - b).abs().max().item() <= 1.01 / 255, name
    for name, array in own_folder.files.items():
        diff = np.abs(array.astype(int) - torch_folder.files[name].astype(int))
        assert diff.max() <= 1, (name, diff.max())


def test_out_of_memory_runs_again_in_smaller_tiles():
    tried = []

    def run(tile):
        tried.append(tile)
        if tile > 64:
            raise torch.cuda.OutOfMemoryError("CUDA out of memory")
        return tile

    assert nodes.with_smaller_tiles(run, 256) == 64 and tried == [256, 128, 64]
    # Other errors, and memory still short at the smallest tile, are raised as they are.
    def bad(tile):
        tried.append(tile)
        raise ValueError("bad")

    def always_short(tile):
        tried.append(tile)
        raise torch.cuda.OutOfMemoryError("still")

    tried.clear()
    with pytest.raises(ValueError):
        nodes.with_smaller_tiles(bad, 256)
    assert tried == [256]
    tried.clear()
    with pytest.raises(torch.cuda.OutOfMemoryError):
        nodes.with_smaller_tiles(always_short, 128)
    assert tried == [128, 64, 32]


class Interrupted(Exception):
    """comfy.model_management.InterruptProcessingException's stand-in."""


def fake_comfy(monkeypatch, interrupt_at):
    """ComfyUI's modules as the nodes use them: a progress bar that records, and a cancel
    posted once `interrupt_at` tiles have been reported. Returns the bar's updates."""
    import types

    updates = []
    comfy = types.ModuleType("comfy")
    utils = types.ModuleType("comfy.utils")
    management = types.ModuleType("comfy.model_management")

    class ProgressBar:
        def __init__(self, total):
            self.total = total

        def update_absolute(self, value, total=None):
            updates.append((value, total))

    def throw_exception_if_processing_interrupted():
        if len(updates) >= interrupt_at:
            raise Interrupted("Processing interrupted")

    utils.ProgressBar = ProgressBar
    management.get_torch_device = lambda: torch.device("cpu")
    management.throw_exception_if_processing_interrupted = throw_exception_if_processing_interrupted
    management.module_size = lambda module: sum(p.numel() * p.element_size() for p in module.parameters())
    management.free_memory = lambda required, device: None
    management.OOM_EXCEPTION = torch.cuda.OutOfMemoryError
    comfy.utils, comfy.model_management = utils, management
    for name, module in (("comfy", comfy), ("comfy.utils", utils), ("comfy.model_management", management)):
        monkeypatch.setitem(sys.modules, name, module)
    return updates


def test_a_cancel_stops_the_node_at_the_next_tile_and_progress_is_per_tile(monkeypatch):
    updates = fake_comfy(monkeypatch, interrupt_at=3)
    monkeypatch.setattr(nodes, "TILE", 32)
    model = Counted(span_model())
    base = as_comfy(sample("baseColor.png"))
    with pytest.raises(Interrupted):
        nodes.UpscaleMaterial().upscale(base, "4", "auto", "auto", upscale_model=model)
    # 128² in 32² tiles, the self-ensemble's two passes in one call of 4 tiles a batch: the
    # bar moved per batch of tiles, and no batch ran after the cancel.
    assert updates == [(4, 32), (8, 32), (12, 32)]
    assert model.calls == 3
