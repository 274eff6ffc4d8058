//! Faithful colour: the defaults add no hue the input lacks.

mod common;

use matup::color::{linear_to_srgb, to_u8};
use matup::config::Config;
use matup::eval::metrics::false_colour;
use matup::material::Material;
use matup::progress::Silent;
use matup::{Map, RunOptions};

/// Texel `i` of a linear colour map as stored 8-bit sRGB.
fn stored(m: &Map, i: usize) -> [i32; 3] {
    [0, 1, 2].map(|c| to_u8(linear_to_srgb(m.plane(c)[i])) as i32)
}

/// Magenta as an artist sees it: red and blue both more than 40 levels above green.
fn magenta(rgb: [i32; 3]) -> bool {
    rgb[0] - rgb[1] > 40 && rgb[2] - rgb[1] > 40
}

/// Output texels (×`scale`) that are magenta where no input texel of their 3×3 neighbourhood
/// is.
fn new_magenta(lr: &Map, hr: &Map, scale: usize) -> usize {
    let (lw, lh) = (lr.width() as isize, lr.height() as isize);
    let input_has = |y: isize, x: isize| {
        (0..9).any(|k| {
            let (yy, xx) = (
                (y + k / 3 - 1).clamp(0, lh - 1),
                (x + k % 3 - 1).clamp(0, lw - 1),
            );
            magenta(stored(lr, (yy * lw + xx) as usize))
        })
    };
    (0..hr.texels())
        .filter(|&i| magenta(stored(hr, i)))
        .filter(|&i| {
            let (y, x) = (i / hr.width() / scale, (i % hr.width()) / scale);
            !input_has(y as isize, x as isize)
        })
        .count()
}

fn upscale(lr: &Material, config: &Config) -> Material {
    matup::upscale(lr, config, &RunOptions::default(), &Silent)
        .unwrap()
        .0
}

#[test]
fn the_samples_output_has_no_magenta_the_input_lacks() {
    let lr = matup::load_material(Some(&common::sample_material()), &Default::default()).unwrap();
    let (defaults, report) =
        matup::upscale(&lr, &Config::default(), &RunOptions::default(), &Silent).unwrap();
    let found = new_magenta(&lr.base_color, &defaults.base_color, 4);
    let border = matup::Border::for_tiling(report.tileable);
    let fc = false_colour(&lr.base_color, &defaults.base_color, None, border).unwrap();
    println!(
        "defaults: {found} new magenta texels, {} of false colour",
        fc.false_colour_texels
    );
    assert_eq!(found, 0);
    assert_eq!(fc.false_colour_texels, 0.0);

    // Without the chroma clamp the network tints the rope's grooves: the test can fail.
    let mut unclamped = Config::default();
    unclamped.filter.clamp_chroma = false;
    let tinted = upscale(&lr, &unclamped);
    let found = new_magenta(&lr.base_color, &tinted.base_color, 4);
    println!("without the clamp: {found} new magenta texels");
    assert!(found > 0);
}
