//! `callable`: a network the caller runs itself, as a function from tiles to tiles (a PyTorch
//! module through the Python package, or any Rust closure). matup does everything around it:
//! the tiles with their context (wrapped for tileable materials), the batches, the feathered
//! blend ([`crate::tiled`]), and the method's own stages before and after.
//!
//! A function is registered at run time under a name ([`register`]) and named like any other
//! upsampler, `callable:NAME`, so every path that takes an upsampler spec (the pipeline,
//! `--select`, benchmarks) reaches it. The registration lasts as long as its guard.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use matup_core::resample::Border;
use matup_core::upsample::{RgbUpsampler, Unwatched, UpsamplerRegistration, Watch};
use matup_core::{Error, Map, Result};

use crate::tiled::{by_size, upsample_tiled, TileAxis, Tiling};

/// Runs the network on a batch of tiles: each tile three planes (R, G, B) of `h × w` texels in
/// [0, 1], row by row; returns each tile upsampled, as a 3-channel [`Map`].
pub type TileFunction = dyn Fn(&[Vec<f32>], [usize; 2]) -> Result<Vec<Map>> + Send + Sync;

/// How a function's tiles are cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FunctionTiles {
    /// The factor the function upsamples by.
    pub scale: usize,
    /// Tiles' side at most, in input texels (before context).
    pub tile: usize,
    /// Input texels of context read on every side of a tile: the network's receptive field.
    pub overlap: usize,
    /// Tiles handed over a call at most.
    pub batch: usize,
}

impl FunctionTiles {
    /// Tiles of 256 texels with 16 of context, 4 a call: SR networks' receptive fields reach
    /// about that far (SPAN's 21 texels), and a GPU's batch fills.
    pub fn at_scale(scale: usize) -> FunctionTiles {
        FunctionTiles {
            scale,
            tile: 256,
            overlap: 16,
            batch: 4,
        }
    }
}

/// An upsampler made of a [`TileFunction`].
pub struct FunctionUpsampler {
    name: String,
    tiles: FunctionTiles,
    run: Box<TileFunction>,
}

impl FunctionUpsampler {
    /// `run` upsampling ×`tiles.scale`, in tiles as `tiles` says; `name` is how errors and
    /// reports call it.
    pub fn new(
        name: impl Into<String>,
        tiles: FunctionTiles,
        run: Box<TileFunction>,
    ) -> Result<FunctionUpsampler> {
        let name = name.into();
        if tiles.scale == 0 || tiles.tile == 0 || tiles.batch == 0 {
            return Err(Error::Plugin {
                plugin: format!("callable:{name}"),
                message: format!(
                    "scale, tile and batch must be positive (scale {}, tile {}, batch {})",
                    tiles.scale, tiles.tile, tiles.batch
                ),
            });
        }
        Ok(FunctionUpsampler { name, tiles, run })
    }

    fn error(&self, message: String) -> Error {
        Error::Invalid(format!("callable:{}: {message}", self.name))
    }

    /// One call: the function's outputs, checked to be one `3 × s·h × s·w` map a tile.
    fn call(&self, tiles: &[Vec<f32>], h: usize, w: usize) -> Result<Vec<Map>> {
        let s = self.tiles.scale;
        let out = (self.run)(tiles, [h, w])?;
        let want = [w * s, h * s];
        let wrong = (out.iter()).find(|m| [m.width(), m.height()] != want || m.channels() != 3);
        if out.len() != tiles.len() || wrong.is_some() {
            let got = match wrong {
                Some(m) => format!("a {}×{}×{} image", m.height(), m.width(), m.channels()),
                None => format!("{} images", out.len()),
            };
            return Err(self.error(format!(
                "given {} tiles of {h}×{w}×3, it returned {got}; want {} of {}×{}×3 (×{s})",
                tiles.len(),
                tiles.len(),
                want[1],
                want[0]
            )));
        }
        Ok(out)
    }
}

impl RgbUpsampler for FunctionUpsampler {
    fn native_scale(&self) -> Option<usize> {
        Some(self.tiles.scale)
    }

