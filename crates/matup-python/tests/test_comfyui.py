"""The ComfyUI nodes' meanings that need neither torch nor ComfyUI: MASK as 1 − alpha, and files
kept within ComfyUI's folders (comfyui/masks.py, comfyui/folders.py)."""

import importlib.util
import os
import sys
import types
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]


def module(name):
    """comfyui/NAME.py alone: the package's __init__ loads the nodes, which need torch."""
    spec = importlib.util.spec_from_file_location(f"comfyui_{name}", REPO / "comfyui" / f"{name}.py")
    loaded = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(loaded)
    return loaded


masks = module("masks")
folders = module("folders")


def test_loadimage_masks_come_back_as_the_files_alpha_through_joinimagewithalpha():
    # LoadImage of an RGBA file: mask = 1 − alpha. matup's alpha must be the file's, and the
    # mask it returns, through JoinImageWithAlpha (alpha = 1 − mask), the file's again.
    alpha = np.linspace(0.0, 1.0, 32 * 32, dtype=np.float32).reshape(32, 32)
    codes = masks.alpha_codes(1.0 - alpha, (32, 32))
    assert codes.dtype == np.uint16
    assert np.abs(codes / 65535.0 - alpha).max() < 1 / 65535
    joined = 1.0 - masks.mask_of(codes, (32, 32))
    assert np.abs(joined - alpha).max() < 1 / 65535
    # 8-bit codes read as 8-bit.
    assert masks.mask_of(np.array([[255, 0]], np.uint8), (1, 2)).tolist() == [[0.0, 1.0]]


def test_a_missing_alpha_means_opaque_in_and_out():
    # LoadImage's stand-in for an image without alpha: 64×64 zeros, whatever the image's size.
    assert masks.alpha_codes(np.zeros((64, 64), np.float32), (128, 128)) is None
    out = masks.mask_of(None, (512, 512))
    assert out.shape == (512, 512) and not out.any()
    # A real mask of another size than the image is refused with both sizes.
    with pytest.raises(ValueError, match="64×64.*128×96"):
        masks.alpha_codes(np.full((64, 64), 0.5, np.float32), (96, 128))


def test_paths_outside_comfyuis_folder_are_refused(tmp_path):
    output = tmp_path / "output"
    output.mkdir()
    assert folders.inside(str(output), "matup/run1", "Save material") == str(output / "matup" / "run1")
    assert folders.inside(str(output), str(output / "x"), "Save material") == str(output / "x")
    for outside in ["../elsewhere", "/etc", str(tmp_path / "outputs-not")]:
        with pytest.raises(ValueError, match="Save material stays within ComfyUI's folder"):
            folders.inside(str(output), outside, "Save material")
    # A link inside that points outside is outside.
    os.symlink(tmp_path, output / "link")
    with pytest.raises(ValueError, match="outside it"):
        folders.inside(str(output), "link/x", "Save material")


def test_a_changed_file_changes_the_folders_stamp(tmp_path):
    (tmp_path / "baseColor.png").write_bytes(b"a")
    before = folders.stamp(str(tmp_path))
    assert folders.stamp(str(tmp_path)) == before
    (tmp_path / "baseColor.png").write_bytes(b"ab")
    assert folders.stamp(str(tmp_path)) != before


def load_pack(name, monkeypatch):
    """The repository root loaded as ComfyUI's ``load_custom_node`` loads a cloned pack: a module
    of ``name`` from its ``__init__.py``, in ``sys.modules`` before it runs."""
    if importlib.util.find_spec("torch") is None:
        # The nodes use torch only when they run (their annotations are strings).
        monkeypatch.setitem(sys.modules, "torch", types.ModuleType("torch"))
    spec = importlib.util.spec_from_file_location(name, REPO / "__init__.py")
    pack = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, pack)
    spec.loader.exec_module(pack)
    return pack


def test_the_repository_cloned_into_custom_nodes_registers_the_nodes(monkeypatch):
    pytest.importorskip("matup")
    # Today's ComfyUI names the module after the folder's full path, dots replaced.
    pack = load_pack(str(REPO / "custom_nodes" / "matup-nodes").replace(".", "_x_"), monkeypatch)
    assert set(pack.NODE_CLASS_MAPPINGS) == {
        "MatupUpscaleMaterial",
        "MatupLoadMaterial",
        "MatupUpscaleLoadedMaterial",
        "MatupSaveMaterial",
    }
    assert set(pack.NODE_DISPLAY_NAME_MAPPINGS) == set(pack.NODE_CLASS_MAPPINGS)
    for node in pack.NODE_CLASS_MAPPINGS.values():
        assert callable(getattr(node, node.FUNCTION))
        assert "required" in node.INPUT_TYPES()
    # The nodes import the package itself, not the pack.
    assert hasattr(sys.modules["matup"], "upscale_folder")


def test_a_pack_loaded_as_matup_says_how_to_clone_it(monkeypatch):
    # An older ComfyUI named the module after the folder alone: `custom_nodes/matup` would be
    # `matup`, the package's own name.
    with pytest.raises(ImportError, match="clone the repository as custom_nodes/matup-nodes"):
        load_pack("matup", monkeypatch)
