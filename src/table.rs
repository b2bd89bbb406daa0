//! The one table type every report writes: a header with an alignment per
//! column and rows of already-formatted cells, rendered as a Markdown pipe
//! table or as CSV (cells with commas, quotes or line breaks quoted).

/// How a column is aligned in Markdown (`|---|` or `|---:|`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Align {
    Left,
    Right,
}

/// A table of text cells.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Table {
    header: Vec<String>,
    align: Vec<Align>,
    rows: Vec<Vec<String>>,
}

impl Table {
    /// A table with these columns: `(title, alignment)`.
    pub fn new<S: Into<String>>(columns: impl IntoIterator<Item = (S, Align)>) -> Table {
        let (header, align) = columns.into_iter().map(|(t, a)| (t.into(), a)).unzip();
        Table {
            header,
            align,
            rows: Vec::new(),
        }
    }

    /// Adds a column at the end (for tables whose columns depend on the data).
    pub fn column(&mut self, title: impl Into<String>, align: Align) {
        self.header.push(title.into());
        self.align.push(align);
    }

    /// Adds a row; it must have one cell per column.
    pub fn row<S: ToString>(&mut self, cells: impl IntoIterator<Item = S>) {
        let row: Vec<String> = cells.into_iter().map(|c| c.to_string()).collect();
        debug_assert_eq!(row.len(), self.header.len(), "cells per row");
        self.rows.push(row);
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// `| a | b |` lines: the header, the alignment row, then the rows.
    pub fn markdown(&self) -> String {
        let line = |cells: &[String]| format!("| {} |\n", cells.join(" | "));
        let mut out = line(&self.header);
        out.push('|');
        for a in &self.align {
            out.push_str(match a {
                Align::Left => "---|",
                Align::Right => "---:|",
            });
        }
        out.push('\n');
        for r in &self.rows {
            out.push_str(&line(r));
        }
        out
    }

    /// The header and rows as comma-separated values.
    pub fn csv(&self) -> String {
        let quote = |c: &String| {
            if c.contains([',', '"', '\n', '\r']) {
                format!("\"{}\"", c.replace('"', "\"\""))
            } else {
                c.clone()
            }
        };
        let line = |cells: &[String]| {
            let q: Vec<String> = cells.iter().map(quote).collect();
            format!("{}\n", q.join(","))
        };
        let mut out = line(&self.header);
        for r in &self.rows {
            out.push_str(&line(r));
        }
        out
    }
}

/// A duration in milliseconds, as every report gives times.
pub fn ms(d: std::time::Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Milliseconds with the precision their size needs: three decimals below
/// 0.1 ms, two below 10, one below 100, none above (build times of small
/// scenes read 0.0 with one decimal).
pub fn fmt_ms(x: f64) -> String {
    if x >= 100.0 {
        format!("{x:.0}")
    } else if x >= 10.0 {
        format!("{x:.1}")
    } else if x >= 0.1 {
        format!("{x:.2}")
    } else {
        format!("{x:.3}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markdown_and_csv_of_one_table() {
        let mut t = Table::new([("name", Align::Left), ("ms", Align::Right)]);
        t.row(["a, b", "1.5"]);
        t.row(["say \"hi\"".to_string(), 2.to_string()]);
        assert_eq!(
            t.markdown(),
            "| name | ms |\n|---|---:|\n| a, b | 1.5 |\n| say \"hi\" | 2 |\n"
        );
        assert_eq!(t.csv(), "name,ms\n\"a, b\",1.5\n\"say \"\"hi\"\"\",2\n");
        t.column("extra", Align::Left);
        assert_eq!(t.markdown().lines().next(), Some("| name | ms | extra |"));
    }

    #[test]
    fn milliseconds_keep_their_digits() {
        assert_eq!(fmt_ms(0.0421), "0.042");
        assert_eq!(fmt_ms(1.234), "1.23");
        assert_eq!(fmt_ms(12.34), "12.3");
        assert_eq!(fmt_ms(123.44), "123");
        assert_eq!(ms(std::time::Duration::from_micros(1500)), 1.5);
    }
}