    fn context(&self) -> usize {
        self.tiles.overlap
    }

    fn tile(&self) -> Option<usize> {
        Some(self.tiles.tile)
    }

    /// The self-ensemble's passes come together: their tiles fill the function's batches.
    fn batches_images(&self) -> bool {
        true
    }

    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        self.upsample_watched(images, scale, border, &Unwatched)
    }

    /// [`RgbUpsampler::upsample`], `watch` told after each call of the function.
    fn upsample_watched(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
        watch: &dyn Watch,
    ) -> Result<Vec<Map>> {
        let t = self.tiles;
        if scale != t.scale {
            return Err(Error::Unsupported {
                plugin: format!("callable:{}", self.name),
                what: format!("scale ×{scale} (it upsamples ×{})", t.scale),
            });
        }
        by_size(images, |same| {
            let (w, h) = (images[same[0]].width(), images[same[0]].height());
            let axes = [h, w].map(|len| TileAxis::even(len, t.tile, t.overlap));
            let tiling = Tiling::new([w, h], same.len(), axes, t.overlap, t.scale);
            let same_images: Vec<&Map> = same.iter().map(|&k| &images[k]).collect();
            upsample_tiled(
                &same_images,
                border,
                tiling,
                t.batch,
                false,
                &mut |tiles, [h, w]| self.call(tiles, h, w),
                watch,
            )
        })
    }
}

/// The functions registered now, by name.
static REGISTERED: Mutex<Option<HashMap<String, Arc<FunctionUpsampler>>>> = Mutex::new(None);

/// Keeps a function registered; dropping it removes the registration.
#[must_use = "the function is registered only while the guard lives"]
pub struct Registered {
    name: String,
}

impl Registered {
    /// The spec that names the function: `callable:NAME`.
    pub fn spec(&self) -> String {
        format!("callable:{}", self.name)
    }
}

impl Drop for Registered {
    fn drop(&mut self) {
        let mut registered = REGISTERED.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(map) = registered.as_mut() {
            map.remove(&self.name);
        }
    }
}

/// Registers `upsampler` under its name, so that `callable:NAME` builds it; an error if the
/// name is taken.
pub fn register(upsampler: FunctionUpsampler) -> Result<Registered> {
    let name = upsampler.name.clone();
    if name.is_empty() || name.contains([',', ':']) {
        return Err(Error::Invalid(format!(
            "'{name}' cannot name a callable upsampler (empty, or holds ',' or ':')"
        )));
    }
    let mut registered = REGISTERED.lock().unwrap_or_else(|p| p.into_inner());
    let map = registered.get_or_insert_with(HashMap::new);
    if map.contains_key(&name) {
        return Err(Error::Invalid(format!(
            "a callable upsampler named '{name}' is registered already"
        )));
    }
    map.insert(name.clone(), Arc::new(upsampler));
    Ok(Registered { name })
}

/// A registered function, shared by every run that names it.
struct Shared(Arc<FunctionUpsampler>);

impl RgbUpsampler for Shared {
    fn native_scale(&self) -> Option<usize> {
        self.0.native_scale()
    }
    fn context(&self) -> usize {
        self.0.context()
    }
    fn tile(&self) -> Option<usize> {
        self.0.tile()
    }
    fn batches_images(&self) -> bool {
        self.0.batches_images()
    }
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        self.0.upsample(images, scale, border)
    }
    fn upsample_watched(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
        watch: &dyn Watch,
    ) -> Result<Vec<Map>> {
        self.0.upsample_watched(images, scale, border, watch)
    }
}

fn create(argument: Option<&str>) -> Result<Box<dyn RgbUpsampler>> {
    let name = argument.unwrap_or("");
    let registered = REGISTERED.lock().unwrap_or_else(|p| p.into_inner());
    let found = (registered.as_ref()).and_then(|map| map.get(name));
    match found {
        Some(upsampler) => Ok(Box::new(Shared(upsampler.clone()))),
        None => {
            let mut known: Vec<&String> = registered.iter().flat_map(|m| m.keys()).collect();
            known.sort();
            Err(Error::Plugin {
                plugin: "callable".into(),
                message: format!(
                    "no function is registered as '{name}' (registered now: {}); the Python \
                     package registers one for each upsampler= it is given",
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known
                            .iter()
                            .map(|k| k.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    }
                ),
            })
        }
    }
}

