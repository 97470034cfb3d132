//! One table, three renderings: Markdown, CSV (RFC 4180 quoting) and HTML. Columns may be grouped
//! under a spanning header (the paper's "model" groups over L_b, L_d, Avg); Markdown and CSV,
//! which have one header row, spell a grouped column as `group column`.

use serde::Serialize;

/// A table of text cells: a header, optional column groups, rows.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Table {
    pub header: Vec<String>,
    /// Spanning groups over the header, left to right: `(label, columns)`; an empty label leaves
    /// its columns ungrouped. Empty = no groups. The spans must add up to the header's length.
    pub groups: Vec<(String, usize)>,
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// A table with this header and no rows.
    pub fn new<S: Into<String>>(header: impl IntoIterator<Item = S>) -> Self {
        Table {
            header: header.into_iter().map(Into::into).collect(),
            ..Default::default()
        }
    }

    /// Groups the columns under spanning labels (see [`Table::groups`]).
    pub fn grouped<S: Into<String>>(
        mut self,
        groups: impl IntoIterator<Item = (S, usize)>,
    ) -> Self {
        self.groups = groups.into_iter().map(|(s, n)| (s.into(), n)).collect();
        self
    }

    /// Appends a row (shorter rows are padded with empty cells when rendered).
    pub fn row<S: Into<String>>(&mut self, cells: impl IntoIterator<Item = S>) -> &mut Self {
        self.rows.push(cells.into_iter().map(Into::into).collect());
        self
    }

    /// The header with each grouped column spelt `group column` (one header row).
    pub fn flat_header(&self) -> Vec<String> {
        let mut out = Vec::with_capacity(self.header.len());
        let mut group = self
            .groups
            .iter()
            .flat_map(|(g, n)| std::iter::repeat_n(g, *n));
        for h in &self.header {
            match group.next() {
                Some(g) if !g.is_empty() => out.push(format!("{g} {h}")),
                _ => out.push(h.clone()),
            }
        }
        out
    }

    fn cells<'a>(&self, row: &'a [String]) -> impl Iterator<Item = &'a str> {
        (0..self.header.len().max(row.len())).map(move |i| row.get(i).map_or("", String::as_str))
    }

    /// GitHub-flavoured Markdown; `|` in cells is escaped.
    pub fn markdown(&self) -> String {
        let esc = |s: &str| s.replace('|', "\\|");
        let line = |cells: Vec<String>| format!("| {} |\n", cells.join(" | "));
        let mut s = line(self.flat_header().iter().map(|h| esc(h)).collect());
        s += &line(vec!["---".to_string(); self.header.len()]);
        for r in &self.rows {
            s += &line(self.cells(r).map(esc).collect());
        }
        s
    }

    /// CSV with a one-row header; cells with a comma, quote or newline are quoted.
    pub fn csv(&self) -> String {
        let q = |s: &str| {
            if s.contains([',', '"', '\n', '\r']) {
                format!("\"{}\"", s.replace('"', "\"\""))
            } else {
                s.to_string()
            }
        };
        let mut s = self
            .flat_header()
            .iter()
            .map(|h| q(h))
            .collect::<Vec<_>>()
            .join(",")
            + "\n";
        for r in &self.rows {
            s += &(self.cells(r).map(q).collect::<Vec<_>>().join(",") + "\n");
        }
        s
    }

    /// An HTML `<table>` (groups as a spanning first header row), cells escaped.
    pub fn html(&self) -> String {
        let mut s = String::from("<table>\n<thead>\n");
        if !self.groups.is_empty() {
            s += "<tr>";
            for (g, n) in &self.groups {
                s += &format!("<th colspan=\"{n}\">{}</th>", super::html::escape(g));
            }
            s += "</tr>\n";
        }
        s += "<tr>";
        for h in &self.header {
            s += &format!("<th>{}</th>", super::html::escape(h));
        }
        s += "</tr>\n</thead>\n<tbody>\n";
        for r in &self.rows {
            s += "<tr>";
            for c in self.cells(r) {
                s += &format!("<td>{}</td>", super::html::escape(c));
            }
            s += "</tr>\n";
        }
        s + "</tbody>\n</table>\n"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Table {
        let mut t = Table::new(["Texture", "L_b", "L_d", "L_b", "L_d"]).grouped([
            ("", 1),
            ("CenterNet", 2),
            ("NanoDet", 2),
        ]);
        t.row(["Original", "0.90", "0.80", "0.70", "0.60"])
            .row(["a, \"b\"", "x|y"]);
        t
    }

    #[test]
    fn markdown_and_csv_share_rows_and_flatten_groups() {
        let t = sample();
        let md = t.markdown();
        let lines: Vec<&str> = md.lines().collect();
        assert_eq!(
            lines[0],
            "| Texture | CenterNet L_b | CenterNet L_d | NanoDet L_b | NanoDet L_d |"
        );
        assert_eq!(lines[1], "| --- | --- | --- | --- | --- |");
        assert_eq!(
            lines[3], "| a, \"b\" | x\\|y |  |  |  |",
            "escaped and padded"
        );
        let csv = t.csv();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(
            lines[0],
            "Texture,CenterNet L_b,CenterNet L_d,NanoDet L_b,NanoDet L_d"
        );
        assert_eq!(lines[1], "Original,0.90,0.80,0.70,0.60");
        assert_eq!(lines[2], "\"a, \"\"b\"\"\",x|y,,,");
    }

    #[test]
    fn html_spans_groups_and_escapes() {
        let mut t = sample();
        t.row(["<b>&"]);
        let h = t.html();
        assert!(h.contains("<th colspan=\"2\">CenterNet</th>"));
        assert!(h.contains("<td>&lt;b&gt;&amp;</td>"));
        assert_eq!(h.matches("<tr>").count(), 2 + 3);
    }
}
