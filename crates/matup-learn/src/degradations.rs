//! The `[degradations]` of a training run: what the network's LR input goes through, drawn per
//! crop and per map, as maps are stored in the wild (`matup_core::degrade`). The truth stays
//! clean, so the network learns to see through blocks, JPEG, dithering, noise, blur and halos.

use matup_core::degrade::{BlockFormat, Degradation, DitherMethod, Subsampling, STORED_KINDS};
use matup_core::{MapKind, Material, Result};
use rand::seq::SliceRandom;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// How often each degradation is drawn, and how strong. Probabilities are per map of a crop
/// that is not kept clean; the drawn ones are applied in a random order.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Degradations {
    /// Share of the crops whose maps are all kept clean.
    pub clean_share: f64,
    /// Whether the loss sees a degraded crop's output back-projected onto its degraded input,
    /// as `filter.back_project = true` would ship it (true, the default), or unprojected, as
    /// a run that trusts the network over a degraded input would (false).
    #[serde(default = "yes")]
    pub project_degraded: bool,
    /// Block compression: colour BC1 or BC3, normals BC5 or (as older games ship them) BC1,
    /// grey maps BC4 or BC1.
    #[serde(default)]
    pub block: Chance,
    /// JPEG of a quality in `quality`, 4:4:4 for a share `full_chroma_share`, else 4:2:0.
    #[serde(default)]
    pub jpeg: JpegChance,
    /// Dithering to a number of levels in `levels`, by error diffusion for a share
    /// `diffusion_share`, else ordered.
    #[serde(default)]
    pub dither: DitherChance,
    /// Gaussian noise of `sigma` levels, or (a share `poisson_share`) shot noise of the same
    /// standard deviation at mid-grey.
    #[serde(default)]
    pub noise: NoiseChance,
    /// A Gaussian blur of `sigma` texels.
    #[serde(default)]
    pub blur: RangeChance,
    /// An unsharp mask of `amount` (its blur σ in `sigma`).
    #[serde(default)]
    pub halo: HaloChance,
}

/// A probability alone.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Chance {
    pub probability: f64,
}

#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct JpegChance {
    pub probability: f64,
    pub quality: [u8; 2],
    pub full_chroma_share: f64,
}

impl Default for JpegChance {
    fn default() -> Self {
        JpegChance {
            probability: 0.0,
            quality: [40, 95],
            full_chroma_share: 0.3,
        }
    }
}

#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct DitherChance {
    pub probability: f64,
    pub levels: [u16; 2],
    pub diffusion_share: f64,
}

impl Default for DitherChance {
    fn default() -> Self {
        DitherChance {
            probability: 0.0,
            levels: [16, 64],
            diffusion_share: 0.5,
        }
    }
}

#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseChance {
    pub probability: f64,
    pub sigma: [f32; 2],
    pub poisson_share: f64,
}

impl Default for NoiseChance {
    fn default() -> Self {
        NoiseChance {
            probability: 0.0,
            sigma: [1.0, 6.0],
            poisson_share: 0.3,
        }
    }
}

#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RangeChance {
    pub probability: f64,
    pub sigma: [f32; 2],
}

impl Default for RangeChance {
    fn default() -> Self {
        RangeChance {
            probability: 0.0,
            sigma: [0.3, 1.0],
        }
    }
}

#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct HaloChance {
    pub probability: f64,
    pub amount: [f32; 2],
    pub sigma: [f32; 2],
}

impl Default for HaloChance {
    fn default() -> Self {
        HaloChance {
            probability: 0.0,
            amount: [0.3, 1.0],
            sigma: [1.0, 2.0],
        }
    }
}

