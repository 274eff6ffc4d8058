"""The Python package against the command line, on the shipped sample; NumPy only (the
PyTorch callable and the ComfyUI nodes are tested by tests/test_torch.py)."""

import json
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
import _thread
from pathlib import Path

import numpy as np
import pytest

import matup

REPO = Path(__file__).resolve().parents[3]
SAMPLE = REPO / "samples" / "victorian_wood"
ROLES = {
    "base_color": "baseColor.png",
    "normal": "normal.png",
    "roughness": "roughness.png",
    "metallic": "metallic.png",
    "height": "height.png",
}


def cli() -> Path:
    """The `matup` binary the workspace's tests built (or $MATUP_CLI)."""
    for candidate in (os.environ.get("MATUP_CLI"), REPO / "target/debug/matup", REPO / "target/release/matup"):
        if candidate and Path(candidate).is_file():
            return Path(candidate)
    raise AssertionError("no matup binary: run `cargo build -p matup-cli` or set MATUP_CLI")


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "out"
    subprocess.run([cli(), "upscale", SAMPLE, "-o", out, "--quiet"], check=True)
    return out


def sample_maps():
    maps = {role: matup.read_image(SAMPLE / name) for role, name in ROLES.items()}
    # Grey files come back H×W×1; give them as H×W, as a NumPy user would.
    return {k: (v[:, :, 0] if v.shape[2] == 1 else v) for k, v in maps.items()}


def map_files(folder: Path):
    return sorted(p.name for p in folder.iterdir() if p.suffix == ".png" and p.name != "preview.png")


def test_a_folder_comes_back_as_the_command_line_writes_it(tmp_path, cli_run):
    report = matup.upscale_folder(SAMPLE, tmp_path / "out", progress=False)
    assert report["output_size"] == [512, 512]
    assert report["upsampler_used"] == "onnx:span_x4_materials"
    assert map_files(tmp_path / "out") == map_files(cli_run)
    for name in map_files(cli_run):
        assert (tmp_path / "out" / name).read_bytes() == (cli_run / name).read_bytes(), name
    cli_report = json.loads((cli_run / "run.json").read_text())
    for key in ("config", "route", "tileable", "levels", "upsampler_used"):
        assert report[key] == cli_report[key], key


def test_arrays_come_back_as_the_command_line_writes_their_files(cli_run):
    maps = sample_maps()
    big = matup.upscale(maps, scale=4, progress=False)
    assert sorted(big) == sorted(maps)
    for role, name in ROLES.items():
        assert big[role].dtype == maps[role].dtype == np.uint8
        assert big[role].ndim == maps[role].ndim
        want = matup.read_image(cli_run / name)
        got = big[role] if big[role].ndim == 3 else big[role][:, :, None]
        assert got.shape == want.shape == (512, 512, want.shape[2])
        assert np.array_equal(got, want), role


def test_arrays_reach_matup_in_memory_with_no_file_written(tmp_path, monkeypatch):
    # Python's temporary folder does not exist and the working folder is empty: a run that
    # wrote its arrays to files would fail or leave them.
    monkeypatch.setattr(tempfile, "tempdir", os.fspath(tmp_path / "no-such-folder"))
    monkeypatch.chdir(tmp_path)
    big = matup.upscale(sample_maps(), upsampler="lanczos3", progress=False)
    assert big["base_color"].shape == (512, 512, 3)
    assert sorted(os.listdir(tmp_path)) == []


def test_a_material_comes_back_with_the_command_lines_files(cli_run):
    big = matup.upscale(matup.read_material(SAMPLE), progress=False)
    assert sorted(big.files) == sorted(ROLES.values())
    for name in ROLES.values():
        assert np.array_equal(big.files[name], matup.read_image(cli_run / name)), name
        assert big.formats[name] == "png"
    # Its maps are those files as matup reads them.
    assert np.allclose(big.maps["roughness"][:, :, 0], big.files["roughness.png"][:, :, 0] / 255.0)


def bicubic(batch: np.ndarray, scale: int = 4, a: float = -0.5) -> np.ndarray:
    """Keys bicubic ×scale of an N×H×W×3 batch, edges clamped: matup's `bicubic` kernel."""

    def weights(t):
        t = np.abs(t)
        return np.where(
            t <= 1,
            (a + 2) * t**3 - (a + 3) * t**2 + 1,
            np.where(t < 2, a * t**3 - 5 * a * t**2 + 8 * a * t - 4 * a, 0.0),
        )

    def along(x, axis):
        n = x.shape[axis]
        centre = (np.arange(n * scale) + 0.5) / scale - 0.5
        first = np.floor(centre).astype(int) - 1
        out = 0
        for k in range(4):
            index = first + k
            w = weights(centre - index).astype(np.float32)
            taken = np.take(x, np.clip(index, 0, n - 1), axis=axis)
            shape = [1] * x.ndim
            shape[axis] = -1
            out = out + taken * w.reshape(shape)
        return out

    return along(along(batch, 1), 2).astype(np.float32)


