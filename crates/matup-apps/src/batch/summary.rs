//! A library's state, read back from the output folder: `batch.csv`, `batch.json` and
//! `index.html`. Built from what is on disk rather than from one worker's memory, so that
//! whichever of several workers finishes last writes the whole library's summary.

use std::path::Path;

use serde::Serialize;

use super::claim::{live_claim, ClaimTiming};
use super::library::{material_name, Library};
use super::records::{read_failure, read_result};
use crate::html::{escape, href};
use matup_core::io::write_atomic;
use matup_core::{Error, Result};

/// Where a material stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Its `run.json` was written with the current settings.
    Done,
    /// Its last attempt with the current settings failed (`error.json`).
    Failed,
    /// A live worker holds its claim.
    Running,
    /// Not started, or last upscaled with other settings.
    Pending,
}

impl Status {
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Done => "done",
            Status::Failed => "failed",
            Status::Running => "running",
            Status::Pending => "pending",
        }
    }
}

/// One material of the summary.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Row {
    pub material: String,
    pub status: Status,
    pub seconds: Option<f64>,
    pub final_loss: Option<f64>,
    /// Work the run skipped because the material could not use it.
    pub skips: Vec<String>,
    pub tileable: Option<bool>,
    pub input_size: Option<[usize; 2]>,
    pub output_size: Option<[usize; 2]>,
    pub error: Option<String>,
    /// Whether the material's folder holds a `view.html` (`matup batch --view`).
    pub view: bool,
}

/// `batch.json`.
#[derive(Serialize)]
struct Summary<'a> {
    library: String,
    materials: &'a [Row],
    skipped_folders: Vec<SkippedFolder>,
}

#[derive(Serialize)]
struct SkippedFolder {
    folder: String,
    reason: String,
}

/// Reads every material's state under `out` for the settings `fingerprints` (one per
/// material of `library`, in order; an error where its files could not be listed).
pub fn summarize(
    library: &Library,
    out: &Path,
    fingerprints: &[std::result::Result<String, String>],
    claims: ClaimTiming,
) -> Vec<Row> {
    library
        .materials
        .iter()
        .zip(fingerprints)
        .map(|(relative, fingerprint)| {
            let folder = out.join(relative);
            let mut row = Row {
                material: material_name(relative),
                status: Status::Pending,
                seconds: None,
                final_loss: None,
                skips: Vec::new(),
                tileable: None,
                input_size: None,
                output_size: None,
                error: None,
                view: false,
            };
            let fingerprint = match fingerprint {
                Ok(f) => f,
                Err(error) => {
                    row.status = Status::Failed;
                    row.error = Some(error.clone());
                    return row;
                }
            };
            if let Some(result) = read_result(&folder, fingerprint) {
                row.status = Status::Done;
                row.seconds = result.total_seconds;
                row.final_loss = result.final_loss;
                row.skips = result.skipped;
                row.tileable = result.tileable;
                row.input_size = result.input_size;
                row.output_size = result.output_size;
                row.view = folder.join("view.html").is_file();
            } else if live_claim(&folder, claims).is_some() {
                row.status = Status::Running;
            } else if let Some(failure) = read_failure(&folder, fingerprint) {
                row.status = Status::Failed;
                row.error = Some(failure.error);
            }
            row
        })
        .collect()
}

/// Writes `batch.csv`, `batch.json` and `index.html` into `out`, each atomically.
pub fn write_summary(library: &Library, out: &Path, rows: &[Row]) -> Result<()> {
    let summary = Summary {
        library: library.root.display().to_string(),
        materials: rows,
        skipped_folders: library
            .skipped
            .iter()
            .map(|(folder, reason)| SkippedFolder {
                folder: material_name(folder),
                reason: reason.clone(),
            })
            .collect(),
    };
    let json = serde_json::to_vec_pretty(&summary).expect("the summary serialises");
    write_atomic(&out.join("batch.json"), &json)?;
    write_atomic(&out.join("batch.csv"), &csv(rows)?)?;
    write_atomic(&out.join("index.html"), html(&summary).as_bytes())
}

fn csv(rows: &[Row]) -> Result<Vec<u8>> {
    let csv_error = |e: csv::Error| Error::Invalid(format!("batch.csv: {e}"));
    let mut csv = csv::Writer::from_writer(Vec::new());
    csv.write_record([
        "material",
        "status",
        "seconds",
        "final_loss",
        "skips",
        "tileable",
        "error",
    ])
    .map_err(csv_error)?;
    for r in rows {
        csv.write_record([
            r.material.clone(),
            r.status.as_str().to_string(),
            r.seconds.map_or(String::new(), |s| format!("{s:.3}")),
            r.final_loss.map_or(String::new(), |l| format!("{l:.6}")),
            r.skips.join("; "),
            r.tileable.map_or(String::new(), |t| t.to_string()),
            r.error.clone().unwrap_or_default(),
        ])
        .map_err(csv_error)?;
    }
    csv.into_inner()
        .map_err(|e| Error::Invalid(format!("batch.csv: {e}")))
}

