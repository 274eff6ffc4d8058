//! [`Map`]: the one in-memory image representation (planar f32).

use rayon::prelude::*;

/// Values from which whole-map operations run on rayon's threads (smaller maps take longer
/// to share out than to compute).
pub(crate) const PARALLEL_TEXELS: usize = 1 << 16;

/// A 2D image of `channels` planes of `width × height` f32 values, stored plane after plane,
/// each plane row-major. Every texture, render and intermediate image in matup is a `Map`.
#[derive(Clone, Debug, PartialEq)]
pub struct Map {
    width: usize,
    height: usize,
    channels: usize,
    data: Vec<f32>,
}

impl Map {
    /// A map filled with `value`.
    pub fn filled(width: usize, height: usize, channels: usize, value: f32) -> Self {
        Map {
            width,
            height,
            channels,
            data: vec![value; width * height * channels],
        }
    }

    /// Wraps planar data (`channels` planes of `width × height`).
    ///
    /// # Panics
    /// If `data.len() != width * height * channels` (a programming error, not bad input).
    pub fn from_planar(width: usize, height: usize, channels: usize, data: Vec<f32>) -> Self {
        assert_eq!(
            data.len(),
            width * height * channels,
            "planar data of {width}×{height}×{channels} has the wrong length"
        );
        Map {
            width,
            height,
            channels,
            data,
        }
    }

