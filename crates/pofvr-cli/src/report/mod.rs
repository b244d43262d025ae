//! Writing an experiment report: CSV tables, SVG charts, PNG images and an `index.html`
//! that shows them, every file written atomically and listed for the caller.

pub(crate) mod experiment;
pub(crate) mod plot;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

/// A report directory being filled.
pub(crate) struct ReportDir {
    dir: PathBuf,
    files: Vec<String>,
}

impl ReportDir {
    /// Creates `dir` (and parents).
    pub(crate) fn create(dir: &Path) -> Result<Self> {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--out: cannot create {}", dir.display()))?;
        Ok(ReportDir {
            dir: dir.to_path_buf(),
            files: Vec::new(),
        })
    }

    /// The full path of a file in the report.
    pub(crate) fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Every file written so far, by name, in order.
    pub(crate) fn files(&self) -> &[String] {
        &self.files
    }

    /// Writes `bytes` to `name` (temp file + rename) and records it.
    pub(crate) fn write(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        pofvr::io::write_bytes_atomic(&self.path(name), bytes)?;
        self.record(name);
        Ok(())
    }

    /// Records a file written by other means (PNG images).
    pub(crate) fn record(&mut self, name: &str) {
        if !self.files.iter().any(|f| f == name) {
            self.files.push(name.to_string());
        }
    }

    /// Writes a CSV table.
    pub(crate) fn csv(&mut self, name: &str, table: &Csv) -> Result<()> {
        self.write(name, table.text.as_bytes())
    }

    /// Writes pretty JSON.
    pub(crate) fn json(&mut self, name: &str, value: &impl serde::Serialize) -> Result<()> {
        self.write(name, serde_json::to_string_pretty(value)?.as_bytes())
    }
}

/// A CSV table built row by row; cells are numbers or plain identifiers, quoted when needed.
pub(crate) struct Csv {
    text: String,
    columns: usize,
}

/// One CSV cell.
pub(crate) enum Cell {
    /// Text.
    S(String),
    /// An integer.
    I(i64),
    /// A float, written with enough digits to round-trip.
    F(f64),
    /// Not available (written empty).
    Na,
}

impl From<&str> for Cell {
    fn from(s: &str) -> Self {
        Cell::S(s.to_string())
    }
}
impl From<String> for Cell {
    fn from(s: String) -> Self {
        Cell::S(s)
    }
}
impl From<f64> for Cell {
    fn from(v: f64) -> Self {
        Cell::F(v)
    }
}
impl From<usize> for Cell {
    fn from(v: usize) -> Self {
        Cell::I(i64::try_from(v).unwrap_or(i64::MAX))
    }
}
impl From<u64> for Cell {
    fn from(v: u64) -> Self {
        Cell::I(i64::try_from(v).unwrap_or(i64::MAX))
    }
}
impl<T: Into<Cell>> From<Option<T>> for Cell {
    fn from(v: Option<T>) -> Self {
        v.map_or(Cell::Na, Into::into)
    }
}

impl Csv {
    pub(crate) fn new(header: &[&str]) -> Self {
        let mut c = Csv {
            text: String::new(),
            columns: header.len(),
        };
        c.push(header.iter().map(|h| Cell::from(*h)).collect());
        c
    }

    /// Appends a row; it must have as many cells as the header.
    pub(crate) fn push(&mut self, row: Vec<Cell>) {
        debug_assert_eq!(row.len(), self.columns, "CSV row width");
        let cells: Vec<String> = row
            .into_iter()
            .map(|c| match c {
                Cell::S(s) if s.contains([',', '"', '\n']) => {
                    format!("\"{}\"", s.replace('"', "\"\""))
                }
                Cell::S(s) => s,
                Cell::I(i) => i.to_string(),
                Cell::F(f) if f.is_finite() => format!("{f}"),
                Cell::F(_) | Cell::Na => String::new(),
            })
            .collect();
        self.text.push_str(&cells.join(","));
        self.text.push('\n');
    }
}

