//! `matup view`'s page in a real browser: headless Chromium takes screenshots with the light
//! at two places and the split at two places, and the test checks them against matup's own
//! renders. Chromium comes from Debian's `chromium` package (`.ci/run` installs it); where it
//! is missing the test says so and passes, unless MATUP_REQUIRE_BROWSER is set (CI sets it).

use std::path::{Path, PathBuf};
use std::process::Command;

use image::RgbImage;
use matup_core::LightSetSpec;

const CANVAS: u32 = 512;

fn matup(args: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_matup"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "matup {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn chromium() -> Option<PathBuf> {
    let candidates = std::env::var_os("MATUP_CHROMIUM")
        .map(PathBuf::from)
        .into_iter()
        .chain(["/usr/bin/chromium", "/usr/bin/chromium-browser"].map(PathBuf::from));
    let found = candidates.into_iter().find(|p| p.is_file());
    if found.is_none() {
        assert!(
            std::env::var_os("MATUP_REQUIRE_BROWSER").is_none(),
            "MATUP_REQUIRE_BROWSER is set but no Chromium was found (install Debian's chromium)"
        );
        eprintln!("view test skipped: no Chromium (install Debian's chromium package to run it)");
    }
    found
}

/// The page's canvas (its top-left 512² pixels) with the state in `hash`.
fn screenshot(browser: &Path, page: &Path, hash: &str, scratch: &Path) -> RgbImage {
    let shot = scratch.join(format!(
        "shot-{}.png",
        hash.replace(['=', ',', '&', '.'], "_")
    ));
    let profile = tempfile::tempdir().unwrap();
    let url = format!("file://{}#{hash}", page.display());
    let o = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--enable-unsafe-swiftshader",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--force-device-scale-factor=1",
            "--window-size=900,600",
            "--virtual-time-budget=20000",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!("--screenshot={}", shot.display()))
        .arg(&url)
        .output()
        .unwrap();
    assert!(
        shot.is_file(),
        "no screenshot of {url}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let image = image::open(&shot).unwrap().to_rgb8();
    image::imageops::crop_imm(&image, 0, 0, CANVAS, CANVAS).to_image()
}

/// Mean absolute difference (in 8-bit steps) over the columns `columns` of two images.
fn mean_diff(a: &RgbImage, b: &RgbImage, columns: std::ops::Range<u32>) -> f64 {
    let mut total = 0.0;
    let mut count = 0.0;
    for y in 0..a.height() {
        for x in columns.clone() {
            let (p, q) = (a.get_pixel(x, y), b.get_pixel(x, y));
            for c in 0..3 {
                total += (p[c] as f64 - q[c] as f64).abs();
                count += 1.0;
            }
        }
    }
    total / count
}

/// The fraction of values differing by more than `steps`.
fn outliers(a: &RgbImage, b: &RgbImage, steps: i32) -> f64 {
    let n = a.as_raw().len() as f64;
    let bad = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .filter(|(p, q)| (**p as i32 - **q as i32).abs() > steps)
        .count();
    bad as f64 / n
}

#[test]
fn the_page_relights_splits_and_matches_matups_render() {
    let Some(browser) = chromium() else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("wood");
    let sample = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../samples/victorian_wood");
    matup(&[
        "upscale",
        sample.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--view",
        "--quiet",
    ]);
    let page = out.join("view.html");
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(
        !html.contains("http://") && !html.contains("https://"),
        "the page needs no network"
    );

    let lights = LightSetSpec::default().build();
    let mut shots = Vec::new();
    for k in [20, 70] {
        let [x, y, z] = lights[k].position;
        // split=0: the whole canvas shows matup's result, one texel a pixel (512²).
        let shot = screenshot(
            &browser,
            &page,
            &format!("light={x},{y},{z}&split=0"),
            dir.path(),
        );
        let render = dir.path().join(format!("render-{k}.png"));
        matup(&[
            "render",
            out.to_str().unwrap(),
            "-o",
            render.to_str().unwrap(),
            "--light",
            &k.to_string(),
            "--no-supersample",
        ]);
        let render = image::open(&render).unwrap().to_rgb8();
        let diff = mean_diff(&shot, &render, 0..CANVAS);
        let far = outliers(&shot, &render, 2);
        assert!(
            diff < 0.05 && far < 0.001,
            "light {k}: the page differs from matup's render by {diff:.3} steps on average, \
             {:.3}% by more than 2",
            100.0 * far
        );
        shots.push(shot);
    }
    // Moving the light changes the picture everywhere.
    assert!(mean_diff(&shots[0], &shots[1], 0..CANVAS) > 10.0);

    // The split: left of it the bilinear comparison, right of it matup.
    let [x, y, z] = lights[20].position;
    let at = |split: f32| {
        screenshot(
            &browser,
            &page,
            &format!("light={x},{y},{z}&split={split}"),
            dir.path(),
        )
    };
    let (quarter, three_quarters) = (at(0.25), at(0.75));
    let (left, right) = (CANVAS / 4, 3 * CANVAS / 4);
    assert_eq!(mean_diff(&quarter, &three_quarters, 0..left - 1), 0.0);
    assert_eq!(mean_diff(&quarter, &three_quarters, right + 1..CANVAS), 0.0);
    assert_eq!(
        mean_diff(&quarter, &shots[0], left + 1..CANVAS),
        0.0,
        "right of the split is matup's result"
    );
    let band = mean_diff(&quarter, &three_quarters, left + 1..right - 1);
    assert!(
        band > 2.0,
        "bilinear and matup differ between the splits: {band}"
    );

    // Laid 2×2, one texel a pixel, centred where the four copies meet: each quarter of the
    // canvas is the opposite quarter of the single material.
    let tiled = screenshot(
        &browser,
        &page,
        &format!("light={x},{y},{z}&split=0&tiles=2&zoom=1&center=512,512"),
        dir.path(),
    );
    let half = CANVAS / 2;
    let moved = RgbImage::from_fn(CANVAS, CANVAS, |px, py| {
        *shots[0].get_pixel((px + half) % CANVAS, (py + half) % CANVAS)
    });
    let diff = mean_diff(&tiled, &moved, 0..CANVAS);
    assert!(diff < 0.05, "the 2×2 tiling differs by {diff:.3} steps");
}
