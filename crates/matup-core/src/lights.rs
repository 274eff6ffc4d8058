//! Point-light sets: the Fibonacci training set of METHOD.md and a Hammersley held-out set.

use glam::Vec3;

/// A point light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    pub position: [f32; 3],
    pub intensity: f32,
    /// Divide the intensity by the squared distance (off by default, as in METHOD.md).
    pub falloff: bool,
}

/// What a shading model needs of a light at one shading point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightSample {
    /// Unit vector from the shading point towards the light.
    pub direction: [f32; 3],
    /// Intensity arriving at the point (after falloff, if any).
    pub intensity: f32,
}

impl Light {
    /// The light as seen from a shading point.
    #[inline]
    pub fn sample_at(&self, point: [f32; 3]) -> LightSample {
        let d = Vec3::from(self.position) - Vec3::from(point);
        let dist2 = d.length_squared().max(1e-20);
        LightSample {
            direction: (d * dist2.sqrt().recip()).to_array(),
            intensity: if self.falloff {
                self.intensity / dist2
            } else {
                self.intensity
            },
        }
    }
}

/// How the light directions are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LightPattern {
    /// Upper half of a spherical Fibonacci grid of twice as many points (the training set).
    #[default]
    Fibonacci,
    /// A Hammersley point set on the hemisphere (a held-out set, disjoint in direction).
    Hammersley,
}

/// Parameters of a light set. The defaults are METHOD.md's training set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightSetSpec {
    pub pattern: LightPattern,
    pub count: usize,
    pub distance: f32,
    pub intensity: f32,
    pub falloff: bool,
}

impl Default for LightSetSpec {
    fn default() -> Self {
        LightSetSpec {
            pattern: LightPattern::Fibonacci,
            count: 100,
            distance: 1.4,
            intensity: 8.0,
            falloff: false,
        }
    }
}

/// Directions below this elevation are lifted (z → √z) so no light grazes the surface.
const LOW_ELEVATION: f32 = 0.1;

impl LightSetSpec {
    /// The held-out evaluation set: same distance and intensity, Hammersley directions.
    pub fn held_out(count: usize) -> Self {
        LightSetSpec {
            pattern: LightPattern::Hammersley,
            count,
            ..Self::default()
        }
    }

    /// The lights, in a fixed order.
    pub fn build(&self) -> Vec<Light> {
        let directions = match self.pattern {
            LightPattern::Fibonacci => fibonacci_hemisphere(self.count),
            LightPattern::Hammersley => hammersley_hemisphere(self.count),
        };
        directions
            .into_iter()
            .map(|d| self.light_towards(d))
            .collect()
    }

    /// A light of this set's distance and intensity in the unit direction `d` of the upper
    /// hemisphere (lifted if it grazes the surface, as in the set): for light sets of one's own,
    /// random ones in training say.
    pub fn light_towards(&self, d: [f32; 3]) -> Light {
        let d = lift_low_elevation(d);
        Light {
            position: d.map(|v| v * self.distance),
            intensity: self.intensity,
            falloff: self.falloff,
        }
    }
}

/// The points with z > 0 of a spherical Fibonacci grid of `2 * count` points
/// (Swinbank & Purser 2006): exactly `count` points, since the grid is symmetric in z.
fn fibonacci_hemisphere(count: usize) -> Vec<[f32; 3]> {
    let n = 2 * count;
    let golden = (1.0 + 5f64.sqrt()) / 2.0;
    (0..n)
        .filter_map(|i| {
            let z = (2 * i + 1) as f64 / n as f64 - 1.0;
            (z > 0.0).then(|| {
                let r = (1.0 - z * z).sqrt();
                let phi = 2.0 * std::f64::consts::PI * i as f64 / golden;
                [(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]
            })
        })
        .collect()
}

/// `count` Hammersley points mapped uniformly (in solid angle) onto the upper hemisphere.
fn hammersley_hemisphere(count: usize) -> Vec<[f32; 3]> {
    (0..count)
        .map(|i| {
            let z = 1.0 - (i as f64 + 0.5) / count as f64;
            let phi = 2.0 * std::f64::consts::PI * radical_inverse_base2(i as u32);
            let r = (1.0 - z * z).max(0.0).sqrt();
            [(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]
        })
        .collect()
}

fn radical_inverse_base2(i: u32) -> f64 {
    i.reverse_bits() as f64 / 4_294_967_296.0
}

fn lift_low_elevation(d: [f32; 3]) -> [f32; 3] {
    if d[2] >= LOW_ELEVATION {
        return d;
    }
    Vec3::new(d[0], d[1], d[2].max(0.0).sqrt())
        .normalize()
        .to_array()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn training_set_matches_method() {
        let lights = LightSetSpec::default().build();
        assert_eq!(lights.len(), 100);
        for l in &lights {
            let r = l.position.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!((r - 1.4).abs() < 1e-5);
            // The lowest grid point (z = 1/200) is lifted to about √0.005 ≈ 0.07.
            assert!(l.position[2] / 1.4 > 0.07, "low lights are lifted");
            assert_eq!(l.intensity, 8.0);
        }
    }

    #[test]
    fn held_out_set_differs_from_training_set() {
        let train = LightSetSpec::default().build();
        let test = LightSetSpec::held_out(64).build();
        assert_eq!(test.len(), 64);
        let closest = test
            .iter()
            .map(|a| {
                train
                    .iter()
                    .map(|b| {
                        (0..3)
                            .map(|k| (a.position[k] - b.position[k]).powi(2))
                            .sum::<f32>()
                    })
                    .fold(f32::MAX, f32::min)
            })
            .fold(f32::MAX, f32::min);
        assert!(
            closest > 1e-6,
            "no held-out light coincides with a training light"
        );
    }

    #[test]
    fn falloff_divides_by_squared_distance() {
        let l = Light {
            position: [0.0, 0.0, 2.0],
            intensity: 8.0,
            falloff: true,
        };
        let s = l.sample_at([0.0, 0.0, 0.0]);
        assert!((s.intensity - 2.0).abs() < 1e-6);
        assert_eq!(s.direction, [0.0, 0.0, 1.0]);
    }
}
