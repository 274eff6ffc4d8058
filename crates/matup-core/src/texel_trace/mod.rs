//! What a map went through before it was saved losslessly, read from its texels: a game's BC
//! texture unpacked to PNG, a model's JPEG cropped and kept as PNG. Its file no longer says so
//! (`Material::lossy` reads files), its texels do: BC's 4×4 blocks of few colours on a line
//! ([`block_trace`]) and JPEG's 8×8 blocks of coefficients on a quantiser's steps
//! ([`jpeg_trace`]), each tested at every offset of its grid, since crops and atlases shift it.
//!
//! Written here because no crate does it: image forensics libraries read a JPEG's quality from
//! its own tables, and texture tools read a DDS's format from its header; a lossless copy has
//! neither.
//!
//! A tileable map is read with its blocks wrapping around its edges, so that every offset sees
//! as many blocks and a map rolled by any number of texels reads the same (its grid's offset
//! rolled with it).

mod blocks;
mod jpeg;
mod noise;

use std::fmt;

pub use blocks::{block_trace, BlockPalette, BlockTrace};
pub use jpeg::{jpeg_trace, JpegTrace};
pub use noise::{immerkaer_response, noise_reading, NoiseReading, IMMERKAER_GAIN};

use crate::map::Map;
use crate::map_kind::MapKind;

/// A lossy storage's trace found in a map's texels.
#[derive(Clone, Debug, PartialEq)]
pub enum TexelTrace {
    Blocks(BlockTrace),
    Jpeg(JpegTrace),
}

impl TexelTrace {
    /// Whether the map was a JPEG (else block-compressed).
    pub fn is_jpeg(&self) -> bool {
        matches!(self, TexelTrace::Jpeg(_))
    }
}

impl fmt::Display for TexelTrace {
    /// "BC1 blocks (4×4 at x 1, y 3)", "a JPEG's 8×8 grid (at x 0, y 0)".
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TexelTrace::Blocks(b) => {
                let [x, y] = b.offset;
                write!(f, "{} blocks (4×4 at x {x}, y {y})", b.palette.formats())
            }
            TexelTrace::Jpeg(j) => {
                let [x, y] = j.offset;
                write!(f, "a JPEG's 8×8 grid (at x {x}, y {y})")
            }
        }
    }
}

/// The trace of lossy storage in `map`'s texels (a map of `kind`), if one shows: BC blocks,
/// else a JPEG's grid. `tileable`: the map wraps around (its blocks read across its edges).
pub fn texel_trace(kind: MapKind, map: &Map, tileable: bool) -> Option<TexelTrace> {
    (block_trace(kind, map, tileable).map(TexelTrace::Blocks))
        .or_else(|| jpeg_trace(kind, map, tileable).map(TexelTrace::Jpeg))
}

/// How much of a map a detector reads: a tileable map whole up to `whole`² (so that every roll
/// reads the same), else its centre `window`².
#[derive(Clone, Copy)]
struct Reach {
    whole: usize,
    window: usize,
}

/// The texels a trace is read from, in 8-bit levels as a file stores them: the whole map
/// (wrapping around where it tiles), or its centre where it is larger than a detector needs.
struct Levels {
    /// The first texel's place in the map: [x, y].
    origin: [usize; 2],
    width: usize,
    height: usize,
    wrap: bool,
    /// One plane per channel read, row-major, `(width + pad) × (height + pad)`: where the
    /// window wraps, its first `pad` columns and rows repeated past its end.
    planes: Vec<Vec<f32>>,
    stride: usize,
}

impl Levels {
    /// `channels` of `map` (a map of `kind`) as stored levels (sRGB colour, normals as
    /// `(n + 1) / 2`, ×255), as far as `reach` says; `pad` texels repeated past the end where
    /// the map tiles and is read whole, so that a block may start on any texel.
    fn of(
        kind: MapKind,
        map: &Map,
        channels: &[usize],
        reach: Reach,
        tileable: bool,
        pad: usize,
    ) -> Levels {
        let (mw, mh) = (map.width(), map.height());
        let wrap = tileable && mw <= reach.whole && mh <= reach.whole;
        let side = if wrap { reach.whole } else { reach.window };
        let (width, height) = (mw.min(side), mh.min(side));
        let origin = [(mw - width) / 2, (mh - height) / 2];
        let pad = if wrap { pad } else { 0 };
        let stride = width + pad;
        let planes = (channels.iter())
            .map(|&c| {
                let plane = map.plane(c);
                let mut out = Vec::with_capacity(stride * (height + pad));
                for y in 0..height + pad {
                    let row = (origin[1] + y % height) * mw;
                    for x in 0..width + pad {
                        let v = plane[row + origin[0] + x % width];
                        out.push(kind.stored(c, v).clamp(0.0, 1.0) * 255.0);
                    }
                }
                out
            })
            .collect();
        Levels {
            origin,
            width,
            height,
            wrap,
            planes,
            stride,
        }
    }

    /// The blocks of side `side` that fit along each axis at every offset of a `side` grid:
    /// all of them where the window wraps, else those clear of both ends at every offset (as
    /// many at each, so that no offset reads more).
    fn blocks(&self, side: usize) -> [usize; 2] {
        let fit = |n: usize| {
            if self.wrap {
                n / side
            } else {
                (n + 1 - side) / side
            }
        };
        [fit(self.width), fit(self.height)]
    }

    /// The level of channel `c` (its index among those read) at `[x, y]` of the window.
    fn at(&self, c: usize, x: usize, y: usize) -> f32 {
        self.planes[c][y * self.stride + x]
    }

    /// An offset in the window as the map's own: the grid's phase from its top-left texel.
    fn map_offset(&self, [x, y]: [usize; 2], side: usize) -> [usize; 2] {
        [(self.origin[0] + x) % side, (self.origin[1] + y) % side]
    }
}

#[cfg(test)]
mod tests;
