//! The `[lights]` settings: the light set the renders are made under.

use serde::{Deserialize, Serialize};

/// The light set the renders are made under.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LightsConfig {
    pub count: usize,
    pub distance: f32,
    pub intensity: f32,
    pub falloff: bool,
}

impl Default for LightsConfig {
    fn default() -> Self {
        LightsConfig {
            count: 100,
            distance: 1.4,
            intensity: 8.0,
            falloff: false,
        }
    }
}

impl LightsConfig {
    /// The training light set these settings describe.
    pub fn build(&self) -> Vec<matup_core::lights::Light> {
        matup_core::lights::LightSetSpec {
            count: self.count,
            distance: self.distance,
            intensity: self.intensity,
            falloff: self.falloff,
            ..Default::default()
        }
        .build()
    }
}
