//! BC's trace: each 4×4 block of a BC1 or BC3 texture holds at most four colours, evenly
//! spaced on one segment (two RGB565 endpoints and the thirds between them); each channel of
//! a BC4 or BC5 block at most eight levels, evenly spaced (or six, and 0 and 255). A clean
//! texture's blocks that vary hold more, and so do a BC texture's windows that straddle its
//! blocks: the palette shows at one offset of the 4-texel grid.

use glam::Vec3;

use super::levels::{Levels, Reach};
use crate::map::Map;
use crate::map_kind::MapKind;

/// The side of BC's blocks.
const BLOCK: usize = 4;

/// What is read: a tileable map whole up to 1024², else its centre 512² (16384 blocks at each
/// offset): a bounded cost on any map.
const REACH: Reach = Reach {
    whole: 1024,
    window: 512,
};

/// The least gap between a palette's neighbouring entries, in levels, for a block to tell:
/// closer ones fit any smooth block's neighbouring levels.
const MIN_GAP: f32 = 3.0;

/// How far a texel may lie from its palette entry, in levels: decoders round the thirds and
/// sevenths differently, and normals are renormalised on reading.
const TOLERANCE: f32 = 1.5;

/// The distinct colours a block's colour line needs to tell (any two lie on a line), and the
/// distinct levels a channel needs (a few levels fit some even division within
/// [`TOLERANCE`]: plates on the 4-texel grid, their bevels two or three levels), each told
/// apart by more than [`SAME_ENTRY`].
const MIN_COLOURS: usize = 3;
const MIN_LEVELS: usize = 4;

/// How close two values are for [`MIN_COLOURS`] and [`MIN_LEVELS`] to count them as one: a
/// flat plate's ±1 of 8-bit rounding is one level, a palette's entries are [`MIN_GAP`] apart.
const SAME_ENTRY: f32 = 2.0;

/// The informative blocks (wide enough for [`MIN_GAP`]) a verdict needs at its offset.
const MIN_BLOCKS: usize = 32;

/// The share of informative blocks that must fit a palette at the best offset.
const MIN_FIT: f64 = 0.8;

/// How far that share must stand above the median offset's: a texture's own few-colour
/// blocks (flat regions split by sharp edges, masks) fit at every offset alike.
const MIN_LEAD: f64 = 0.4;

/// The palette a block-compressed texture's blocks show.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlockPalette {
    /// At most four colours on a segment, evenly spaced: BC1's and BC3's colour blocks.
    ColourLine,
    /// At most eight levels evenly spaced in each of `channels` apart: BC4 (one), BC5 (two).
    Levels { channels: usize },
}

impl BlockPalette {
    /// The formats whose blocks hold this palette: "BC1/BC3", "BC4", "BC5".
    pub fn formats(self) -> &'static str {
        match self {
            BlockPalette::ColourLine => "BC1/BC3",
            BlockPalette::Levels { channels: 1 } => "BC4",
            BlockPalette::Levels { .. } => "BC5",
        }
    }

    /// The channels of the levels read a block of this palette in: RGB, or x (and y).
    fn channels(self) -> &'static [usize] {
        match self {
            BlockPalette::ColourLine => &[0, 1, 2],
            BlockPalette::Levels { channels } => &[0, 1][..channels],
        }
    }

    /// The most palette entries a block holds, and so steps between its extremes.
    fn steps(self) -> usize {
        match self {
            BlockPalette::ColourLine => 3,
            BlockPalette::Levels { .. } => 7,
        }
    }
}

/// BC blocks found in a map's texels.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockTrace {
    pub palette: BlockPalette,
    /// The grid's offset from the map's top-left texel: [x, y], each 0–3.
    pub offset: [usize; 2],
    /// The share of informative blocks that fit the palette at that offset.
    pub fit: f64,
    /// The same share at the median offset.
    pub median_fit: f64,
    /// The informative blocks at that offset.
    pub blocks: usize,
}

/// BC blocks in `map` (a map of `kind`), if its texels show them: colour and normal maps are
/// tested for BC1/BC3 colour blocks, normals' x and y for BC5's and grey maps for BC4's levels.
/// `tileable`: blocks wrap around the map's edges.
pub fn block_trace(kind: MapKind, map: &Map, tileable: bool) -> Option<BlockTrace> {
    let palettes: &[BlockPalette] = match map.channels() {
        n if n >= 3 && kind == MapKind::Normal => &[
            BlockPalette::Levels { channels: 2 },
            BlockPalette::ColourLine,
        ],
        n if n >= 3 => &[BlockPalette::ColourLine],
        _ => &[BlockPalette::Levels { channels: 1 }],
    };
    (palettes.iter()).find_map(|&palette| {
        let levels = Levels::of(kind, map, palette.channels(), REACH, tileable, BLOCK - 1);
        palette_trace(&levels, palette, kind == MapKind::Normal)
    })
}

