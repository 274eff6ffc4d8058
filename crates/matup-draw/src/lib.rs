//! matup's drawing, for the pictures the applications write (`preview.png`, contact sheets,
//! plots): text drawn onto maps with a shipped font, and contact sheets with labels.

pub mod sheet;
pub mod text;

pub use sheet::{contact_sheet, labelled_sheet};