/// The page: a table of every material with its preview and numbers, sortable by clicking a
/// column (a few lines of inline script), opening from the file system: no server, no
/// network.
fn html(summary: &Summary) -> String {
    let count = |s: Status| summary.materials.iter().filter(|r| r.status == s).count();
    let mut rows = String::new();
    for r in summary.materials {
        let number = |v: Option<f64>, digits: usize| {
            v.map_or((String::new(), String::new()), |v| {
                (format!("{v}"), format!("{v:.digits$}"))
            })
        };
        let (seconds_key, seconds) = number(r.seconds, 1);
        let (loss_key, loss) = number(r.final_loss, 5);
        let preview = if r.status == Status::Done {
            let src = escape(&href(&r.material, "preview.png"));
            format!(r#"<a href="{src}"><img src="{src}" loading="lazy" alt=""></a>"#)
        } else {
            String::new()
        };
        let size = match (r.input_size, r.output_size) {
            (Some(i), Some(o)) => format!("{}×{} → {}×{}", i[0], i[1], o[0], o[1]),
            _ => String::new(),
        };
        rows.push_str(&format!(
            concat!(
                "<tr class=\"{status}\"><td>{preview}</td>",
                "<td><a href=\"{folder}\">{name}</a>{view}</td><td>{status}</td><td>{size}</td>",
                "<td data-sort=\"{seconds_key}\">{seconds}</td>",
                "<td data-sort=\"{loss_key}\">{loss}</td><td>{tileable}</td>",
                "<td>{skips}</td><td>{error}</td></tr>\n"
            ),
            status = r.status.as_str(),
            preview = preview,
            folder = escape(&href(&r.material, "")),
            name = escape(&r.material),
            view = if r.view {
                format!(
                    r#" (<a href="{}">relight</a>)"#,
                    escape(&href(&r.material, "view.html"))
                )
            } else {
                String::new()
            },
            size = size,
            seconds_key = seconds_key,
            seconds = seconds,
            loss_key = loss_key,
            loss = loss,
            tileable = r.tileable.map_or("", |t| if t { "yes" } else { "no" }),
            skips = escape(&r.skips.join("; ")),
            error = escape(r.error.as_deref().unwrap_or("")),
        ));
    }
    let skipped: String = summary
        .skipped_folders
        .iter()
        .map(|s| {
            format!(
                "<li><code>{}</code>: {}</li>\n",
                escape(&s.folder),
                escape(&s.reason)
            )
        })
        .collect();
    let skipped = if skipped.is_empty() {
        String::new()
    } else {
        format!("<h2>Folders without a material</h2>\n<ul>\n{skipped}</ul>\n")
    };
    format!(
        r##"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>matup batch: {library}</title>
<style>
body {{ font: 14px system-ui, sans-serif; margin: 1.5em; }}
table {{ border-collapse: collapse; }}
th, td {{ border-bottom: 1px solid #ddd; padding: 4px 8px; text-align: left; vertical-align: middle; }}
th {{ cursor: pointer; background: #f4f4f4; position: sticky; top: 0; }}
th:after {{ content: " ⇅"; color: #aaa; }}
img {{ height: 96px; image-rendering: pixelated; }}
tr.failed td {{ background: #fde8e8; }}
tr.running td, tr.pending td {{ color: #777; }}
</style></head><body>
<h1>matup batch</h1>
<p>Library <code>{library}</code>: {done} done, {failed} failed, {running} running, {pending} pending. Each preview shows bilinear on the left and matup on the right, under two lights. Click a column to sort.</p>
<table id="materials"><thead><tr><th>preview</th><th>material</th><th>status</th><th>size</th><th>seconds</th><th>final loss</th><th>tileable</th><th>skips</th><th>error</th></tr></thead>
<tbody>
{rows}</tbody></table>
{skipped}<script>
// Sort by a column: numbers by value (from data-sort when present), text otherwise.
document.querySelectorAll("#materials th").forEach((th, column) => {{
  let ascending = true;
  th.addEventListener("click", () => {{
    const body = document.querySelector("#materials tbody");
    const key = row => {{
      const cell = row.children[column];
      return cell.dataset.sort !== undefined ? cell.dataset.sort : cell.textContent;
    }};
    const rows = Array.from(body.rows);
    rows.sort((a, b) => {{
      const [x, y] = [key(a), key(b)];
      const [nx, ny] = [parseFloat(x), parseFloat(y)];
      const order = !isNaN(nx) && !isNaN(ny) ? nx - ny
        : isNaN(nx) !== isNaN(ny) ? (isNaN(nx) ? 1 : -1)
        : x.localeCompare(y);
      return ascending ? order : -order;
    }});
    ascending = !ascending;
    rows.forEach(row => body.appendChild(row));
  }});
}});
</script>
</body></html>
"##,
        library = escape(&summary.library),
        done = count(Status::Done),
        failed = count(Status::Failed),
        running = count(Status::Running),
        pending = count(Status::Pending),
        rows = rows,
        skipped = skipped,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn links_and_text_are_escaped() {
        assert_eq!(
            href("wood/oak 2", "preview.png"),
            "./wood/oak%202/preview.png"
        );
        assert_eq!(href(".", "preview.png"), "./preview.png");
        assert_eq!(href("a#b", ""), "./a%23b/");
        assert_eq!(escape("<a & 'b'>"), "&lt;a &amp; &#39;b&#39;&gt;");
    }
}