impl Degradations {
    /// The degradations a crop may be drawn, in words, in the order of the TOML's keys.
    pub fn drawn(&self) -> Vec<&'static str> {
        [
            ("block compression", self.block.probability),
            ("JPEG", self.jpeg.probability),
            ("dithering", self.dither.probability),
            ("noise", self.noise.probability),
            ("blur", self.blur.probability),
            ("halos", self.halo.probability),
        ]
        .into_iter()
        .filter(|&(_, p)| p > 0.0)
        .map(|(name, _)| name)
        .collect()
    }

    /// Checks the probabilities, shares and ranges.
    pub fn validate(&self) -> std::result::Result<(), String> {
        let shares = [
            ("clean_share", self.clean_share),
            ("block.probability", self.block.probability),
            ("jpeg.probability", self.jpeg.probability),
            ("jpeg.full_chroma_share", self.jpeg.full_chroma_share),
            ("dither.probability", self.dither.probability),
            ("dither.diffusion_share", self.dither.diffusion_share),
            ("noise.probability", self.noise.probability),
            ("noise.poisson_share", self.noise.poisson_share),
            ("blur.probability", self.blur.probability),
            ("halo.probability", self.halo.probability),
        ];
        for (key, share) in shares {
            if !(0.0..=1.0).contains(&share) {
                return Err(format!(
                    "degradations.{key} {share} must be between 0 and 1"
                ));
            }
        }
        let [q0, q1] = self.jpeg.quality;
        if !(1 <= q0 && q0 <= q1 && q1 <= 100) {
            return Err(format!(
                "degradations.jpeg.quality [{q0}, {q1}] must rise within 1 to 100"
            ));
        }
        let [l0, l1] = self.dither.levels;
        if !(2 <= l0 && l0 <= l1 && l1 <= 256) {
            return Err(format!(
                "degradations.dither.levels [{l0}, {l1}] must rise within 2 to 256"
            ));
        }
        for (key, [a, b]) in [
            ("noise.sigma", self.noise.sigma),
            ("blur.sigma", self.blur.sigma),
            ("halo.amount", self.halo.amount),
            ("halo.sigma", self.halo.sigma),
        ] {
            if !(a > 0.0 && a <= b && b.is_finite()) {
                return Err(format!(
                    "degradations.{key} [{a}, {b}] must be positive and rising"
                ));
            }
        }
        Ok(())
    }

    /// `lr` with each of its stored maps degraded as drawn from `rng` (all kept clean for a
    /// share `clean_share` of the crops), and whether any degradation was drawn.
    pub fn apply(&self, lr: &Material, rng: &mut impl Rng) -> Result<(Material, bool)> {
        let mut out = lr.clone();
        if rng.random_bool(self.clean_share) {
            return Ok((out, false));
        }
        let mut degraded = false;
        for kind in STORED_KINDS {
            let steps = self.draw(kind, rng);
            if let Some(map) = out.map_mut(kind) {
                degraded |= !steps.is_empty();
                for step in steps {
                    *map = step.apply(kind, map, rng)?;
                }
            }
        }
        Ok((out, degraded))
    }

    /// The degradations of one map of `kind`, in the order they are applied.
    pub fn draw(&self, kind: MapKind, rng: &mut impl Rng) -> Vec<Degradation> {
        let mut steps = Vec::new();
        if rng.random_bool(self.block.probability) {
            let other = rng.random_bool(0.5);
            steps.push(Degradation::Block(match kind {
                MapKind::BaseColor if other => BlockFormat::Bc3,
                MapKind::BaseColor => BlockFormat::Bc1,
                MapKind::Normal if other => BlockFormat::Bc1,
                MapKind::Normal => BlockFormat::Bc5,
                _ if other => BlockFormat::Bc1,
                _ => BlockFormat::Bc4,
            }));
        }
        if rng.random_bool(self.jpeg.probability) {
            let [q0, q1] = self.jpeg.quality;
            steps.push(Degradation::Jpeg {
                quality: rng.random_range(q0..=q1),
                subsampling: if rng.random_bool(self.jpeg.full_chroma_share) {
                    Subsampling::Full
                } else {
                    Subsampling::Half
                },
            });
        }
        if rng.random_bool(self.dither.probability) {
            let [l0, l1] = self.dither.levels;
            steps.push(Degradation::Dither {
                levels: rng.random_range(l0..=l1),
                method: if rng.random_bool(self.dither.diffusion_share) {
                    DitherMethod::ErrorDiffusion
                } else {
                    DitherMethod::Ordered
                },
            });
        }
        if rng.random_bool(self.noise.probability) {
            let sigma = uniform(rng, self.noise.sigma);
            steps.push(if rng.random_bool(self.noise.poisson_share) {
                // Shot noise of standard deviation `sigma` levels at mid-grey:
                // sqrt(0.5 / peak) · 255 = sigma.
                Degradation::PoissonNoise {
                    peak: 0.5 * (255.0 / sigma).powi(2),
                }
            } else {
                Degradation::GaussianNoise { sigma }
            });
        }
        if rng.random_bool(self.blur.probability) {
            steps.push(Degradation::Blur {
                sigma: uniform(rng, self.blur.sigma),
            });
        }
        if rng.random_bool(self.halo.probability) {
            steps.push(Degradation::Halo {
                sigma: uniform(rng, self.halo.sigma),
                amount: uniform(rng, self.halo.amount),
            });
        }
        steps.shuffle(rng);
        steps
    }
}

