"""Every format and variant matup writes, opened by independent readers (Pillow, tifffile, the
OpenEXR package and Debian's ImageMagick), must decode to the values matup meant, within the
format's own loss."""

import os
import shutil
import subprocess

import numpy as np
import pytest

import matup

PIL = pytest.importorskip("PIL.Image", reason="pip install pillow tifffile OpenEXR")
tifffile = pytest.importorskip("tifffile", reason="pip install pillow tifffile OpenEXR")
OpenEXR = pytest.importorskip("OpenEXR", reason="pip install pillow tifffile OpenEXR")

SIDE = 40


def picture(channels, dtype, side=SIDE):
    """Smooth values across the range, each channel its own, as a map's."""
    y, x = np.mgrid[0:side, 0:side].astype(np.float32)
    planes = [0.5 + 0.45 * np.sin(0.21 * x + 0.13 * y + 1.7 * c) for c in range(channels)]
    unit = np.stack(planes, axis=2)
    if dtype == np.float32:
        return unit.astype(np.float32)
    top = np.iinfo(dtype).max
    return np.round(unit * top).astype(dtype)


def as_unit(array):
    array = np.asarray(array)
    if array.dtype == np.uint8:
        return array.astype(np.float64) / 255.0
    if array.dtype == np.uint16:
        return array.astype(np.float64) / 65535.0
    return array.astype(np.float64)


def pillow(path):
    with PIL.open(path) as image:
        image.load()
        if image.mode in ("I;16", "I;16B", "I"):
            return np.asarray(image).astype(np.uint16)
        return np.asarray(image)


def imagemagick_command():
    """ImageMagick's command (7's `magick` or 6's `convert`, as Debian ships it), or None. A
    missing one fails where MATUP_REQUIRE_IMAGEMAGICK is set (CI installs it)."""
    for name in ("magick", "/usr/bin/convert", "convert"):
        command = shutil.which(name)
        if command:
            version = subprocess.run([command, "-version"], capture_output=True, text=True)
            if version.stdout.startswith("Version: ImageMagick"):
                return command
    assert not os.environ.get("MATUP_REQUIRE_IMAGEMAGICK"), "ImageMagick is not installed"
    return None


IMAGEMAGICK = imagemagick_command()


def imagemagick(path):
    """The file's first image as ImageMagick decodes it, through a 16-bit PAM (grey, grey +
    alpha, RGB or RGBA as ImageMagick reads the file)."""
    if IMAGEMAGICK is None:
        pytest.skip("ImageMagick is not installed (apt-get install imagemagick)")
    pam = subprocess.run(
        [IMAGEMAGICK, f"{path}[0]", "-depth", "16", "pam:-"], capture_output=True, check=True
    ).stdout
    header, _, data = pam.partition(b"ENDHDR\n")
    fields = dict(line.split(b" ", 1) for line in header.splitlines()[1:] if b" " in line)
    width, height, depth = (int(fields[key]) for key in (b"WIDTH", b"HEIGHT", b"DEPTH"))
    samples = np.frombuffer(data, ">u2", width * height * depth).astype(np.uint16)
    return samples.reshape(height, width, depth)


def exr(path):
    with OpenEXR.File(str(path)) as file:
        channels = file.channels()
        if "RGBA" in channels or "RGB" in channels:
            return np.asarray(channels.get("RGBA", channels.get("RGB")).pixels, np.float32)
        planes = [np.asarray(channels[name].pixels, np.float32) for name in ("Y", "A") if name in channels]
        return np.stack(planes, axis=2)


def channels_meant(read, channels):
    """The read image's channels that hold what was written: grey written as RGB (WebP) or
    grey + alpha as RGBA (TIFF, BMP, WebP) keeps the grey in R and the alpha last."""
    if read.ndim == 2:
        read = read[:, :, None]
    if read.shape[2] == channels:
        return read
    if channels == 1:
        return read[:, :, :1]
    if channels == 2:
        return read[:, :, [0, read.shape[2] - 1]]
    if channels == 3 and read.shape[2] == 4:
        return read[:, :, :3]
    raise AssertionError(f"{read.shape[2]} channels read for {channels} written")