def test_a_numpy_callable_doing_bicubic_gives_the_bicubic_plugins_maps():
    maps = sample_maps()
    built_in = matup.upscale(maps, upsampler="bicubic", progress=False)
    calls = []

    def network(batch):
        calls.append(batch.shape)
        assert batch.dtype == np.float32 and batch.shape[3] == 3
        assert 0.0 <= batch.min() and batch.max() <= 1.0
        return bicubic(batch)

    called = matup.upscale(maps, upsampler=network, progress=False)
    assert calls, "the callable was not called"
    for role in ROLES:
        diff = np.abs(called[role].astype(int) - built_in[role].astype(int))
        assert diff.max() <= 1, (role, diff.max())


def test_the_output_box_filters_back_to_the_input():
    maps = sample_maps()
    big = matup.upscale(maps, upsampler=matup.Network(bicubic, scale=4, tile=48), progress=False)
    for role in ("roughness", "base_color"):
        lr = maps[role].astype(float)
        hr = big[role].astype(float)
        back = hr.reshape(lr.shape[0], 4, lr.shape[1], 4, *lr.shape[2:]).mean(axis=(1, 3))
        # Within the 8-bit files' rounding (base colour is averaged as light, not codes).
        assert np.abs(back - lr).mean() < 0.6, role


def test_settings_are_the_toml_keys_by_name_or_section():
    text = matup.settings(self_ensemble=8, window=9, lights={"count": 32}, tileable=True)
    assert "self_ensemble = 8" in text and "window = 9" in text and "count = 32" in text
    assert "tileable = true" in text
    with pytest.raises(ValueError, match="unknown field `self_ensembel`"):
        matup.settings(self_ensembel=8)
    with pytest.raises(matup.InvalidInput, match="symmetries of the square, not 3"):
        matup.settings(self_ensemble=3)


def test_list_names_the_plugins_and_the_callable():
    plugins = matup.list()
    names = {p["name"] for p in plugins["upsamplers"]}
    assert {"bicubic", "lanczos3", "onnx", "callable"} <= names
    assert "ggx" in {p["name"] for p in plugins["shading_models"]}
    assert "span_x4_materials" in {m["name"] for m in plugins["models"]}


def test_float64_and_float16_arrays_come_back_as_float32_ones_do_in_their_own_dtype():
    # NumPy's default float64, and half floats, are worked on as float32: the same maps.
    maps = {role: a.astype(np.float32) / 255.0 for role, a in sample_maps().items()}
    want = matup.upscale(maps, progress=False)
    for dtype in (np.float64, np.float16):
        given = {role: a.astype(dtype) for role, a in maps.items()}
        if dtype == np.float16:
            # What float16 rounds is the input; compare with float32 maps of the same values.
            want_here = matup.upscale(
                {role: a.astype(np.float32) for role, a in given.items()}, progress=False
            )
        else:
            want_here = want
        got = matup.upscale(given, progress=False)
        for role in maps:
            assert got[role].dtype == dtype, role
            assert np.array_equal(got[role], want_here[role].astype(dtype)), role


@pytest.mark.parametrize(
    "change, error, message",
    [
        (lambda m: m.update(roughness=m["roughness"][:64, :64]), ValueError, "one size"),
        (lambda m: m.update(roughness=m["roughness"].astype(np.int32)), ValueError, "int32"),
        (lambda m: m.update(height=np.full(m["height"].shape, 1e300)), ValueError, "float32's range"),
        (
            lambda m: m.update(height=np.full(m["height"].shape, np.nan, np.float32)),
            ValueError,
            "NaN",
        ),
        (lambda m: m.update(normal=m["normal"][:, :, None, :]), ValueError, "shape"),
        (lambda m: m.clear(), ValueError, "non-empty"),
    ],
)
def test_bad_arrays_are_refused_by_name(change, error, message):
    maps = sample_maps()
    change(maps)
    with pytest.raises(error, match=message):
        matup.upscale(maps, progress=False)


def test_a_callable_returning_the_wrong_shape_is_refused():
    half = matup.Network(lambda x: x[:, ::2, ::2], scale=4)
    with pytest.raises(matup.InvalidInput, match="returned"):
        matup.upscale(sample_maps(), upsampler=half, progress=False)
    with pytest.raises(matup.InvalidInput, match="not a whole scale"):
        matup.Network(lambda x: np.zeros((x.shape[0], 40, 40, 3), np.float32))


class NetworkFailed(RuntimeError):
    pass