fn yes() -> bool {
    true
}

fn uniform(rng: &mut impl Rng, [a, b]: [f32; 2]) -> f32 {
    if a == b {
        a
    } else {
        rng.random_range(a..=b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::SeedableRng;

    fn mix() -> Degradations {
        toml::from_str(
            r#"
            clean_share = 0.25
            block = { probability = 0.4 }
            jpeg = { probability = 0.5, quality = [40, 95] }
            noise = { probability = 0.3, sigma = [2, 4] }
            blur = { probability = 0.2 }
            halo = { probability = 0.1 }
            dither = { probability = 0.1 }
            "#,
        )
        .unwrap()
    }

    #[test]
    fn each_is_drawn_as_often_as_its_probability_says() {
        let mix = mix();
        mix.validate().unwrap();
        let mut rng = StdRng::seed_from_u64(3);
        let draws = 4000;
        let (mut block, mut jpeg, mut noise, mut orders) = (0, 0, 0, [0usize; 2]);
        for _ in 0..draws {
            let steps = mix.draw(MapKind::Normal, &mut rng);
            for (i, step) in steps.iter().enumerate() {
                match step {
                    Degradation::Block(f) => {
                        block += 1;
                        assert!(matches!(f, BlockFormat::Bc5 | BlockFormat::Bc1), "{f:?}");
                    }
                    Degradation::Jpeg { quality, .. } => {
                        jpeg += 1;
                        assert!((40..=95).contains(quality));
                        if steps.len() == 2 {
                            orders[i] += 1;
                        }
                    }
                    Degradation::GaussianNoise { sigma } => {
                        noise += 1;
                        assert!((2.0..=4.0).contains(sigma));
                    }
                    Degradation::PoissonNoise { peak } => {
                        noise += 1;
                        let sigma = 255.0 * (0.5 / peak).sqrt();
                        assert!((1.99..=4.01).contains(&sigma), "{sigma}");
                    }
                    _ => {}
                }
            }
        }
        let share = |n: usize| n as f64 / draws as f64;
        assert!((share(block) - 0.4).abs() < 0.03, "block {}", share(block));
        assert!((share(jpeg) - 0.5).abs() < 0.03, "jpeg {}", share(jpeg));
        assert!((share(noise) - 0.3).abs() < 0.03, "noise {}", share(noise));
        // In any order: JPEG comes first about as often as second.
        let first = orders[0] as f64 / (orders[0] + orders[1]) as f64;
        assert!(
            (0.4..0.6).contains(&first),
            "JPEG first in {first} of pairs"
        );
    }

    #[test]
    fn a_share_of_crops_stays_clean_and_the_rest_is_degraded() {
        let mix = mix();
        let material = Material::uniform(16, [0.5; 3], 0.5, 0.0);
        let mut rng = StdRng::seed_from_u64(5);
        let (mut clean, mut unchanged) = (0, 0);
        for _ in 0..400 {
            let (out, degraded) = mix.apply(&material, &mut rng).unwrap();
            clean += !degraded as usize;
            unchanged += (out == material) as usize;
            assert!(degraded || out == material);
        }
        assert!(unchanged >= clean);
        // Clean: the share kept (100 of 400), and the few crops where no map drew anything.
        assert!((75..=130).contains(&clean), "{clean} of 400 clean");
    }

    #[test]
    fn the_drawn_degradations_are_named_and_no_others() {
        assert_eq!(
            mix().drawn(),
            [
                "block compression",
                "JPEG",
                "dithering",
                "noise",
                "blur",
                "halos"
            ]
        );
        let jpeg_alone: Degradations =
            toml::from_str("clean_share = 0.1\njpeg = { probability = 1.0 }").unwrap();
        assert_eq!(jpeg_alone.drawn(), ["JPEG"]);
    }

    #[test]
    fn bad_settings_are_named() {
        let mut mix = mix();
        mix.jpeg.quality = [90, 40];
        assert!(mix.validate().unwrap_err().contains("jpeg.quality"));
        let mut mix = self::mix();
        mix.noise.probability = 1.5;
        assert!(mix.validate().unwrap_err().contains("noise.probability"));
    }
}
