//! Tiles cut into a training crop. The corpus has no tiled floors or walls (its README lists
//! the gap), and a network trained on it sharpens a tile's bevel, a line about one LR texel
//! wide, as it would a crack: on Tiles036 the batch-24 network's normals are as good as stock
//! SPAN's on the flat tile tops (0.88° against 0.87°) and worse on the bevels (10.9° against
//! 8.1°). This lays a grid of tiles over a crop, made of the corpus's own maps: the crop's
//! material on the tiles (its relief flattened, as glazed tiles are), a second crop's in the
//! grout, and bevelled edges between them whose slope is added to the normals (as heights add),
//! so the normals, the height and the colours of a tile agree as a scanned tile's do. Edges are
//! ragged (a straight, clean edge taught the network to straighten the painted lines of a road,
//! Road006 −0.23 dB), and some joints are flush (inlays, painted lines: colour without relief).

use matup_core::{Map, Material};
use rand::Rng;

/// The tiles' geometry, in texels of the true crop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileLayout {
    /// Distance between grout lines along x and y.
    pub period: [f32; 2],
    /// Where the grid starts along x and y.
    pub phase: [f32; 2],
    /// Every other row shifted by half a tile (a running bond, as bricks are laid).
    pub running_bond: bool,
    /// Half the width of the grout's flat bottom.
    pub grout: f32,
    /// Width of the bevel from the grout up to the tile's top.
    pub bevel: f32,
    /// The bevel's steepest slope (height over distance, both in texels).
    pub slope: f32,
    /// What is left of the tile material's relief on the tops (1: all of it).
    pub relief: f32,
    /// The grout material's base colour is scaled by this (grout is often darker).
    pub grout_shade: f32,
    /// How far the edges wander from straight lines, in texels (value noise).
    pub raggedness: f32,
    /// Seeds the edges' noise.
    pub noise_seed: u64,
}

impl TileLayout {
    /// A random layout: tiles of 12 to 96 texels (3 to 24 LR texels at ×4), grout 0.5 to 6
    /// texels wide, bevels of 1 to 5 texels at 15° to 60° (flush, without relief, one time in
    /// four), edges up to 2 texels from straight, at any phase (so that the lines fall anywhere
    /// within an LR texel).
    pub fn random(rng: &mut impl Rng) -> TileLayout {
        let px = rng.random_range(12.0..96.0f32);
        let py = if rng.random_bool(0.5) {
            px
        } else {
            rng.random_range(12.0..96.0f32)
        };
        TileLayout {
            period: [px, py],
            phase: [rng.random_range(0.0..px), rng.random_range(0.0..py)],
            running_bond: rng.random_bool(0.3),
            grout: rng.random_range(0.25..3.0),
            bevel: rng.random_range(1.0..5.0),
            slope: rng
                .random_range(15f32.to_radians()..60f32.to_radians())
                .tan(),
            relief: rng.random_range(0.0..1.0),
            grout_shade: rng.random_range(0.3..1.0),
            raggedness: rng.random_range(0.0..2.0),
            noise_seed: rng.random(),
        }
    }

