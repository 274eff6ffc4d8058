//! Maps held on a candle device (a GPU's memory, or the CPU in tests) as `[channels, height,
//! width]` tensors, and the operations the default path runs on them there: upload and
//! download, separable resampling as two matrix products with [`crate::resample`]'s own
//! weights, and the square's symmetries. What is computed on the host and on a device is then
//! the same weights, summed in another order.

use candle_core::{DType, Device, Tensor};

use crate::io::stream::Samples;
use crate::layout::Stored;
use crate::map::{Dihedral, Map};
use crate::material::SampleDepth;
use crate::resample::{
    neighbourhood_ranges, shrink_matrix, upsample_matrix, Border, Kernel, Shrink,
};

/// Bytes of memory free on `device` now, as its driver reports them: a GPU's; `None` for the
/// CPU (the host's memory limit governs it).
pub fn free_memory(device: &Device) -> candle_core::Result<Option<u64>> {
    match device {
        #[cfg(feature = "cuda")]
        Device::Cuda(gpu) => {
            let (free, _total) =
                (gpu.cuda_stream().context().mem_get_info()).map_err(candle_core::Error::wrap)?;
            Ok(Some(free as u64))
        }
        _ => Ok(None),
    }
}

/// `map` on `device`, `[channels, height, width]`.
pub fn upload(map: &Map, device: &Device) -> candle_core::Result<Tensor> {
    Tensor::from_slice(
        map.data(),
        (map.channels(), map.height(), map.width()),
        device,
    )
}

/// A `[channels, height, width]` tensor back on the host.
pub fn download(t: &Tensor) -> candle_core::Result<Map> {
    let (c, h, w) = t.dims3()?;
    let data = t.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()?;
    Ok(Map::from_planar(w, h, c, data))
}

/// A separable resampling of `[channels, h, w]` tensors to `[channels, oh, ow]`: the rows'
/// `oh × h` matrix and the columns' `ow × w` one (stored transposed), on the device.
pub struct Separable {
    rows: Tensor,
    columns_t: Tensor,
}

impl Separable {
    /// [`crate::resample::upsample`] of `[w, h]` images by `scale` with `kernel`.
    pub fn upsample(
        [w, h]: [usize; 2],
        scale: usize,
        kernel: Kernel,
        border: Border,
        device: &Device,
    ) -> candle_core::Result<Separable> {
        Separable::new(
            upsample_matrix(h, scale, kernel, border),
            upsample_matrix(w, scale, kernel, border),
            [w, h],
            [w * scale, h * scale],
            device,
        )
    }

    /// [`crate::resample::shrink`] of `from` images to `to` as `how` says (a box filter for
    /// a whole ratio by [`Shrink::Area`]).
    pub fn shrink(
        from: [usize; 2],
        to: [usize; 2],
        how: Shrink,
        border: Border,
        device: &Device,
    ) -> candle_core::Result<Separable> {
        Separable::new(
            shrink_matrix(from[1], to[1], how, border),
            shrink_matrix(from[0], to[0], how, border),
            from,
            to,
            device,
        )
    }

    fn new(
        rows: Vec<f32>,
        columns: Vec<f32>,
        [w, h]: [usize; 2],
        [ow, oh]: [usize; 2],
        device: &Device,
    ) -> candle_core::Result<Separable> {
        Ok(Separable {
            rows: Tensor::from_vec(rows, (oh, h), device)?,
            columns_t: Tensor::from_vec(columns, (ow, w), device)?
                .t()?
                .contiguous()?,
        })
    }

    /// `t`, `[channels, h, w]`, resampled: the columns as one product over every row of every
    /// channel, then the rows as one product over every column (no matrix copied per channel).
    pub fn apply(&self, t: &Tensor) -> candle_core::Result<Tensor> {
        let (c, h, w) = t.dims3()?;
        let (oh, ow) = (self.rows.dim(0)?, self.columns_t.dim(1)?);
        let across = t
            .contiguous()?
            .reshape((c * h, w))?
            .matmul(&self.columns_t)?;
        let by_rows = across
            .reshape((c, h, ow))?
            .transpose(0, 1)?
            .contiguous()?
            .reshape((h, c * ow))?;
        self.rows
            .matmul(&by_rows)?
            .reshape((oh, c, ow))?
            .transpose(0, 1)?
            .contiguous()
    }
}