/// Escapes text for HTML.
pub(crate) fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The HTML page, built section by section.
pub(crate) struct Html {
    body: String,
}

impl Html {
    pub(crate) fn new() -> Self {
        Html {
            body: String::new(),
        }
    }

    pub(crate) fn h2(&mut self, text: &str) {
        let _ = writeln!(self.body, "<h2>{}</h2>", esc(text));
    }

    pub(crate) fn p(&mut self, text: &str) {
        let _ = writeln!(self.body, "<p>{}</p>", esc(text));
    }

    /// A paragraph whose HTML is trusted (built here, with escaped parts).
    pub(crate) fn raw(&mut self, html: &str) {
        self.body.push_str(html);
        self.body.push('\n');
    }

    /// A highlighted note (unavailable data, failed checks).
    pub(crate) fn note(&mut self, class: &str, text: &str) {
        let _ = writeln!(
            self.body,
            "<p class=\"note {}\">{}</p>",
            esc(class),
            esc(text)
        );
    }

    pub(crate) fn img(&mut self, file: &str, alt: &str) {
        let _ = writeln!(
            self.body,
            "<figure><img src=\"{}\" alt=\"{}\"></figure>",
            esc(file),
            esc(alt)
        );
    }

    /// Links to the data files behind a figure.
    pub(crate) fn data(&mut self, files: &[&str]) {
        let links: Vec<String> = files
            .iter()
            .map(|f| format!("<a href=\"{0}\">{0}</a>", esc(f)))
            .collect();
        let _ = writeln!(
            self.body,
            "<p class=\"data\">data: {}</p>",
            links.join(", ")
        );
    }

    /// A table with a header row.
    pub(crate) fn table(&mut self, header: &[&str], rows: &[Vec<String>]) {
        self.body.push_str("<table><tr>");
        for h in header {
            let _ = write!(self.body, "<th>{}</th>", esc(h));
        }
        self.body.push_str("</tr>\n");
        for r in rows {
            self.body.push_str("<tr>");
            for c in r {
                let _ = write!(self.body, "<td>{}</td>", esc(c));
            }
            self.body.push_str("</tr>\n");
        }
        self.body.push_str("</table>\n");
    }

    pub(crate) fn finish(&self, title: &str) -> String {
        format!(
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
             <title>{t}</title><style>\
             body{{font-family:sans-serif;max-width:900px;margin:2em auto;padding:0 1em;color:#222}}\
             img{{max-width:100%}} figure{{margin:1em 0}}\
             table{{border-collapse:collapse;margin:1em 0}} td,th{{border:1px solid #bbb;padding:2px 8px;text-align:right}}\
             .note{{padding:.6em;border-left:4px solid #999;background:#f4f4f4}}\
             .ok{{border-color:#080;background:#e9f7e9;font-weight:bold}}\
             .fail{{border-color:#c00;background:#fde8e8;font-weight:bold}}\
             .na{{border-color:#c80;background:#fff6e0}}\
             .data{{font-size:90%}} .side img{{width:32%;margin-right:1%}}\
             </style></head><body>\n<h1>{t}</h1>\n{b}</body></html>\n",
            t = esc(title),
            b = self.body
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_quotes_text_and_leaves_missing_cells_empty() {
        let mut c = Csv::new(&["a", "b", "c", "d"]);
        c.push(vec!["x,y".into(), 3usize.into(), 0.5.into(), Cell::Na]);
        c.push(vec![
            "q\"".into(),
            Cell::from(None::<f64>),
            f64::NAN.into(),
            7u64.into(),
        ]);
        assert_eq!(c.text, "a,b,c,d\n\"x,y\",3,0.5,\n\"q\"\"\",,,7\n");
    }

    #[test]
    fn html_escapes_text() {
        assert_eq!(esc("<a & \"b\">"), "&lt;a &amp; &quot;b&quot;&gt;");
        let mut h = Html::new();
        h.p("1 < 2");
        assert!(h.finish("t").contains("<p>1 &lt; 2</p>"));
    }
}
