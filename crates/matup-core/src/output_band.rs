//! A band of an output's rows as the pipeline hands it on: its maps on the host, and where the
//! run made them on a device (a GPU), those maps still there. Whoever keeps the band brings
//! back only what it needs: a writer the files' samples, encoded on the device
//! ([`crate::io::MaterialWriter::write_band`]), a preview its window, a library caller the
//! whole material ([`OutputBand::to_material`]).

use std::borrow::Cow;

use candle_core::Tensor;

use crate::device_maps::download;
use crate::map::Map;
use crate::material::{MapKind, Material};
use crate::{Error, Result};

/// Rows of an output, every map as wide as the output.
pub struct OutputBand {
    /// The band's maps. A map held on a device is a map of no texels here, its channels
    /// kept, so that a file's plan can read them.
    material: Material,
    /// The maps held on a device, `[channels, rows, width]`.
    on_device: Vec<(MapKind, Tensor)>,
    /// [width, rows].
    size: [usize; 2],
}

impl From<Material> for OutputBand {
    fn from(material: Material) -> OutputBand {
        let size = [material.width(), material.height_px()];
        OutputBand {
            material,
            on_device: Vec::new(),
            size,
        }
    }
}

impl OutputBand {
    /// The maps of `rest` with those of `on_device` (every one `[channels, rows, width]` of
    /// one size) in place of `rest`'s maps of their kinds, which are dropped.
    pub fn with_maps_on_device(
        mut rest: Material,
        on_device: Vec<(MapKind, Tensor)>,
    ) -> Result<OutputBand> {
        let mut size = None;
        for (kind, t) in &on_device {
            let (channels, rows, width) = t.dims3()?;
            if *size.get_or_insert([width, rows]) != [width, rows] {
                return Err(Error::Invalid(format!(
                    "a band's {kind} on the device is {width}×{rows}, its other maps {:?}",
                    size.unwrap()
                )));
            }
            let map = rest.map_mut(*kind).ok_or_else(|| {
                Error::Invalid(format!("a band holds no {kind} on the host to stand for"))
            })?;
            *map = Map::filled(0, 0, channels, 0.0);
        }
        let size = size.unwrap_or([rest.width(), rest.height_px()]);
        Ok(OutputBand {
            material: rest,
            on_device,
            size,
        })
    }

    pub fn width(&self) -> usize {
        self.size[0]
    }

    pub fn rows(&self) -> usize {
        self.size[1]
    }

    /// The kinds of map held on a device.
    pub fn kinds_on_device(&self) -> impl Iterator<Item = MapKind> + '_ {
        self.on_device.iter().map(|(kind, _)| *kind)
    }

    /// The band's material and its maps held on a device (whose maps in the material have
    /// no texels).
    pub(crate) fn parts(&self) -> (&Material, &[(MapKind, Tensor)]) {
        (&self.material, &self.on_device)
    }

    /// The whole band on the host (borrowed where it is all there).
    pub fn to_material(&self) -> Result<Cow<'_, Material>> {
        Ok(match self.on_device.is_empty() {
            true => Cow::Borrowed(&self.material),
            false => Cow::Owned(self.crop(0, 0, self.size[0], self.size[1])?),
        })
    }

    /// The band's `width × rows` texels from column `x0` and row `y0`, on the host.
    pub fn crop(&self, x0: usize, y0: usize, width: usize, rows: usize) -> Result<Material> {
        let whole = x0 == 0 && y0 == 0 && [width, rows] == self.size;
        let mut out = self.material.map_maps(|m| match m.texels() {
            0 => m.clone(),
            _ if whole => m.clone(),
            _ => m.crop(x0, y0, width, rows),
        });
        for (kind, t) in &self.on_device {
            let window = t.narrow(1, y0, rows)?.narrow(2, x0, width)?;
            *out.map_mut(*kind).expect("a kind the material has") = download(&window)?;
        }
        Ok(out)
    }

    /// Keeps `count` of the band's rows from row `first`.
    pub fn keep_rows(&mut self, first: usize, count: usize) -> Result<()> {
        for kind in MapKind::ALL {
            let on_device = self.on_device.iter_mut().find(|(k, _)| *k == kind);
            match (on_device, self.material.map_mut(kind)) {
                (Some((_, t)), _) => *t = t.narrow(1, first, count)?,
                (None, Some(map)) => map.keep_rows(first, count),
                (None, None) => {}
            }
        }
        for map in self.material.carried.maps_mut() {
            map.keep_rows(first, count);
        }
        self.size[1] = count;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device_maps::upload;
    use candle_core::Device;

    fn material() -> Material {
        let mut m = Material::uniform(6, [0.2, 0.4, 0.6], 0.5, 0.0);
        m.base_color = Map::from_fn(6, 6, 3, |c, y, x| (c * 36 + y * 6 + x) as f32 / 108.0);
        m.roughness = Map::from_fn(6, 6, 1, |_, y, x| (y * 6 + x) as f32 / 36.0);
        m.height = Some(Map::from_fn(6, 6, 1, |_, y, _| y as f32 / 6.0));
        m
    }

    #[test]
    fn maps_on_a_device_come_back_as_the_host_held_them() {
        let whole = material();
        let on_device = [MapKind::BaseColor, MapKind::Roughness]
            .map(|k| (k, upload(whole.map(k).unwrap(), &Device::Cpu).unwrap()));
        let mut band = OutputBand::with_maps_on_device(whole.clone(), on_device.into()).unwrap();
        assert_eq!((band.width(), band.rows()), (6, 6));
        assert_eq!(
            band.kinds_on_device().collect::<Vec<_>>(),
            [MapKind::BaseColor, MapKind::Roughness]
        );
        // Only the placeholders are on the host: the device's maps are not held twice.
        assert_eq!(band.parts().0.base_color.texels(), 0);
        assert_eq!(band.parts().0.base_color.channels(), 3);
        assert_eq!(*band.to_material().unwrap(), whole);
        assert_eq!(
            band.crop(1, 2, 3, 2).unwrap(),
            whole.map_maps(|m| m.crop(1, 2, 3, 2))
        );
        band.keep_rows(1, 4).unwrap();
        let mut kept = whole.clone();
        kept.maps_mut().for_each(|m| m.keep_rows(1, 4));
        assert_eq!(band.rows(), 4);
        assert_eq!(*band.to_material().unwrap(), kept);
    }
}