/// How a block reads against a palette.
#[derive(Clone, Copy, PartialEq)]
enum Verdict {
    /// Too even to tell: its extremes closer than the palette's steps at [`MIN_GAP`], too few
    /// distinct values, or varying along one axis alone.
    Uninformative,
    Fits,
    Misfits,
}

impl Verdict {
    /// An informative block's verdict: whether it fits.
    fn fitting(fits: bool) -> Verdict {
        if fits {
            Verdict::Fits
        } else {
            Verdict::Misfits
        }
    }
}

/// The palette's trace in `levels`: each of the 16 offsets' share of informative blocks that
/// fit it, the best against the median. `renormalised`: normals, moved off their palette's
/// line when read (see [`colour_line_verdict`]).
fn palette_trace(levels: &Levels, palette: BlockPalette, renormalised: bool) -> Option<BlockTrace> {
    let [bw, bh] = levels.blocks(BLOCK);
    let shares: Vec<(f64, usize)> = (0..BLOCK * BLOCK)
        .map(|o| {
            let [ox, oy] = [o % BLOCK, o / BLOCK];
            let (mut fits, mut informative) = (0usize, 0usize);
            for by in 0..bh {
                for bx in 0..bw {
                    let at = [ox + bx * BLOCK, oy + by * BLOCK];
                    match block_verdict(levels, at, palette, renormalised) {
                        Verdict::Uninformative => {}
                        verdict => {
                            informative += 1;
                            fits += usize::from(verdict == Verdict::Fits);
                        }
                    }
                }
            }
            (fits as f64 / informative.max(1) as f64, informative)
        })
        .collect();
    let (best, &(fit, blocks)) = (shares.iter().enumerate())
        .max_by(|a, b| a.1 .0.total_cmp(&b.1 .0))
        .expect("16 offsets");
    let mut sorted: Vec<f64> = shares.iter().map(|s| s.0).collect();
    sorted.sort_by(f64::total_cmp);
    let median_fit = sorted[sorted.len() / 2];
    let trace = BlockTrace {
        palette,
        offset: levels.map_offset([best % BLOCK, best / BLOCK], BLOCK),
        fit,
        median_fit,
        blocks,
    };
    let found = blocks >= MIN_BLOCKS && fit >= MIN_FIT && fit - median_fit >= MIN_LEAD;
    found.then_some(trace)
}

/// How the 4×4 block at `[x, y]` of `levels` reads against `palette`.
fn block_verdict(
    levels: &Levels,
    [x, y]: [usize; 2],
    palette: BlockPalette,
    renormalised: bool,
) -> Verdict {
    let texel = |c: usize, i: usize| levels.at(c, x + i % BLOCK, y + i / BLOCK);
    // A block that varies along one axis alone (its rows all alike, or its columns) holds a
    // ramp's few evenly spaced levels, which fit any palette: plates and bevels laid on the
    // 4-texel grid.
    let channels = palette.channels().len();
    let alike = |a: usize, b: usize| (0..channels).all(|c| (texel(c, a) - texel(c, b)).abs() < 0.5);
    let rows_alike = (BLOCK..BLOCK * BLOCK).all(|i| alike(i, i % BLOCK));
    let columns_alike = (0..BLOCK * BLOCK).all(|i| alike(i, i - i % BLOCK));
    if rows_alike || columns_alike {
        return Verdict::Uninformative;
    }
    match palette {
        BlockPalette::ColourLine => {
            let colours: [[f32; 3]; 16] =
                std::array::from_fn(|i| std::array::from_fn(|c| texel(c, i)));
            colour_line_verdict(&colours, renormalised)
        }
        BlockPalette::Levels { channels } => {
            let verdicts =
                (0..channels).map(|c| levels_verdict(&std::array::from_fn(|i| texel(c, i))));
            // Each channel is a block of its own (BC5 is two BC4 blocks): the block fits where
            // every channel that tells fits.
            verdicts.fold(Verdict::Uninformative, |all, v| match (all, v) {
                (Verdict::Misfits, _) | (_, Verdict::Misfits) => Verdict::Misfits,
                (Verdict::Fits, _) | (_, Verdict::Fits) => Verdict::Fits,
                _ => Verdict::Uninformative,
            })
        }
    }
}

