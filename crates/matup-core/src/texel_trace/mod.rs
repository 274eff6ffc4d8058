//! What a map went through before it was saved losslessly, read from its texels: a game's BC
//! texture unpacked to PNG, a model's JPEG cropped and kept as PNG. Its file no longer says so
//! (`Material::lossy` reads files), its texels do: BC's 4×4 blocks of few colours on a line
//! ([`block_trace`]) and JPEG's 8×8 blocks of coefficients on a quantiser's steps
//! ([`jpeg_trace`]), each tested at every offset of its grid, since crops and atlases shift it;
//! dithering's or posterising's few levels a channel ([`quantised_trace`]).
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
mod levels;
mod noise;
mod quantised;

use std::fmt;

pub use blocks::{block_trace, BlockPalette, BlockTrace};
pub use jpeg::{jpeg_trace, JpegTrace};
pub use noise::{
    immerkaer_response, noise_floor, noise_reading, NoiseFloor, NoiseReading, IMMERKAER_GAIN,
};
pub use quantised::{quantised_trace, QuantisedTrace};

use crate::map::Map;
use crate::map_kind::MapKind;

/// A lossy storage's trace found in a map's texels.
#[derive(Clone, Debug, PartialEq)]
pub enum TexelTrace {
    Blocks(BlockTrace),
    Jpeg(JpegTrace),
    Quantised(QuantisedTrace),
}

impl TexelTrace {
    /// Whether the map was a JPEG (else block-compressed).
    pub fn is_jpeg(&self) -> bool {
        matches!(self, TexelTrace::Jpeg(_))
    }
}

impl fmt::Display for TexelTrace {
    /// "BC1 blocks (4×4 at x 1, y 3)", "a JPEG's 8×8 grid (at x 0, y 0)", "32 levels a
    /// channel (dithered or posterised)".
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
            TexelTrace::Quantised(q) => {
                let mut read: Vec<String> =
                    (q.levels.iter().flatten()).map(usize::to_string).collect();
                // One number where every channel read has the same ladder.
                if read.windows(2).all(|w| w[0] == w[1]) {
                    read.truncate(1);
                }
                let levels = read.join("/");
                write!(f, "{levels} levels a channel (dithered or posterised)")
            }
        }
    }
}

/// The trace of lossy storage in `map`'s texels (a map of `kind`), if one shows: BC blocks,
/// else a JPEG's grid, else few levels a channel. `tileable`: the map wraps around (its blocks
/// read across its edges).
pub fn texel_trace(kind: MapKind, map: &Map, tileable: bool) -> Option<TexelTrace> {
    (block_trace(kind, map, tileable).map(TexelTrace::Blocks))
        .or_else(|| jpeg_trace(kind, map, tileable).map(TexelTrace::Jpeg))
        .or_else(|| quantised_trace(kind, map, tileable).map(TexelTrace::Quantised))
}

#[cfg(test)]
mod tests;
