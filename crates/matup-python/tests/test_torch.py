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
