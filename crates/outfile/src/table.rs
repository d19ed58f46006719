//! The one table type of every report and its four writers: Markdown (GitHub's pipe
//! tables), CSV (RFC 4180), JSON (an array of objects, one per row) and aligned plain text
//! for a terminal.

/// How a column's cells align in Markdown (numbers right, text left).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Align {
    /// Text.
    Left,
    /// Numbers.
    Right,
}

/// A table of text cells under named columns. Cells are already formatted (the writers
/// print them as they are); a missing value is an empty cell.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Table {
    /// Column names.
    pub headers: Vec<String>,
    /// Each column's alignment (as many as `headers`).
    pub align: Vec<Align>,
    /// Rows of cells; a short row is padded with empty cells.
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// An empty table; the first column is text, the others numbers.
    pub fn new<S: AsRef<str>>(headers: &[S]) -> Self {
        Table {
            headers: headers.iter().map(|h| h.as_ref().to_string()).collect(),
            align: (0..headers.len())
                .map(|k| if k == 0 { Align::Left } else { Align::Right })
                .collect(),
            rows: Vec::new(),
        }
    }

    /// An empty table whose columns are all text (left-aligned, `---` in Markdown).
    pub fn text<S: AsRef<str>>(headers: &[S]) -> Self {
        let mut t = Table::new(headers);
        t.align.fill(Align::Left);
        t
    }

    /// The table with column `k`'s alignment set.
    pub fn with_align(mut self, k: usize, a: Align) -> Self {
        if let Some(slot) = self.align.get_mut(k) {
            *slot = a;
        }
        self
    }

    /// The table with columns `cols` right-aligned (numbers) and the others as they were.
    pub fn right(mut self, cols: &[usize]) -> Self {
        for &k in cols {
            self = self.with_align(k, Align::Right);
        }
        self
    }

    /// Adds a row.
    pub fn push<S: ToString>(&mut self, row: impl IntoIterator<Item = S>) {
        self.rows
            .push(row.into_iter().map(|c| c.to_string()).collect());
    }

    fn cells<'a>(&'a self, row: &'a [String]) -> impl Iterator<Item = &'a str> + 'a {
        (0..self.headers.len()).map(move |k| row.get(k).map_or("", String::as_str))
    }

    /// A Markdown pipe table: `|` in a cell is escaped as `\|` and a line break becomes a
    /// space, so every row stays one table row.
    pub fn markdown(&self) -> String {
        let esc = |c: &str| c.replace('|', "\\|").replace(['\r', '\n'], " ");
        let line = |cells: &mut dyn Iterator<Item = &str>| {
            let v: Vec<String> = cells.map(esc).collect();
            format!("| {} |\n", v.join(" | "))
        };
        let mut s = line(&mut self.headers.iter().map(String::as_str));
        s.push('|');
        for k in 0..self.headers.len() {
            s.push_str(match self.align.get(k) {
                Some(Align::Right) => "---:|",
                _ => "---|",
            });
        }
        s.push('\n');
        for r in &self.rows {
            s += &line(&mut self.cells(r));
        }
        s
    }

    /// CSV with a header line: a cell holding a comma, a quote or a line break is quoted,
    /// its quotes doubled.
    pub fn csv(&self) -> String {
        let line = |cells: &mut dyn Iterator<Item = &str>| {
            let v: Vec<String> = cells.map(csv_field).collect();
            v.join(",") + "\n"
        };
        let mut s = line(&mut self.headers.iter().map(String::as_str));
        for r in &self.rows {
            s += &line(&mut self.cells(r));
        }
        s
    }

    /// Aligned plain text for a terminal: each column padded to its widest cell (header
    /// included), two spaces apart, right-aligned columns padded on the left; one line per
    /// row, trailing spaces trimmed, a line break in a cell printed as a space.
    pub fn aligned(&self) -> String {
        let flat = |c: &str| c.replace(['\r', '\n'], " ");
        let rows: Vec<Vec<String>> = self
            .rows
            .iter()
            .map(|r| self.cells(r).map(flat).collect())
            .collect();
        let mut width: Vec<usize> = self.headers.iter().map(|h| h.chars().count()).collect();
        for r in &rows {
            for (w, c) in width.iter_mut().zip(r) {
                *w = (*w).max(c.chars().count());
            }
        }
        let line = |cells: &mut dyn Iterator<Item = &str>| {
            let mut l = String::new();
            for (k, (v, &w)) in cells.zip(&width).enumerate() {
                if self.align.get(k) == Some(&Align::Right) {
                    l += &format!("{v:>w$}  ");
                } else {
                    l += &format!("{v:<w$}  ");
                }
            }
            l.trim_end().to_string() + "\n"
        };
        let mut s = line(&mut self.headers.iter().map(String::as_str));
        for r in &rows {
            s += &line(&mut r.iter().map(String::as_str));
        }
        s
    }

    /// An array with one object per row, keyed by column name: a cell that reads as a
    /// finite number is a JSON number, an empty cell `null`, any other a string.
    pub fn json(&self) -> serde_json::Value {
        let value = |c: &str| {
            if c.is_empty() {
                return serde_json::Value::Null;
            }
            let n = c
                .parse::<i64>()
                .ok()
                .map(serde_json::Value::from)
                .or_else(|| {
                    c.parse::<f64>()
                        .ok()
                        .filter(|v| v.is_finite())
                        .and_then(|v| serde_json::Number::from_f64(v).map(Into::into))
                });
            n.unwrap_or_else(|| serde_json::Value::String(c.to_string()))
        };
        self.rows
            .iter()
            .map(|r| {
                let obj: serde_json::Map<String, serde_json::Value> = self
                    .headers
                    .iter()
                    .zip(self.cells(r))
                    .map(|(h, c)| (h.clone(), value(c)))
                    .collect();
                serde_json::Value::Object(obj)
            })
            .collect()
    }
}