    /// Builds a map from a function of (channel, row, column).
    pub fn from_fn(
        width: usize,
        height: usize,
        channels: usize,
        f: impl Fn(usize, usize, usize) -> f32 + Sync,
    ) -> Self {
        let mut data = vec![0f32; width * height * channels];
        let row = |(r, out): (usize, &mut [f32])| {
            let (c, y) = (r / height, r % height);
            for (x, v) in out.iter_mut().enumerate() {
                *v = f(c, y, x);
            }
        };
        // Rows in parallel where there are enough of them to pay for it.
        if data.len() >= PARALLEL_TEXELS {
            data.par_chunks_mut(width.max(1)).enumerate().for_each(row);
        } else {
            data.chunks_mut(width.max(1)).enumerate().for_each(row);
        }
        Map::from_planar(width, height, channels, data)
    }

    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    pub fn channels(&self) -> usize {
        self.channels
    }
    /// Texels per plane.
    pub fn texels(&self) -> usize {
        self.width * self.height
    }
    pub fn data(&self) -> &[f32] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }
    pub fn into_data(self) -> Vec<f32> {
        self.data
    }

    /// One channel plane, row-major.
    pub fn plane(&self, c: usize) -> &[f32] {
        let n = self.texels();
        &self.data[c * n..(c + 1) * n]
    }
    pub fn plane_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.texels();
        &mut self.data[c * n..(c + 1) * n]
    }

    /// Every channel plane, mutable at once (to write several in one parallel pass).
    pub fn planes_mut<const C: usize>(&mut self) -> [&mut [f32]; C] {
        assert_eq!(
            self.channels, C,
            "planes_mut of a {}-channel map",
            self.channels
        );
        let n = self.texels();
        let mut planes = self.data.chunks_exact_mut(n.max(1));
        std::array::from_fn(|_| planes.next().unwrap_or_default())
    }

    #[inline]
    pub fn get(&self, c: usize, y: usize, x: usize) -> f32 {
        self.data[(c * self.height + y) * self.width + x]
    }
    #[inline]
    pub fn set(&mut self, c: usize, y: usize, x: usize, v: f32) {
        self.data[(c * self.height + y) * self.width + x] = v;
    }

    /// The value of every channel at one texel.
    pub fn texel<const C: usize>(&self, index: usize) -> [f32; C] {
        debug_assert_eq!(C, self.channels);
        let n = self.texels();
        std::array::from_fn(|c| self.data[c * n + index])
    }

    /// Applies `f` to every value.
    pub fn map_values(mut self, f: impl Fn(f32) -> f32 + Sync + Send) -> Self {
        if self.data.len() >= PARALLEL_TEXELS {
            self.data.par_iter_mut().for_each(|v| *v = f(*v));
        } else {
            self.data.iter_mut().for_each(|v| *v = f(*v));
        }
        self
    }

    /// A map holding only the listed channels, in that order.
    pub fn select_channels(&self, channels: &[usize]) -> Map {
        let mut data = Vec::with_capacity(self.texels() * channels.len());
        for &c in channels {
            data.extend_from_slice(self.plane(c));
        }
        Map::from_planar(self.width, self.height, channels.len(), data)
    }

    /// Stacks maps of the same size channel-wise.
    pub fn stack(maps: &[&Map]) -> Map {
        let (w, h) = (maps[0].width, maps[0].height);
        let mut data = Vec::new();
        for m in maps {
            assert_eq!((m.width, m.height), (w, h), "stacked maps differ in size");
            data.extend_from_slice(&m.data);
        }
        let channels = data.len() / (w * h);
        Map::from_planar(w, h, channels, data)
    }

    /// Whether every value of a channel lies within `tolerance` of its first value.
    pub fn is_constant(&self, c: usize, tolerance: f32) -> bool {
        let plane = self.plane(c);
        let first = plane[0];
        plane.iter().all(|v| (v - first).abs() <= tolerance)
    }

    /// The mean of one channel.
    pub fn mean(&self, c: usize) -> f32 {
        let plane = self.plane(c);
        (plane.iter().map(|&v| v as f64).sum::<f64>() / plane.len() as f64) as f32
    }

    /// The map under a symmetry of the square: mirrored, rotated or transposed.
    pub fn transformed(&self, t: Dihedral) -> Map {
        let (w, h) = (self.width, self.height);
        let (ow, oh) = if t.transpose { (h, w) } else { (w, h) };
        Map::from_fn(ow, oh, self.channels, |c, y, x| {
            let (y, x) = t.source_texel(w, h, y, x);
            self.get(c, y, x)
        })
    }

    /// Adds `other.transformed(t)` to this map without building it (a self-ensemble sums
    /// passes at the output size, where one more map is 0.25–0.75 GB at 8K²).
    pub fn add_transformed(&mut self, other: &Map, t: Dihedral) {
        let (w, h) = (other.width, other.height);
        let (ow, oh) = if t.transpose { (h, w) } else { (w, h) };
        assert_eq!(
            (ow, oh, other.channels),
            (self.width, self.height, self.channels)
        );
        for c in 0..self.channels {
            let plane = &mut self.data[c * ow * oh..(c + 1) * ow * oh];
            plane.par_chunks_mut(ow).enumerate().for_each(|(y, row)| {
                for (x, v) in row.iter_mut().enumerate() {
                    let (sy, sx) = t.source_texel(w, h, y, x);
                    *v += other.get(c, sy, sx);
                }
            });
        }
    }

    /// Rows `first..first + count` of every plane (a band of a streamed output).
    pub fn rows(&self, first: usize, count: usize) -> Map {
        assert!(first + count <= self.height);
        let (w, n) = (self.width, self.texels());
        let mut data = Vec::with_capacity(w * count * self.channels);
        for c in 0..self.channels {
            data.extend_from_slice(&self.data[c * n + first * w..c * n + (first + count) * w]);
        }
        Map::from_planar(w, count, self.channels, data)
    }

    /// Keeps rows `first..first + count` of every plane in place (no second buffer: a band
    /// dropping its context rows).
    pub fn keep_rows(&mut self, first: usize, count: usize) {
        assert!(first + count <= self.height);
        let (w, n) = (self.width, self.texels());
        for c in 0..self.channels {
            self.data.copy_within(
                c * n + first * w..c * n + (first + count) * w,
                c * count * w,
            );
        }
        self.data.truncate(self.channels * count * w);
        self.height = count;
    }

    /// The rows `source(0), source(1), …, source(count − 1)` of every plane: the rows a band
    /// reads, its context included (indices already wrapped or clamped by the caller).
    pub fn gather_rows(&self, count: usize, source: impl Fn(usize) -> usize) -> Map {
        let (w, n) = (self.width, self.texels());
        let mut data = Vec::with_capacity(w * count * self.channels);
        for c in 0..self.channels {
            for y in 0..count {
                let from = c * n + source(y) * w;
                data.extend_from_slice(&self.data[from..from + w]);
            }
        }
        Map::from_planar(w, count, self.channels, data)
    }

    /// Copies `band` (as wide, as many channels) over rows `first..` of every plane.
    pub fn paste_rows(&mut self, first: usize, band: &Map) {
        assert!(band.width == self.width && band.channels == self.channels);
        assert!(first + band.height <= self.height);
        let (w, n, m) = (self.width, self.texels(), band.texels());
        for c in 0..self.channels {
            self.data[c * n + first * w..c * n + first * w + m]
                .copy_from_slice(&band.data[c * m..(c + 1) * m]);
        }
    }

    /// A copy of the rectangle starting at (`x0`, `y0`).
    pub fn crop(&self, x0: usize, y0: usize, width: usize, height: usize) -> Map {
        assert!(x0 + width <= self.width && y0 + height <= self.height);
        Map::from_fn(width, height, self.channels, |c, y, x| {
            self.get(c, y0 + y, x0 + x)
        })
    }
}