/// `t`, `[channels, h, w]`, as [`Map::transformed`] moves a map's texels by `d`: flipped, then
/// transposed.
pub fn turned(t: &Tensor, d: Dihedral) -> candle_core::Result<Tensor> {
    let mut flips = Vec::new();
    if d.flip_y {
        flips.push(1);
    }
    if d.flip_x {
        flips.push(2);
    }
    let flipped = if flips.is_empty() {
        t.clone()
    } else {
        t.flip(&flips)?
    };
    if d.transpose {
        flipped.transpose(1, 2)?.contiguous()
    } else {
        Ok(flipped)
    }
}

/// Each texel of `t`, `[channels, h, w]`, repeated `scale × scale`: the LR texel under each
/// output texel.
pub fn repeated(t: &Tensor, scale: usize) -> candle_core::Result<Tensor> {
    let (c, h, w) = t.dims3()?;
    t.unsqueeze(3)?
        .unsqueeze(2)?
        .broadcast_as((c, h, scale, w, scale))?
        .contiguous()?
        .reshape((c, h * scale, w * scale))
}

/// The least and greatest of each of `values`' `N` components over each texel's 3×3
/// neighbourhood ([`crate::resample::neighbourhood_ranges`], computed on the host: `values`
/// are an input's, small), on `device` at `scale` times their size: `[2·N, h·scale,
/// w·scale]`, each component's least, then its greatest.
pub fn neighbourhood_bounds<const N: usize>(
    values: &[[f32; N]],
    width: usize,
    scale: usize,
    border: Border,
    device: &Device,
) -> candle_core::Result<Tensor> {
    let ranges = neighbourhood_ranges(values, width, border);
    let height = values.len() / width.max(1);
    let bounds = Map::from_fn(width, height, 2 * N, |k, y, x| {
        ranges[y * width + x][k / 2][k % 2]
    });
    repeated(&upload(&bounds, device)?, scale)
}

/// The sums of `t`'s `scale × scale` blocks, `[channels, h / scale, w / scale]`.
pub fn block_sums(t: &Tensor, scale: usize) -> candle_core::Result<Tensor> {
    let (c, h, w) = t.dims3()?;
    t.contiguous()?
        .reshape((c, h / scale, scale, w / scale, scale))?
        .sum(4)?
        .sum(2)
}

