//! Few levels' trace: a map dithered or posterised to at most 64 levels a channel (a 16-bit
//! RGB565 or RGB555 texture) keeps every texel on that ladder of levels, where an 8-bit
//! texture's own values land on a ladder of N levels about N/256 of the time. Read from the
//! histogram alone, so any offset and any roll of a map reads the same.

use super::levels::{Levels, Reach};
use crate::map::Map;
use crate::map_kind::MapKind;

/// What is read: a tileable map whole up to 1024², else its centre 512².
const REACH: Reach = Reach {
    whole: 1024,
    window: 512,
};

/// The most levels a ladder may have: 64 (RGB565's green); past that a ladder is too fine to
/// tell from chance (64 levels hold a quarter of any texture's values).
const MAX_LEVELS: usize = 64;

/// The share of a channel's texels that must lie on its ladder: all of them where a map was
/// quantised, at most 0.94 on the clean materials of `../shared` (a metallic map of a few
/// values, a base colour of flat patches; docs/experiments/2026-12-02-texel-traces.md).
const MIN_SHARE: f64 = 0.995;

/// The rungs a channel must use before its ladder says anything: a map of fewer distinct
/// values (a flat roughness, a metallic mask of 0 and 1) lies on every ladder.
const MIN_RUNGS: usize = 8;

/// A map's texels found on ladders of few levels.
#[derive(Clone, Debug, PartialEq)]
pub struct QuantisedTrace {
    /// Each channel read, its ladder's number of levels; `None` where the channel has too few
    /// distinct values to tell.
    pub levels: Vec<Option<usize>>,
}

/// Few levels in `map` (a map of `kind`), if every channel that varies enough lies on a ladder
/// of at most 64 levels as files store them (sRGB colour, grey maps as values). Normals are not
/// read: matup renormalises them when it reads them, which moves them off any ladder.
/// `tileable`: the map is read whole where it is no larger than 1024².
pub fn quantised_trace(kind: MapKind, map: &Map, tileable: bool) -> Option<QuantisedTrace> {
    if kind == MapKind::Normal {
        return None;
    }
    let channels: Vec<usize> = (0..map.channels().min(3)).collect();
    let levels = Levels::of(kind, map, &channels, REACH, tileable, 0);
    let read: Vec<Channel> = (0..channels.len())
        .map(|c| channel_ladder(&histogram(&levels, c)))
        .collect();
    // Every channel that varies enough on a ladder, and at least one that does.
    let spread = read.contains(&Channel::Spread);
    if spread || read.iter().all(|r| *r == Channel::TooFew) {
        return None;
    }
    let levels = (read.into_iter())
        .map(|r| match r {
            Channel::OnLadder(n) => Some(n),
            _ => None,
        })
        .collect();
    Some(QuantisedTrace { levels })
}

/// What one channel's histogram says.
#[derive(Clone, Copy, PartialEq)]
enum Channel {
    /// Too few distinct values to tell (a mask, a flat map): on every ladder.
    TooFew,
    /// On a ladder of this many levels, the fewest that hold it.
    OnLadder(usize),
    /// On no ladder of at most [`MAX_LEVELS`].
    Spread,
}

/// How many texels of channel `c` hold each 8-bit level.
fn histogram(levels: &Levels, c: usize) -> [usize; 256] {
    let mut counts = [0; 256];
    for y in 0..levels.height {
        for x in 0..levels.width {
            counts[levels.at(c, x, y).round().clamp(0.0, 255.0) as usize] += 1;
        }
    }
    counts
}

/// A channel's reading from its histogram.
fn channel_ladder(counts: &[usize; 256]) -> Channel {
    let distinct = counts.iter().filter(|&&n| n > 0).count();
    if distinct < MIN_RUNGS {
        return Channel::TooFew;
    }
    let total: usize = counts.iter().sum();
    let holds = |ladder: &[u8]| {
        let on: usize = ladder.iter().map(|&l| counts[l as usize]).sum();
        let used = ladder.iter().filter(|&&l| counts[l as usize] > 0).count();
        used >= MIN_RUNGS && on as f64 >= MIN_SHARE * total as f64
    };
    (ladders())
        .find(|(_, ladder)| holds(ladder))
        .map_or(Channel::Spread, |(n, _)| Channel::OnLadder(n))
}

/// Every ladder tried, fewest levels first: `n` levels evenly spread over 0–255 and rounded,
/// and where `n` is 16, 32 or 64, the levels of `log2 n` bits widened to 8 by repeating their
/// top bits, as GPUs and texture tools widen RGB565 (they differ from the rounded ones by one
/// level on a few rungs).
fn ladders() -> impl Iterator<Item = (usize, Vec<u8>)> {
    (MIN_RUNGS..=MAX_LEVELS).flat_map(|n| {
        let steps = (n - 1) as f64;
        let rounded: Vec<u8> = (0..n)
            .map(|k| (k as f64 * 255.0 / steps).round() as u8)
            .collect();
        let bits = n.trailing_zeros();
        let widened = (n.is_power_of_two() && bits >= 4).then(|| {
            (0..n as u32)
                .map(|q| ((q << (8 - bits)) | (q >> (2 * bits - 8))) as u8)
                .collect::<Vec<u8>>()
        });
        std::iter::once((n, rounded)).chain(widened.map(|w| (n, w)))
    })
}