    /// Value noise in [−1, 1] at (`x`, `y`) on a lattice of `cell` texels: smooth, and a
    /// function of the layout's seed alone.
    fn noise(&self, x: f32, y: f32, cell: f32) -> f32 {
        let lattice = |i: i64, j: i64| {
            // SplitMix64's finaliser: a well-mixed hash of the lattice point and the seed.
            let mut z = self.noise_seed
                ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 40) as f32 / (1u64 << 23) as f32 - 1.0
        };
        let (u, v) = (x / cell, y / cell);
        let (i, j) = (u.floor() as i64, v.floor() as i64);
        let (a, b) = (smoothstep(u - u.floor()), smoothstep(v - v.floor()));
        let row = |j: i64| lattice(i, j) + (lattice(i + 1, j) - lattice(i, j)) * a;
        row(j) + (row(j + 1) - row(j)) * b
    }

    /// How far the edges are moved at (`x`, `y`): two octaves of noise.
    fn jitter(&self, x: f32, y: f32) -> f32 {
        self.raggedness * (0.6 * self.noise(x, y, 4.0) + 0.4 * self.noise(x, y, 1.5))
    }

    /// Distance from the point (`x`, `y`) to the nearest grout line's centre, the lines
    /// ragged by [`TileLayout::jitter`].
    fn distance_to_grout(&self, x: f32, y: f32) -> f32 {
        let [px, py] = self.period;
        let to_line = |v: f32, period: f32| {
            let m = v.rem_euclid(period);
            m.min(period - m)
        };
        let row = ((y - self.phase[1]) / py).floor() as i64;
        let shift = if self.running_bond && row.rem_euclid(2) == 1 {
            px / 2.0
        } else {
            0.0
        };
        let straight = to_line(x - self.phase[0] - shift, px).min(to_line(y - self.phase[1], py));
        straight + self.jitter(x, y)
    }

    /// The surface's height above the grout's bottom, in texels, at distance `d` from a line:
    /// zero in the grout, rising along a smoothstep over the bevel to its top.
    fn rise(&self, d: f32) -> f32 {
        let t = ((d - self.grout) / self.bevel).clamp(0.0, 1.0);
        // A smoothstep's steepest slope is 1.5 / bevel; scaled to `slope` there.
        self.slope * self.bevel / 1.5 * smoothstep(t)
    }

    /// The share of the texel at (`x`, `y`) (its centre) covered by grout.
    fn grout_cover(&self, x: f32, y: f32) -> f32 {
        (self.grout + 0.5 - self.distance_to_grout(x, y)).clamp(0.0, 1.0)
    }

    /// `tile` cut into tiles with `grout` between them (two materials of one size).
    pub fn cut(&self, tile: &Material, grout: &Material) -> Material {
        let (w, h) = (tile.width(), tile.height_px());
        assert_eq!((w, h), (grout.width(), grout.height_px()));
        let at = |x: usize, y: usize| (x as f32 + 0.5, y as f32 + 0.5);
        let cover = Map::from_fn(w, h, 1, |_, y, x| {
            let (x, y) = at(x, y);
            self.grout_cover(x, y)
        });
        // The rise at any point of the surface (texel centres are at half-integers).
        let rise_at = |x: f32, y: f32| self.rise(self.distance_to_grout(x, y));
        let mix = |a: f32, b: f32, y: usize, x: usize| {
            let c = cover.get(0, y, x);
            a + (b - a) * c
        };
        let base_color = Map::from_fn(w, h, 3, |c, y, x| {
            let g = (grout.base_color.get(c, y, x) * self.grout_shade).clamp(0.0, 1.0);
            mix(tile.base_color.get(c, y, x), g, y, x)
        });
        let roughness = Map::from_fn(w, h, 1, |_, y, x| {
            mix(
                tile.roughness.get(0, y, x),
                grout.roughness.get(0, y, x),
                y,
                x,
            )
        });
        // Grout is a mineral: no metal in it.
        let metallic = Map::from_fn(w, h, 1, |_, y, x| {
            mix(tile.metallic.get(0, y, x), 0.0, y, x)
        });
        // Slopes (−∂z/∂x, −∂z/∂y) add where heights add: the tops' relief (flattened), the
        // grout's, and the bevel's, its mean over the texel (the rise across it), so a bevel
        // narrower than a texel still tilts it as much as it climbs.
        let slopes = |m: &Material, scale: f32, y: usize, x: usize| {
            let nz = m.normal.get(2, y, x).max(0.05);
            [0, 1].map(|c| scale * m.normal.get(c, y, x) / nz)
        };
        let mut normal = Map::filled(w, h, 3, 0.0);
        for y in 0..h {
            for x in 0..w {
                let (cx, cy) = at(x, y);
                let top = slopes(tile, self.relief, y, x);
                let bottom = slopes(grout, 1.0, y, x);
                let sx =
                    mix(top[0], bottom[0], y, x) - (rise_at(cx + 0.5, cy) - rise_at(cx - 0.5, cy));
                let sy =
                    mix(top[1], bottom[1], y, x) - (rise_at(cx, cy + 0.5) - rise_at(cx, cy - 0.5));
                let len = (sx * sx + sy * sy + 1.0).sqrt();
                for (c, v) in [sx, sy, 1.0].into_iter().enumerate() {
                    normal.set(c, y, x, v / len);
                }
            }
        }
        // Height maps are in [0, 1] at an arbitrary scale: half of it for the materials'
        // own relief, half for the step from the grout up to the tops.
        let full_rise = self.rise(f32::INFINITY).max(1e-6);
        let height = match (&tile.height, &grout.height) {
            (Some(top), Some(bottom)) => Some(Map::from_fn(w, h, 1, |_, y, x| {
                let own = mix(
                    0.5 + self.relief * (top.get(0, y, x) - 0.5),
                    bottom.get(0, y, x),
                    y,
                    x,
                );
                let (cx, cy) = at(x, y);
                (0.5 * own + 0.5 * rise_at(cx, cy) / full_rise).clamp(0.0, 1.0)
            })),
            _ => None,
        };
        Material {
            base_color,
            normal,
            roughness,
            metallic,
            height,
            anisotropy: tile.anisotropy.clone(),
            anisotropy_angle: tile.anisotropy_angle.clone(),
            carried: Default::default(),
            origin: None,
            lossy: Default::default(),
        }
    }
}