/// One CSV field (RFC 4180): quoted, with its quotes doubled, when it holds a comma, a
/// quote or a line break; as it is otherwise.
pub fn csv_field(v: &str) -> String {
    if v.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", v.replace('"', "\"\""))
    } else {
        v.to_string()
    }
}

/// `1234567` as `1,234,567`.
pub fn thousands(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::with_capacity(s.len() + s.len() / 3);
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Table {
        let mut t = Table::new(&["scene", "ms", "note"]).with_align(2, Align::Left);
        t.push(["bunny", "1.5", "a|b"]);
        t.push(["san, miguel", "12", "say \"hi\"\nthere"]);
        t.push(["short"]);
        t
    }

    #[test]
    fn markdown_escapes_pipes_and_aligns_numbers_right() {
        assert_eq!(
            sample().markdown(),
            "| scene | ms | note |\n|---|---:|---|\n| bunny | 1.5 | a\\|b |\n\
             | san, miguel | 12 | say \"hi\" there |\n| short |  |  |\n"
        );
    }

    #[test]
    fn text_tables_align_every_column_left() {
        let mut t = Table::text(&["a", "b"]);
        t.push(["1", "2"]);
        assert_eq!(t.markdown(), "| a | b |\n|---|---|\n| 1 | 2 |\n");
        let t = Table::text(&["a", "b", "c"]).right(&[0, 2]);
        assert_eq!(t.markdown(), "| a | b | c |\n|---:|---|---:|\n");
    }

    #[test]
    fn aligned_text_pads_columns_and_flattens_line_breaks() {
        assert_eq!(
            sample().aligned(),
            "scene         ms  note\n\
             bunny        1.5  a|b\n\
             san, miguel   12  say \"hi\" there\n\
             short\n"
        );
        assert_eq!(Table::text(&["x"]).aligned(), "x\n");
    }

    #[test]
    fn csv_quotes_commas_quotes_and_line_breaks() {
        assert_eq!(
            sample().csv(),
            "scene,ms,note\nbunny,1.5,a|b\n\"san, miguel\",12,\"say \"\"hi\"\"\nthere\"\nshort,,\n"
        );
        assert_eq!(csv_field("plain"), "plain");
    }

    #[test]
    fn thousands_groups_digits() {
        assert_eq!(thousands(0), "0");
        assert_eq!(thousands(999), "999");
        assert_eq!(thousands(1000), "1,000");
        assert_eq!(thousands(1234567), "1,234,567");
    }

    #[test]
    fn json_has_numbers_nulls_and_strings() {
        let j = sample().json();
        assert_eq!(j[0]["scene"], "bunny");
        assert_eq!(j[0]["ms"], 1.5);
        assert_eq!(j[1]["ms"], 12);
        assert_eq!(j[0]["note"], "a|b");
        assert!(j[2]["ms"].is_null() && j[2]["note"].is_null());
        assert_eq!(j.as_array().unwrap().len(), 3);
        // "inf" and "NaN" parse as floats but are not JSON numbers.
        let mut t = Table::new(&["x"]);
        t.push(["inf"]);
        assert_eq!(t.json()[0]["x"], "inf");
    }
}