# (format, extension, dtype written, readers, largest and mean error allowed in [0, 1]).
EXACT8 = (0.5 / 255, 0.5 / 255)
FORMATS = [
    ("png", "png", np.uint8, ("pillow", "imagemagick"), EXACT8),
    ("png16", "png", np.uint16, ("pillow", "imagemagick"), (0.5 / 65535, 0.5 / 65535)),
    ("jpg", "jpg", np.uint8, ("pillow", "imagemagick"), (0.1, 0.01)),
    ("tga", "tga", np.uint8, ("pillow", "imagemagick"), EXACT8),
    ("tga-rle", "tga", np.uint8, ("pillow", "imagemagick"), EXACT8),
    ("bmp", "bmp", np.uint8, ("pillow", "imagemagick"), EXACT8),
    ("webp-lossless", "webp", np.uint8, ("pillow", "imagemagick"), EXACT8),
    ("webp", "webp", np.uint8, ("pillow", "imagemagick"), (0.2, 0.02)),
    ("tiff", "tif", np.uint8, ("pillow", "tifffile", "imagemagick"), EXACT8),
    ("tiff16", "tif", np.uint16, ("tifffile", "imagemagick"), (0.5 / 65535, 0.5 / 65535)),
    ("tiff-float", "tif", np.float32, ("tifffile", "imagemagick"), (0.0, 0.0)),
    ("exr-float", "exr", np.float32, ("openexr", "imagemagick"), (0.0, 0.0)),
    ("exr-half", "exr", np.float32, ("openexr", "imagemagick"), (1e-3, 1e-3)),
]
# ImageMagick decodes into 16-bit samples (Debian's Q16 build): floats come within one step,
# and EXR within half precision (it reads EXR through OpenEXR's half RGBA interface).
IMAGEMAGICK_FLOAT = {"tif": (1 / 65535, 1 / 65535), "exr": (1e-3, 1e-3)}


@pytest.mark.parametrize("channels", [1, 2, 3, 4])
@pytest.mark.parametrize("format, extension, dtype, readers, allowed", FORMATS, ids=[f[0] for f in FORMATS])
def test_every_written_format_opens_in_independent_readers(tmp_path, format, extension, dtype, readers, allowed, channels):
    array = picture(channels, dtype)
    path = tmp_path / f"map.{extension}"
    if format == "jpg" and channels in (2, 4):
        with pytest.raises(matup.FileError, match="JPEG holds no alpha"):
            matup.write_image(path, array, format)
        return
    matup.write_image(path, array, format)
    for reader in readers:
        read = {"pillow": pillow, "tifffile": tifffile.imread, "openexr": exr, "imagemagick": imagemagick}[reader](path)
        read = channels_meant(np.asarray(read), channels)
        assert read.shape == (SIDE, SIDE, channels), (reader, read.shape)
        error = np.abs(as_unit(read) - as_unit(array))
        # Pillow holds 16-bit grey only: it reads 16-bit colour and grey + alpha as 8 bits.
        within = (1 / 255, 1 / 255) if read.dtype == np.uint8 and dtype == np.uint16 else allowed
        if reader == "imagemagick" and dtype == np.float32:
            within = np.maximum(within, IMAGEMAGICK_FLOAT[extension])
        assert error.max() <= within[0] + 1e-9 and error.mean() <= within[1] + 1e-9, (
            reader,
            error.max(),
            error.mean(),
        )


