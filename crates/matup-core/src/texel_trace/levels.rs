//! The texels a trace is read from, as 8-bit levels, and how much of a map each detector
//! reads. Shared by the detectors, apart from the module that gathers them.

use crate::map::Map;
use crate::map_kind::MapKind;

/// How much of a map a detector reads: a tileable map whole up to `whole`² (so that every roll
/// reads the same), else its centre `window`².
#[derive(Clone, Copy)]
pub(super) struct Reach {
    pub(super) whole: usize,
    pub(super) window: usize,
}

/// The texels a trace is read from, in 8-bit levels as a file stores them: the whole map
/// (wrapping around where it tiles), or its centre where it is larger than a detector needs.
pub(super) struct Levels {
    /// The first texel's place in the map: [x, y].
    pub(super) origin: [usize; 2],
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) wrap: bool,
    /// One plane per channel read, row-major, `(width + pad) × (height + pad)`: where the
    /// window wraps, its first `pad` columns and rows repeated past its end.
    pub(super) planes: Vec<Vec<f32>>,
    pub(super) stride: usize,
}

impl Levels {
    /// `channels` of `map` (a map of `kind`) as stored levels (sRGB colour, normals as
    /// `(n + 1) / 2`, ×255), as far as `reach` says; `pad` texels repeated past the end where
    /// the map tiles and is read whole, so that a block may start on any texel.
    pub(super) fn of(
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
    pub(super) fn blocks(&self, side: usize) -> [usize; 2] {
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
    pub(super) fn at(&self, c: usize, x: usize, y: usize) -> f32 {
        self.planes[c][y * self.stride + x]
    }

    /// An offset in the window as the map's own: the grid's phase from its top-left texel.
    pub(super) fn map_offset(&self, [x, y]: [usize; 2], side: usize) -> [usize; 2] {
        [(self.origin[0] + x) % side, (self.origin[1] + y) % side]
    }
}