/// One of the eight symmetries of the square: mirror the columns (`flip_x`) and/or the rows
/// (`flip_y`), then swap rows and columns (`transpose`). The data augmentation of
/// super-resolution training; [`crate::Material::transformed`] applies it to a material,
/// turning its normals with it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Dihedral {
    pub flip_x: bool,
    pub flip_y: bool,
    pub transpose: bool,
}

impl Dihedral {
    /// Rows become columns: an axis's statistics, computed along rows, for the columns.
    pub const TRANSPOSE: Dihedral = Dihedral {
        flip_x: false,
        flip_y: false,
        transpose: true,
    };

    /// All eight, the identity first.
    pub const ALL: [Dihedral; 8] = {
        let mut all = [Dihedral {
            flip_x: false,
            flip_y: false,
            transpose: false,
        }; 8];
        let mut i = 0;
        while i < 8 {
            all[i] = Dihedral {
                flip_x: i & 1 != 0,
                flip_y: i & 2 != 0,
                transpose: i & 4 != 0,
            };
            i += 1;
        }
        all
    };

    /// The symmetry that undoes this one. (Flips then a transpose are undone by the transpose
    /// then the flips, which is the flips swapped, then the transpose.)
    pub fn inverse(self) -> Dihedral {
        if self.transpose {
            Dihedral {
                flip_x: self.flip_y,
                flip_y: self.flip_x,
                transpose: true,
            }
        } else {
            self
        }
    }

    /// The texel of a `width × height` map that texel (`y`, `x`) of its transform reads: the
    /// transpose undone, then the flips.
    fn source_texel(self, width: usize, height: usize, y: usize, x: usize) -> (usize, usize) {
        let (y, x) = if self.transpose { (x, y) } else { (y, x) };
        let y = if self.flip_y { height - 1 - y } else { y };
        let x = if self.flip_x { width - 1 - x } else { x };
        (y, x)
    }

    /// Where a tangent-plane vector (x right, y down the rows) points after the symmetry.
    pub fn vector(self, [x, y]: [f32; 2]) -> [f32; 2] {
        let x = if self.flip_x { -x } else { x };
        let y = if self.flip_y { -y } else { y };
        if self.transpose {
            [y, x]
        } else {
            [x, y]
        }
    }
}

#[cfg(test)]
mod dihedral_tests {
    use super::*;

    #[test]
    fn each_symmetry_is_undone_by_its_inverse_and_they_are_all_different() {
        let m = Map::from_fn(5, 3, 2, |c, y, x| (c * 100 + y * 10 + x) as f32);
        let mut seen = Vec::new();
        for t in Dihedral::ALL {
            let turned = m.transformed(t);
            assert_eq!(turned.transformed(t.inverse()), m, "{t:?}");
            let mut sum = Map::filled(turned.width(), turned.height(), 2, 1.0);
            sum.add_transformed(&m, t);
            assert_eq!(sum, turned.clone().map_values(|v| v + 1.0), "{t:?}");
            assert!(!seen.contains(&turned), "{t:?} repeats another symmetry");
            seen.push(turned);
            let v = t.inverse().vector(t.vector([0.3, -0.7]));
            assert_eq!(v, [0.3, -0.7], "{t:?}");
        }
        // Mirroring the columns moves the first column last.
        let flipped = m.transformed(Dihedral {
            flip_x: true,
            ..Dihedral::default()
        });
        assert_eq!(flipped.get(1, 2, 0), m.get(1, 2, 4));
    }
}
