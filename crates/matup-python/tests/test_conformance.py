"""Every format and variant matup writes, opened by independent readers (Pillow, tifffile and
the OpenEXR package), must decode to the values matup meant, within the format's own loss."""

import numpy as np
import pytest

import matup

PIL = pytest.importorskip("PIL.Image", reason="pip install pillow tifffile OpenEXR")
tifffile = pytest.importorskip("tifffile", reason="pip install pillow tifffile OpenEXR")
OpenEXR = pytest.importorskip("OpenEXR", reason="pip install pillow tifffile OpenEXR")

SIDE = 40


def picture(channels, dtype):
    """Smooth values across the range, each channel its own, as a map's."""
    y, x = np.mgrid[0:SIDE, 0:SIDE].astype(np.float32)
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
    ("png", "png", np.uint8, ("pillow",), EXACT8),
    ("png16", "png", np.uint16, ("pillow",), (0.5 / 65535, 0.5 / 65535)),
    ("jpg", "jpg", np.uint8, ("pillow",), (0.1, 0.01)),
    ("tga", "tga", np.uint8, ("pillow",), EXACT8),
    ("tga-rle", "tga", np.uint8, ("pillow",), EXACT8),
    ("bmp", "bmp", np.uint8, ("pillow",), EXACT8),
    ("webp-lossless", "webp", np.uint8, ("pillow",), EXACT8),
    ("webp", "webp", np.uint8, ("pillow",), (0.2, 0.02)),
    ("tiff", "tif", np.uint8, ("pillow", "tifffile"), EXACT8),
    ("tiff16", "tif", np.uint16, ("tifffile",), (0.5 / 65535, 0.5 / 65535)),
    ("tiff-float", "tif", np.float32, ("tifffile",), (0.0, 0.0)),
    ("exr-float", "exr", np.float32, ("openexr",), (0.0, 0.0)),
    ("exr-half", "exr", np.float32, ("openexr",), (1e-3, 1e-3)),
]


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
        read = {"pillow": pillow, "tifffile": tifffile.imread, "openexr": exr}[reader](path)
        read = channels_meant(np.asarray(read), channels)
        assert read.shape == (SIDE, SIDE, channels), (reader, read.shape)
        error = np.abs(as_unit(read) - as_unit(array))
        # Pillow holds 16-bit grey only: it reads 16-bit colour and grey + alpha as 8 bits.
        within = (1 / 255, 1 / 255) if read.dtype == np.uint8 and dtype == np.uint16 else allowed
        assert error.max() <= within[0] + 1e-9 and error.mean() <= within[1] + 1e-9, (
            reader,
            error.max(),
            error.mean(),
        )


@pytest.mark.parametrize("format", ["dds-bc1", "dds-bc3", "dds-bc7", "dds-rgba8"])
def test_dds_opens_in_pillow(tmp_path, format):
    array = picture(4 if format != "dds-bc1" else 3, np.uint8)
    path = tmp_path / "map.dds"
    matup.write_image(path, array, format)
    read = channels_meant(pillow(path), array.shape[2])
    # Pillow decodes the blocks as matup does (within a level of rounding)...
    ours = matup.read_image(path)  # DDS samples come as floats in [0, 1]
    assert np.abs(as_unit(read) - as_unit(ours)).max() <= 1 / 255 + 1e-6, format
    # ...and they hold the picture within the block format's own loss.
    error = np.abs(as_unit(read) - as_unit(array))
    assert error.mean() < (0.5 / 255 if format == "dds-rgba8" else 0.03), (format, error.mean())


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