/// A block of colours against BC1's palette: at most four, on the segment between its two
/// farthest, at its ends and thirds (or its ends and middle). `renormalised`: the block's
/// colours are normals made unit length on reading, which bends BC1's segment into an arc of
/// a great circle and moves its thirds by several levels: they still lie on one plane through
/// the origin.
fn colour_line_verdict(colours: &[[f32; 3]; 16], renormalised: bool) -> Verdict {
    if distinct_within(colours, SAME_ENTRY).len() < MIN_COLOURS {
        return Verdict::Uninformative;
    }
    let distinct: Vec<Vec3> = distinct(colours).into_iter().map(Vec3::from).collect();
    let (mut a, mut b) = (distinct[0], distinct[0]);
    for (i, &p) in distinct.iter().enumerate() {
        for &q in &distinct[i + 1..] {
            if p.distance_squared(q) > a.distance_squared(b) {
                (a, b) = (p, q);
            }
        }
    }
    let length = a.distance(b);
    if length < 3.0 * MIN_GAP {
        return Verdict::Uninformative;
    }
    if distinct.len() > 4 {
        return Verdict::Misfits;
    }
    if renormalised {
        return Verdict::fitting(on_plane_through_origin(&distinct, a, b));
    }
    let direction = (b - a) / length;
    let mut along = Vec::with_capacity(distinct.len());
    for &p in &distinct {
        let t = (p - a).dot(direction);
        if (p - a - t * direction).length() > TOLERANCE {
            return Verdict::Misfits;
        }
        along.push(t);
    }
    let steps = BlockPalette::ColourLine.steps();
    Verdict::fitting(on_even_steps(&along, length, steps))
}

/// Whether `colours` (stored normals) lie within [`TOLERANCE`] of the plane through the
/// origin (the stored level 127.5) and `a` and `b`.
fn on_plane_through_origin(colours: &[Vec3], a: Vec3, b: Vec3) -> bool {
    let origin = Vec3::splat(127.5);
    let normal = (a - origin).cross(b - origin);
    if normal.length() < 1e-3 {
        return true;
    }
    let normal = normal.normalize();
    (colours.iter()).all(|&p| (p - origin).dot(normal).abs() <= TOLERANCE)
}

/// One channel of a block against BC4's palette: at most eight levels, evenly spaced between
/// its extremes (or six, beside 0 and 255).
fn levels_verdict(values: &[f32; 16]) -> Verdict {
    let steps = BlockPalette::Levels { channels: 1 }.steps();
    let spread = |vs: &[f32]| {
        let (lo, hi) = vs
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
        (lo, hi - lo)
    };
    let (_, span) = spread(values);
    let levels = distinct_within(&values.map(|v| [v]), SAME_ENTRY).len();
    if span < steps as f32 * MIN_GAP || levels < MIN_LEVELS {
        return Verdict::Uninformative;
    }
    let fits = |vs: &[f32]| {
        let distinct = distinct(&vs.iter().map(|&v| [v]).collect::<Vec<_>>());
        if vs.is_empty() || distinct.len() > steps + 1 {
            return false;
        }
        let (lo, span) = spread(vs);
        let along: Vec<f32> = distinct.iter().map(|v| v[0] - lo).collect();
        on_even_steps(&along, span, steps)
    };
    // BC4's six-level blocks keep 0 and 255 apart from their line.
    let inner: Vec<f32> = (values.iter().copied())
        .filter(|&v| v > 0.5 && v < 254.5)
        .collect();
    Verdict::fitting(fits(values) || (inner.len() < values.len() && fits(&inner)))
}

/// Whether positions `along` a segment of `length` (in levels) sit within [`TOLERANCE`] of one
/// of its even divisions into at most `max_steps` steps.
fn on_even_steps(along: &[f32], length: f32, max_steps: usize) -> bool {
    (1..=max_steps).any(|steps| {
        let step = length / steps as f32;
        (along.iter()).all(|&t| (t - (t / step).round() * step).abs() <= TOLERANCE)
    })
}

/// The distinct values of `texels`, to the nearest level (a decoded palette's entries are
/// whole levels apart; a normal renormalised on reading moves within one).
fn distinct<const N: usize>(texels: &[[f32; N]]) -> Vec<[f32; N]> {
    distinct_within(texels, 0.5)
}

/// The values of `texels`, each one first met and farther than `radius` in some channel
/// from every one kept before it.
fn distinct_within<const N: usize>(texels: &[[f32; N]], radius: f32) -> Vec<[f32; N]> {
    let mut seen: Vec<[f32; N]> = Vec::with_capacity(texels.len());
    for t in texels {
        let same = |s: &[f32; N]| (0..N).all(|c| (s[c] - t[c]).abs() < radius);
        if !seen.iter().any(same) {
            seen.push(*t);
        }
    }
    seen
}
