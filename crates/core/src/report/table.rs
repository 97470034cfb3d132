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

/// One Markdown table line; `|` in cells is escaped.
fn markdown_line<'a>(cells: impl Iterator<Item = &'a str>) -> String {
    let cells: Vec<String> = cells.map(|c| c.replace('|', "\\|")).collect();
    format!("| {} |\n", cells.join(" | "))
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
        let mut s = self.markdown_header();
        for r in &self.rows {
            s += &self.markdown_row(r);
        }
        s
    }

    /// The Markdown of the last row, after the header when it is the first: printed as each row
    /// is measured, a long benchmark streams one Markdown table.
    pub fn markdown_last(&self) -> String {
        let Some(last) = self.rows.last() else {
            return String::new();
        };
        let head = if self.rows.len() == 1 {
            self.markdown_header()
        } else {
            String::new()
        };
        head + &self.markdown_row(last)
    }

    fn markdown_header(&self) -> String {
        let h: Vec<String> = self.flat_header();
        let rule = vec!["---".to_string(); self.header.len()];
        markdown_line(h.iter().map(String::as_str))
            + &markdown_line(rule.iter().map(String::as_str))
    }

    fn markdown_row(&self, r: &[String]) -> String {
        markdown_line(self.cells(r))
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
    fn streamed_rows_add_up_to_the_whole_markdown() {
        let full = sample();
        let mut t = Table::new(full.header.clone()).grouped(full.groups.clone());
        let mut streamed = t.markdown_last();
        assert_eq!(streamed, "", "nothing before the first row");
        for r in &full.rows {
            t.row(r.clone());
            streamed += &t.markdown_last();
        }
        assert_eq!(streamed, full.markdown());
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
