//! Text drawn into images (the preview's labels), in a font shipped with matup so that a
//! machine without fonts draws the same. ab_glyph rasterises the glyphs; the layout is one
//! line, left to right, with the font's kerning.

use ab_glyph::{Font, FontRef, PxScale, ScaleFont};

use matup_core::map::Map;

/// DejaVu Sans (its licence beside it in `assets/`), also the plots' font.
pub static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// Draws `text` into the RGB `image` with its top-left corner at (`x`, `y`), `size` pixels
/// high, blending `color` by the glyphs' coverage. What falls outside the image is clipped.
pub fn draw_text(image: &mut Map, x: f32, y: f32, size: f32, text: &str, color: [f32; 3]) {
    let font = FontRef::try_from_slice(FONT).expect("the shipped font parses");
    let scaled = font.as_scaled(PxScale::from(size));
    let mut pen = x;
    let mut previous = None;
    for ch in text.chars() {
        let id = scaled.glyph_id(ch);
        if let Some(p) = previous {
            pen += scaled.kern(p, id);
        }
        let glyph = id.with_scale_and_position(size, ab_glyph::point(pen, y + scaled.ascent()));
        pen += scaled.h_advance(id);
        previous = Some(id);
        let Some(outline) = font.outline_glyph(glyph) else {
            continue; // a space
        };
        let bounds = outline.px_bounds();
        outline.draw(|gx, gy, coverage| {
            let (px, py) = (
                bounds.min.x as i64 + gx as i64,
                bounds.min.y as i64 + gy as i64,
            );
            if px < 0 || py < 0 || px >= image.width() as i64 || py >= image.height() as i64 {
                return;
            }
            let (px, py) = (px as usize, py as usize);
            for (c, &value) in color.iter().enumerate() {
                let old = image.get(c, py, px);
                image.set(c, py, px, old + coverage.min(1.0) * (value - old));
            }
        });
    }
}

/// The width `text` takes at `size` pixels.
pub fn text_width(size: f32, text: &str) -> f32 {
    let font = FontRef::try_from_slice(FONT).expect("the shipped font parses");
    let scaled = font.as_scaled(PxScale::from(size));
    text.chars()
        .map(|c| scaled.h_advance(scaled.glyph_id(c)))
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_drawn_where_asked_and_clipped() {
        let mut image = Map::filled(120, 30, 3, 0.0);
        draw_text(&mut image, 4.0, 4.0, 16.0, "matup", [1.0, 1.0, 1.0]);
        let lit = |x0: usize, x1: usize| {
            (0..30)
                .flat_map(|y| (x0..x1).map(move |x| (y, x)))
                .filter(|&(y, x)| image.get(0, y, x) > 0.5)
                .count()
        };
        let width = text_width(16.0, "matup");
        assert!((35.0..60.0).contains(&width), "{width}");
        assert!(lit(4, 4 + width as usize) > 60, "the glyphs cover pixels");
        assert_eq!(lit(6 + width as usize, 120), 0, "nothing right of the text");
        // Off the image: no panic, nothing drawn.
        draw_text(&mut image, 200.0, -50.0, 16.0, "x", [1.0, 0.0, 0.0]);
    }
}
