//! Contact sheets: images laid out on a grid, optionally labelled (the preview, `matup render`).

use crate::text::{draw_text, text_width};
use matup_core::map::Map;

/// Lays images out on a grid, `columns` wide, with a `gap`-texel dark border between them.
pub fn contact_sheet(images: &[Map], columns: usize, gap: usize) -> Map {
    assert!(!images.is_empty() && columns > 0);
    let (w, h) = (images[0].width(), images[0].height());
    let rows = images.len().div_ceil(columns);
    let (sw, sh) = (columns * (w + gap) + gap, rows * (h + gap) + gap);
    let mut sheet = Map::filled(sw, sh, 3, 0.1);
    for (k, image) in images.iter().enumerate() {
        let (x0, y0) = (
            gap + (k % columns) * (w + gap),
            gap + (k / columns) * (h + gap),
        );
        for c in 0..3 {
            for y in 0..h {
                for x in 0..w {
                    sheet.set(
                        c,
                        y0 + y,
                        x0 + x,
                        image.get(c.min(image.channels() - 1), y, x),
                    );
                }
            }
        }
    }
    sheet
}

/// A contact sheet with a label over each column and a caption over each row, in light grey
/// on the sheet's dark background (`gap` texels between images, as [`contact_sheet`]).
pub fn labelled_sheet(
    images: &[Map],
    columns: usize,
    gap: usize,
    column_labels: &[String],
    row_captions: &[String],
) -> Map {
    const TEXT: f32 = 14.0;
    const STRIP: usize = 20;
    const INK: [f32; 3] = [0.85, 0.85, 0.85];
    let (w, h) = (images[0].width(), images[0].height());
    let rows = images.len().div_ceil(columns);
    let sheet = contact_sheet(images, columns, gap);
    let mut out = Map::filled(sheet.width(), sheet.height() + STRIP * (rows + 1), 3, 0.1);
    for (column, label) in column_labels.iter().enumerate().take(columns) {
        let centre = (gap + column * (w + gap)) as f32 + w as f32 / 2.0;
        let x = (centre - text_width(TEXT, label) / 2.0).max(gap as f32);
        draw_text(&mut out, x, 2.0, TEXT, label, INK);
    }
    for row in 0..rows {
        let top = gap + row * (h + gap); // the row's first line in `sheet`
        let shift = STRIP * (row + 2); // its header strip and caption strips above it
        if let Some(caption) = row_captions.get(row) {
            draw_text(
                &mut out,
                gap as f32,
                (top + shift - STRIP + 2) as f32,
                TEXT,
                caption,
                INK,
            );
        }
        for y in top..(top + h + gap).min(sheet.height()) {
            for c in 0..3 {
                for x in 0..sheet.width() {
                    out.set(c, y + shift, x, sheet.get(c, y, x));
                }
            }
        }
    }
    out
}