def mip_levels(path):
    """The mip count of a DDS file's header, checked against the file's length: every level
    of the chain (blocks of 4×4 for BC formats) is there."""
    data = path.read_bytes()
    height, width, levels = (int.from_bytes(data[o : o + 4], "little") for o in (12, 16, 28))
    dx10 = data[84:88] == b"DX10"
    dxgi = int.from_bytes(data[128:132], "little") if dx10 else None
    block_bytes = {71: 8, 80: 8, 77: 16, 83: 16, 98: 16}.get(dxgi)  # BC1, BC4; BC3, BC5, BC7
    if block_bytes is None and not dx10:
        block_bytes = {b"DXT1": 8, b"DXT5": 16}.get(data[84:88])
    # Uncompressed: R8G8B8A8 (DX10), or the legacy header's bits per pixel.
    pixel_bytes = 4 if dx10 else int.from_bytes(data[88:92], "little") // 8
    size = 0
    for level in range(levels):
        w, h = max(width >> level, 1), max(height >> level, 1)
        size += ((w + 3) // 4) * ((h + 3) // 4) * block_bytes if block_bytes else w * h * pixel_bytes
    assert len(data) == 128 + (20 if dx10 else 0) + size, (path.name, len(data), levels)
    return levels


# (format, channels written, channels a reader compares: BC5 holds two).
DDS_FORMATS = [("dds-bc1", 3, 3), ("dds-bc3", 4, 4), ("dds-bc4", 1, 1), ("dds-bc5", 3, 2), ("dds-bc7", 4, 4), ("dds-rgba8", 4, 4)]


@pytest.mark.parametrize("format, channels, compared", DDS_FORMATS, ids=[f[0] for f in DDS_FORMATS])
def test_dds_opens_in_pillow_with_its_mips(tmp_path, format, channels, compared):
    array = picture(channels, np.uint8)
    path = tmp_path / "map.dds"
    matup.write_image(path, array, format)
    assert mip_levels(path) == 6  # 40, 20, 10, 5, 2, 1
    read = channels_meant(pillow(path), channels)[:, :, :compared]
    # Pillow decodes the blocks as matup does (within a level of rounding)...
    ours = matup.read_image(path)[:, :, :compared]  # DDS samples come as floats in [0, 1]
    assert np.abs(as_unit(read) - as_unit(ours)).max() <= 1 / 255 + 1e-6, format
    # ...and they hold the picture within the block format's own loss.
    error = np.abs(as_unit(read) - as_unit(array[:, :, :compared]))
    assert error.mean() < (0.5 / 255 if format == "dds-rgba8" else 0.03), (format, error.mean())


@pytest.mark.parametrize("compression", ["dxt1", "dxt5", "none"])
def test_legacy_dds_comes_back_legacy_and_opens_in_imagemagick(tmp_path, compression):
    """An old game's DDS (the DX9 header, DXT1/DXT5 or uncompressed, made here by ImageMagick)
    comes back with its header, which ImageMagick 6 reads; it reads no DX10 header, which
    matup writes where it chooses the format, as engines load."""
    if IMAGEMAGICK is None:
        pytest.skip("ImageMagick is not installed (apt-get install imagemagick)")
    source, folder = tmp_path / "source", tmp_path / "game"
    source.mkdir()
    folder.mkdir()
    for name, channels in (("rock_d", 3), ("rock_r", 1)):
        # A power of two: ImageMagick writes mips only then.
        matup.write_image(source / f"{name}.png", picture(channels, np.uint8, 32), "png")
        subprocess.run(
            [IMAGEMAGICK, str(source / f"{name}.png"), "-define", f"dds:compression={compression}",
             str(folder / f"{name}.dds")],
            check=True,
        )
    matup.upscale_folder(folder, tmp_path / "out", upsampler="bicubic", scale=2, progress=False)
    for name in ("rock_d", "rock_r"):
        path = tmp_path / "out" / f"{name}.dds"
        assert path.read_bytes()[84:88] != b"DX10", name
        # A full chain in (32² to 1²), a full chain out (64² to 1²).
        assert (mip_levels(folder / f"{name}.dds"), mip_levels(path)) == (6, 7), name
        ours = matup.read_image(path)
        theirs = channels_meant(imagemagick(path), ours.shape[2])
        assert theirs.shape == ours.shape, (name, theirs.shape, ours.shape)
        assert np.abs(as_unit(theirs) - as_unit(ours)).max() <= 1 / 255 + 1e-6, name


def test_the_samples_tga_run_opens_in_pillow(tmp_path):
    """`--format tga` on the shipped sample: Pillow refused its grey maps when RLE packets ran
    across scanlines."""
    from pathlib import Path

    sample = Path(__file__).resolve().parents[3] / "samples" / "victorian_wood"
    matup.upscale_folder(sample, tmp_path / "out", upsampler="bicubic", format="tga", progress=False)
    for path in sorted((tmp_path / "out").glob("*.tga")):
        ours = matup.read_image(path)
        theirs = channels_meant(pillow(path), ours.shape[2])
        assert np.array_equal(theirs, ours), path.name