inventory::submit! {
    UpsamplerRegistration {
        name: "callable",
        description: "a function registered at run time, such as a Python callable given to the \
                      matup package as upsampler=; matup tiles, blends and back-projects around it",
        options: &[],
        create,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use matup_core::resample::{box_downsample, upsample, Kernel};

    /// Bicubic ×2 of each tile, as a function of tiles.
    fn bicubic_tiles(tiles: &[Vec<f32>], [h, w]: [usize; 2]) -> Result<Vec<Map>> {
        Ok((tiles.iter())
            .map(|t| {
                let tile = Map::from_planar(w, h, 3, t.clone());
                upsample(&tile, 2, Kernel::Bicubic { a: -0.5 }, Border::Clamp)
            })
            .collect())
    }

    fn image() -> Map {
        Map::from_fn(50, 37, 3, |c, y, x| {
            (((x * 7 + y * 3 + c * 5) % 11) as f32 / 10.0 + (x as f32 * 0.2).sin() * 0.1)
                .clamp(0.0, 1.0)
        })
    }

    #[test]
    fn tiles_with_enough_context_give_the_whole_image_output() {
        // Bicubic reads 2 texels around: with 4 of context, 16-texel tiles blend to exactly
        // the whole image's bicubic, wrapped for a tileable image.
        let tiles = FunctionTiles {
            scale: 2,
            tile: 16,
            overlap: 4,
            batch: 3,
        };
        let up = FunctionUpsampler::new("bicubic", tiles, Box::new(bicubic_tiles)).unwrap();
        let image = image();
        for border in [Border::Wrap, Border::Mirror] {
            let got = up
                .upsample(std::slice::from_ref(&image), 2, border)
                .unwrap();
            let whole = upsample(&image, 2, Kernel::Bicubic { a: -0.5 }, border);
            let worst = (got[0].data().iter().zip(whole.data()))
                .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(worst < 1e-5, "{border:?}: off by {worst}");
        }
        // ×1 is not its scale.
        assert!(up.upsample(&[image], 1, Border::Wrap).is_err());
    }

    #[test]
    fn a_function_is_named_by_its_registration_and_checked_call_by_call() {
        let tiles = FunctionTiles::at_scale(2);
        let guard = register(
            FunctionUpsampler::new("test-bicubic", tiles, Box::new(bicubic_tiles)).unwrap(),
        )
        .unwrap();
        assert_eq!(guard.spec(), "callable:test-bicubic");
        let up = matup_core::upsampler(&guard.spec().parse().unwrap()).unwrap();
        let out = up.upsample(&[image()], 2, Border::Wrap).unwrap();
        let back = box_downsample(&out[0], 2);
        assert_eq!((out[0].width(), out[0].height()), (100, 74));
        assert!(back.data().iter().all(|v| v.is_finite()));
        // The name is taken while the guard lives, and free once it is dropped.
        let again = FunctionUpsampler::new("test-bicubic", tiles, Box::new(bicubic_tiles));
        assert!(register(again.unwrap()).is_err());
        drop(guard);
        let e = matup_core::upsampler(&"callable:test-bicubic".parse().unwrap());
        assert!(e.err().unwrap().to_string().contains("no function"));

        // A function that returns the wrong size is refused with what it returned: one tile
        // of the 50×37 image with 16 texels of context around it.
        let half = |tiles: &[Vec<f32>], [h, w]: [usize; 2]| -> Result<Vec<Map>> {
            Ok(vec![Map::filled(w, h, 3, 0.0); tiles.len()])
        };
        let wrong = FunctionUpsampler::new("wrong", tiles, Box::new(half)).unwrap();
        let e = wrong.upsample(&[image()], 2, Border::Wrap).unwrap_err();
        assert!(e.to_string().contains("it returned a 69×82×3 image"), "{e}");
    }
}