/// `3t² − 2t³`: from 0 to 1 over [0, 1] with zero slope at both ends.
fn smoothstep(t: f32) -> f32 {
    t * t * (3.0 - 2.0 * t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> TileLayout {
        TileLayout {
            period: [16.0, 16.0],
            phase: [0.0, 0.0],
            running_bond: false,
            grout: 1.5,
            bevel: 4.0,
            slope: 1.0,
            relief: 1.0,
            grout_shade: 0.5,
            raggedness: 0.0,
            noise_seed: 7,
        }
    }

    #[test]
    fn grout_runs_along_the_grid_in_the_grout_material_and_tops_keep_the_tile_material() {
        let tile = Material::uniform(32, [0.8, 0.7, 0.6], 0.2, 1.0);
        let grout = Material::uniform(32, [0.4, 0.4, 0.4], 0.9, 0.0);
        let out = layout().cut(&tile, &grout);
        // Texel 0's centre is 0.5 from the line at 0: all grout, shaded by 0.5.
        assert!((out.base_color.get(0, 5, 0) - 0.2).abs() < 1e-6);
        assert_eq!(out.roughness.get(0, 5, 0), 0.9);
        assert_eq!(out.metallic.get(0, 5, 0), 0.0);
        // Texel 8 is the middle of a tile: the tile's material, facing up.
        assert_eq!(out.base_color.get(0, 8, 8), 0.8);
        assert_eq!(out.roughness.get(0, 8, 8), 0.2);
        assert_eq!(out.metallic.get(0, 8, 8), 1.0);
        assert_eq!(out.normal.get(2, 8, 8), 1.0);
        // Texel 1 spans 1 to 2 from the line, half of it within the grout's 1.5.
        assert!((out.base_color.get(0, 8, 1) - 0.5).abs() < 1e-6);
    }

    #[test]
    fn the_bevels_normals_are_the_slopes_of_its_height() {
        let mut tile = Material::uniform(32, [0.5; 3], 0.5, 0.0);
        tile.height = Some(Map::filled(32, 32, 1, 0.5));
        let grout = tile.clone();
        let out = layout().cut(&tile, &grout);
        let height = out.height.as_ref().unwrap();
        // Along row 8 the surface rises from each line (x = 0, 16, 32) over the bevel (1.5 to
        // 5.5 from it): normals lean away from the rise.
        for x in 1..31 {
            let rise = height.get(0, 8, x + 1) - height.get(0, 8, x - 1);
            let nx = out.normal.get(0, 8, x);
            assert!(rise * nx <= 0.0, "x = {x}: rise {rise}, normal x {nx}");
            if rise.abs() > 1e-3 {
                assert!(nx.abs() > 0.05, "x = {x}: a slope with a flat normal");
            }
            let n = [0, 1, 2].map(|c| out.normal.get(c, 8, x));
            assert!((n.iter().map(|v| v * v).sum::<f32>() - 1.0).abs() < 1e-5);
        }
        // The steepest tilt is near the layout's slope (45°) and not above it (a texel's mean
        // slope is a little below the steepest: 44.4°).
        let steepest = (0..32)
            .map(|x| out.normal.get(2, 8, x).acos().to_degrees())
            .fold(0.0, f32::max);
        assert!((44.0..=45.0).contains(&steepest), "{steepest}°");
        // The grout is lower than the tops.
        assert!(height.get(0, 8, 0) < height.get(0, 8, 8) - 0.3);
    }

    #[test]
    fn a_share_of_the_training_crops_is_tiled_and_the_others_are_plain_crops() {
        use crate::data::{random_pair, Corpus, Shares};
        use rand::SeedableRng;
        let corpus = Corpus {
            names: vec!["light".into(), "dark".into()],
            materials: vec![
                Material::uniform(64, [0.9; 3], 0.3, 0.0),
                Material::uniform(64, [0.1; 3], 0.3, 0.0),
            ],
        };
        let tiled = |pair: &crate::data::Pair| {
            let v = pair.truth.base_color.plane(0);
            v.iter().any(|&x| (x - v[0]).abs() > 0.01)
        };
        let draw = |share: f64, seed: u64| {
            let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
            let shares = Shares {
                tiled: share,
                ..Shares::default()
            };
            random_pair(&corpus, 32, 4, shares, &mut rng)
        };
        let tiled_count = (0..200).filter(|&seed| tiled(&draw(0.25, seed))).count();
        // A quarter are cut, and some of those have both crops from one material (invisible
        // here) or no line within the crop.
        assert!((25..=55).contains(&tiled_count), "{tiled_count} of 200");
        for seed in 0..50 {
            let (plain, again) = (draw(0.0, seed), draw(0.0, seed));
            assert!(!tiled(&plain));
            assert_eq!(plain.truth, again.truth);
            assert_eq!(plain.lr, plain.truth.box_downsample(4));
        }
    }

    #[test]
    fn ragged_edges_wander_within_their_bound_and_flush_joints_have_no_relief() {
        let tile = Material::uniform(64, [0.8; 3], 0.2, 0.0);
        let grout = Material::uniform(64, [0.4; 3], 0.9, 0.0);
        let ragged = TileLayout {
            raggedness: 1.5,
            slope: 0.0,
            period: [32.0, 1e4],
            phase: [0.0, 5e3],
            ..layout()
        };
        let out = ragged.cut(&tile, &grout);
        // The grout's right edge by the line at x = 32, row by row: where its cover falls
        // below a half.
        let edges: Vec<usize> = (0..64)
            .map(|y| {
                (32..48)
                    .find(|&x| out.roughness.get(0, y, x) < 0.55)
                    .unwrap()
            })
            .collect();
        let (lo, hi) = (edges.iter().min().unwrap(), edges.iter().max().unwrap());
        // Straight, the edge is at 33 (the grout's 1.5 texels); ragged, it wanders by up to
        // 1.5 either way and at least a texel over 64 rows.
        assert!(*lo >= 32 && *hi <= 35 && hi - lo >= 1, "{edges:?}");
        for y in 0..64 {
            for x in 0..64 {
                let j = ragged.jitter(x as f32 + 0.5, y as f32 + 0.5);
                assert!(j.abs() <= 1.5, "jitter {j}");
                // Flush: colour without relief.
                assert_eq!(out.normal.get(2, y, x), 1.0);
            }
        }
    }
}