def test_an_exception_in_the_callable_reaches_the_caller_with_its_traceback(tmp_path):
    def network(batch):
        if batch.shape[1] > 32:  # the probe passes; the run's first call raises
            raise NetworkFailed("out of memory, say")
        return bicubic(batch)

    with pytest.raises(NetworkFailed, match="out of memory") as caught:
        matup.upscale_folder(SAMPLE, tmp_path / "out", upsampler=network, progress=False)
    assert any(entry.name == "network" for entry in caught.traceback)
    assert not [p for p in (tmp_path / "out").glob("*.png")], "a partial output was left"


def test_a_missing_folder_is_an_os_error_naming_it(tmp_path):
    with pytest.raises(OSError, match="no-such-folder"):
        matup.upscale_folder(tmp_path / "no-such-folder", tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_the_gil_is_released_while_matup_works(tmp_path):
    ticks = []
    done = threading.Event()

    def count():
        while not done.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.01)

    thread = threading.Thread(target=count)
    thread.start()
    start = time.perf_counter()
    try:
        matup.upscale_folder(SAMPLE, tmp_path / "out", upsampler="lanczos3", progress=False)
    finally:
        done.set()
        thread.join()
    elapsed = time.perf_counter() - start
    during = [t for t in ticks if start < t < start + elapsed]
    # The other thread ticks every 10 ms: it ran through most of the upscale.
    assert len(during) >= 0.5 * elapsed / 0.01, (len(during), elapsed)


def test_ctrl_c_stops_a_run_and_leaves_no_partial_output(tmp_path):
    def slow(batch):
        time.sleep(0.2)
        return bicubic(batch)

    network = matup.Network(slow, scale=4, tile=32, batch=1)
    # A shell's background job starts with SIGINT ignored, and interrupt_main then does nothing:
    # Ctrl-C's own handler is installed for the test, as in a terminal.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(1.0, _thread.interrupt_main)
    timer.start()
    start = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            matup.upscale_folder(SAMPLE, tmp_path / "out", upsampler=network, progress=False)
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    # It stopped at the next call, not at the end of the run (16 tiles × passes × maps).
    assert time.perf_counter() - start < 5.0
    assert not [p for p in (tmp_path / "out").glob("*.png")], "a partial output was left"


def test_progress_reaches_a_callback():
    events = []
    matup.upscale(sample_maps(), upsampler="lanczos3", progress=lambda *e: events.append(e))
    kinds = {e[0] for e in events}
    assert {"stage", "note"} <= kinds
    assert any("tileable" in e[1] for e in events if e[0] == "note")


class Cancelled(Exception):
    """What a host application's cancel raises from the progress callback."""


def test_a_cancel_raised_at_a_tile_stops_the_run_before_the_next_tile():
    calls, tiles = [], []

    def network(batch):
        calls.append(len(batch))
        return bicubic(batch)

    def progress(kind, text, count, number):
        if kind == "tiles":
            tiles.append((count, number))
            if len(tiles) == 3:
                raise Cancelled("cancelled at the third tile")

    net = matup.Network(network, scale=4, tile=32, batch=1)
    with pytest.raises(Cancelled, match="third tile"):
        matup.upscale(sample_maps(), upsampler=net, progress=progress)
    # A 128² map in 32² tiles, its two self-ensemble passes in one call: 32 tiles, each
    # reported as it finishes; none ran after the cancel.
    assert tiles == [(1, 32), (2, 32), (3, 32)]
    assert len(calls) == 3


def test_a_material_reads_and_writes_back_with_its_layout(tmp_path):
    material = matup.read_material(SAMPLE)
    assert material.size == (128, 128)
    assert material.maps["base_color"].shape == (128, 128, 3)
    assert material.maps["base_color"].dtype == np.float32
    assert sorted(material.files) == sorted(ROLES.values())
    assert any("baseColor.png" in s for s in material.sources)
    written = matup.write_material(material, tmp_path / "copy")
    assert len(written) == len(ROLES)
    for name in ROLES.values():
        assert np.array_equal(matup.read_image(tmp_path / "copy" / name), matup.read_image(SAMPLE / name))
    with pytest.raises(OSError, match="material's own"):
        matup.write_material(material, SAMPLE)
    big = matup.upscale(material, upsampler="lanczos3", progress=False)
    assert isinstance(big, matup.Material) and big.size == (512, 512)
    assert sorted(big.files) == sorted(ROLES.values())


def test_evaluate_and_render_measure_as_the_command_line(tmp_path):
    shutil.copytree(SAMPLE, tmp_path / "same")
    same = matup.evaluate(SAMPLE, tmp_path / "same", lights=4)
    assert same["render_psnr"] > 90
    renders = matup.render(SAMPLE, lights=3)
    assert renders.shape == (3, 128, 128, 3) and renders.dtype == np.float32
    assert np.isfinite(renders).all() and renders.max() > 0
