//! `OUT/report.html`: one page a browser opens, the tables an evaluation wrote as
//! markdown (rendered by `pulldown-cmark`, tables included) and its plots beside
//! them, each PNG linking to its SVG. The page refers to the plots by relative
//! path: the folder can be moved or served as it is.

use anyhow::{Context, Result};
use pulldown_cmark::{Options, Parser, html};
use std::path::{Path, PathBuf};

/// A plot of the report: the file stem of its `.png` and `.svg`, and its caption.
pub struct Plot<'a> {
    pub stem: &'a str,
    pub caption: &'a str,
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1000px;margin:2em auto;padding:0 1em;color:#222}\
table{border-collapse:collapse;margin:1em 0;font-size:14px}th,td{border:1px solid #ccc;padding:3px 8px}\
th{background:#f2f2f2}\
figure{margin:1.5em 0}img{max-width:100%;border:1px solid #eee}figcaption{color:#555;font-size:14px}";

/// The page: `title` as its heading, the `markdown` (tables and text), then the plots.
pub fn render(title: &str, markdown: &str, plots: &[Plot]) -> String {
    let mut body = String::new();
    html::push_html(&mut body, Parser::new_ext(markdown, Options::ENABLE_TABLES));
    let title = escaped(title);
    let mut figures = String::new();
    for Plot { stem, caption } in plots {
        let (stem, caption) = (escaped(stem), escaped(caption));
        figures.push_str(&format!(
            "<figure><a href=\"{stem}.svg\"><img src=\"{stem}.png\" alt=\"{caption}\"></a>\n\
             <figcaption>{caption} (the picture links to its SVG)</figcaption></figure>\n"
        ));
    }
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{title}</title>\n\
         <style>{STYLE}</style>\n</head>\n<body>\n<h1>{title}</h1>\n{body}{figures}</body>\n</html>\n"
    )
}

fn escaped(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    // Writing into a String cannot fail.
    let _ = pulldown_cmark_escape::escape_html(&mut out, text);
    out
}

/// Writes `DIR/report.html`; returns its path.
pub fn write(dir: &Path, title: &str, markdown: &str, plots: &[Plot]) -> Result<PathBuf> {
    let path = dir.join("report.html");
    std::fs::write(&path, render(title, markdown, plots)).with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_report_has_the_tables_as_html_and_links_every_plot() {
        let markdown =
            "Table I, seed 1000.\n\n| dataset | images | correct |\n|---|---:|---:|\n| orange2x1 | 6 | 6 (100%) |\n";
        let plots = [Plot { stem: "rates", caption: "Detection rate" }, Plot { stem: "timing", caption: "Time" }];
        let page = render("outlet eval <Table I>", markdown, &plots);
        assert!(page.starts_with("<!DOCTYPE html>"));
        assert!(page.contains("<table>") && page.contains("<th>dataset</th>"), "{page}");
        assert!(page.contains("<td>orange2x1</td>") && page.contains(">6 (100%)</td>"), "{page}");
        for stem in ["rates", "timing"] {
            assert!(page.contains(&format!("<img src=\"{stem}.png\"")), "{stem}: {page}");
            assert!(page.contains(&format!("<a href=\"{stem}.svg\">")), "{stem}: {page}");
        }
        // Text is escaped, not taken for markup.
        assert!(page.contains("<title>outlet eval &lt;Table I&gt;</title>"), "{page}");
        assert!(!page.contains("<Table I>"));
    }
}
