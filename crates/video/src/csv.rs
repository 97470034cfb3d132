//! The small CSV files users write by hand (annotations, turntable logs): a header naming the
//! columns in any case and order, comma-separated rows, blank lines and `#` comments skipped;
//! every error names the line and the column.

use anyhow::{bail, Context, Result};

/// A parsed file: the header's columns (trimmed, lower case) and the data rows.
pub struct Table<'a> {
    /// The header line as written (for error messages).
    pub header: &'a str,
    /// Column names, trimmed and lower-cased.
    pub cols: Vec<String>,
    rows: Vec<(usize, &'a str)>,
}

/// One data row.
pub struct Row<'t> {
    /// Line number in the file, from 1.
    pub line: usize,
    fields: Vec<&'t str>,
    cols: &'t [String],
}

impl<'a> Table<'a> {
    /// Splits `text` into the header and the data rows.
    pub fn parse(text: &'a str) -> Result<Self> {
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
        let (_, header) = lines.next().context("empty file: no header line")?;
        let cols = header
            .split(',')
            .map(|c| c.trim().to_ascii_lowercase())
            .collect();
        Ok(Self {
            header,
            cols,
            rows: lines.collect(),
        })
    }

    /// The first column named any of `names`.
    pub fn col(&self, names: &[&str]) -> Option<usize> {
        self.cols.iter().position(|c| names.contains(&c.as_str()))
    }

    /// The data rows, in file order.
    pub fn rows(&self) -> impl Iterator<Item = Row<'_>> {
        self.rows.iter().map(|&(n, l)| Row {
            line: n + 1,
            fields: l.split(',').map(str::trim).collect(),
            cols: &self.cols,
        })
    }
}

impl Row<'_> {
    /// The field of column `i` (trimmed); `None` when the row is shorter.
    pub fn field(&self, i: usize) -> Option<&str> {
        self.fields.get(i).copied()
    }

    /// Column `i` as a finite number.
    pub fn num(&self, i: usize) -> Result<f64> {
        let (ln, name) = (self.line, &self.cols[i]);
        let s = self
            .field(i)
            .with_context(|| format!("line {ln}: missing column {name}"))?;
        let v: f64 = s
            .parse()
            .with_context(|| format!("line {ln}: {name} {s:?} is not a number"))?;
        if !v.is_finite() {
            bail!("line {ln}: {name} is not finite");
        }
        Ok(v)
    }
}