/// The samples a file of `depth` stores for the values `t` of component `component` (any
/// shape, row by row), made on `t`'s device as the host's writer makes them: encoded as
/// `stored` says, then, in integer files, scaled, clamped and rounded. Only the file's
/// samples cross back.
pub fn stored_samples(
    t: &Tensor,
    stored: Stored,
    component: usize,
    depth: SampleDepth,
) -> candle_core::Result<Samples> {
    let values = stored.encode_tensor(component, t)?.flatten_all()?;
    let levels = |top: f64| values.clamp(0f32, 1f32)?.affine(top, 0.0)?.round();
    Ok(match depth {
        SampleDepth::U8 => Samples::U8(levels(255.0)?.to_dtype(DType::U8)?.to_vec1()?),
        // Candle has no 16-bit integer type: the levels cross back as 32-bit ones.
        SampleDepth::U16 => Samples::U16(
            (levels(65535.0)?
                .to_dtype(DType::U32)?
                .to_vec1::<u32>()?
                .into_iter())
            .map(|v| v as u16)
            .collect(),
        ),
        SampleDepth::F32 => Samples::F32(values.to_dtype(DType::F32)?.to_vec1()?),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::resample::{area_resize, box_downsample, shrink, upsample};

    fn varied(w: usize, h: usize, channels: usize) -> Map {
        Map::from_fn(w, h, channels, |c, y, x| {
            ((x * 7 + y * 13 + c * 5) % 17) as f32 / 16.0
        })
    }

    fn worst(a: &Map, b: &Map) -> f32 {
        assert_eq!(
            (a.width(), a.height(), a.channels()),
            (b.width(), b.height(), b.channels())
        );
        (a.data().iter().zip(b.data())).fold(0.0, |m, (x, y)| m.max((x - y).abs()))
    }

    #[test]
    fn resampling_on_a_device_is_the_hosts() {
        let device = Device::Cpu;
        let map = varied(9, 6, 2);
        let t = upload(&map, &device).unwrap();
        for border in [Border::Wrap, Border::Mirror, Border::Clamp] {
            for kernel in [Kernel::Bilinear, Kernel::Lanczos3] {
                for scale in [2, 3, 4] {
                    let on = Separable::upsample([9, 6], scale, kernel, border, &device).unwrap();
                    let got = download(&on.apply(&t).unwrap()).unwrap();
                    let want = upsample(&map, scale, kernel, border);
                    let off = worst(&got, &want);
                    assert!(off < 1e-6, "{kernel:?} {border} ×{scale}: {off}");
                }
            }
            let lanczos = Shrink::Kernel(Kernel::Lanczos3);
            for (to, how) in [
                ([3, 2], Shrink::Area),
                ([6, 4], Shrink::Area),
                ([6, 4], lanczos),
            ] {
                let on = Separable::shrink([9, 6], to, how, border, &device).unwrap();
                let got = download(&on.apply(&t).unwrap()).unwrap();
                let off = worst(&got, &shrink(&map, to[0], to[1], how, border));
                assert!(off < 1e-6, "{how:?} to {to:?}: {off}");
            }
        }
        let boxed = download(&block_sums(&t, 3).unwrap())
            .unwrap()
            .map_values(|v| v / 9.0);
        assert!(worst(&boxed, &box_downsample(&map, 3)) < 1e-6);
        assert!(worst(&boxed, &area_resize(&map, 3, 2)) < 1e-6);
    }

    #[test]
    fn a_devices_samples_are_the_host_writers() {
        use crate::color::to_u8;
        use crate::material::NormalConvention;
        // Past both ends, and on the halves where rounding decides.
        let values: Vec<f32> = (0..=600).map(|i| i as f32 / 500.0 - 0.1).collect();
        let t = Tensor::new(values.as_slice(), &Device::Cpu).unwrap();
        for stored in [
            Stored::Linear,
            Stored::Srgb,
            Stored::Normal(NormalConvention::OpenGl),
            Stored::Inverted,
        ] {
            let encoded: Vec<f32> = values.iter().map(|&v| stored.encode(1, v)).collect();
            let u8s = stored_samples(&t, stored, 1, SampleDepth::U8).unwrap();
            let want: Vec<u8> = encoded.iter().map(|&v| to_u8(v)).collect();
            assert_eq!(u8s, Samples::U8(want), "{stored:?}");
            let Samples::U16(u16s) = stored_samples(&t, stored, 1, SampleDepth::U16).unwrap()
            else {
                panic!("16-bit samples asked for");
            };
            for (got, v) in u16s.iter().zip(&encoded) {
                let want = (v.clamp(0.0, 1.0) * 65535.0).round();
                assert_eq!(*got as f32, want, "{stored:?} {v}");
            }
            let Samples::F32(floats) = stored_samples(&t, stored, 1, SampleDepth::F32).unwrap()
            else {
                panic!("float samples asked for");
            };
            for (got, v) in floats.iter().zip(&encoded) {
                assert!((got - v).abs() < 1e-6, "{stored:?} {v}: {got}");
            }
        }
    }

    #[test]
    fn symmetries_and_repeats_move_texels_as_maps_do() {
        let map = varied(5, 3, 2);
        let t = upload(&map, &Device::Cpu).unwrap();
        for d in Dihedral::ALL {
            let got = download(&turned(&t, d).unwrap()).unwrap();
            assert_eq!(got.data(), map.transformed(d).data(), "{d:?}");
        }
        let big = download(&repeated(&t, 2).unwrap()).unwrap();
        assert_eq!((big.width(), big.height()), (10, 6));
        assert_eq!(big.get(1, 5, 9), map.get(1, 2, 4));
        assert_eq!(big.get(0, 2, 3), map.get(0, 1, 1));
    }
}
