//! The self-contained HTML report: one page, inline style, images by relative
//! path. A small script checks on load that every image decoded and says so in
//! the page (`data-images-ok`), which the tests read through headless Chromium.

/// Escapes text for HTML.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Converts the Markdown this crate writes (headings, pipe tables, paragraphs)
/// to HTML. Not a general Markdown parser: only what the reports contain.
pub fn markdown_to_html(md: &str) -> String {
    let mut out = String::new();
    let mut table: Vec<Vec<String>> = Vec::new();
    let flush = |table: &mut Vec<Vec<String>>, out: &mut String| {
        if table.is_empty() {
            return;
        }
        out.push_str("<table>\n");
        for (i, row) in table.iter().enumerate() {
            // Row 1 is the alignment row of the Markdown table.
            if i == 1 {
                continue;
            }
            let tag = if i == 0 { "th" } else { "td" };
            out.push_str("<tr>");
            for cell in row {
                out.push_str(&format!("<{tag}>{}</{tag}>", escape(cell)));
            }
            out.push_str("</tr>\n");
        }
        out.push_str("</table>\n");
        table.clear();
    };
    for line in md.lines() {
        let t = line.trim();
        if let Some(inner) = t.strip_prefix('|') {
            let cells = inner
                .trim_end_matches('|')
                .split('|')
                .map(|c| c.trim().to_string())
                .collect();
            table.push(cells);
            continue;
        }
        flush(&mut table, &mut out);
        if t.is_empty() {
            continue;
        }
        if let Some(item) = t.strip_prefix("- ") {
            out.push_str(&format!("<ul><li>{}</li></ul>\n", escape(item)));
            continue;
        }
        let level = t.chars().take_while(|c| *c == '#').count();
        if (1..=6).contains(&level) && t[level..].starts_with(' ') {
            let h = level.clamp(2, 6);
            out.push_str(&format!("<h{h}>{}</h{h}>\n", escape(t[level..].trim())));
        } else {
            out.push_str(&format!("<p>{}</p>\n", escape(t)));
        }
    }
    flush(&mut table, &mut out);
    // Consecutive items in one list.
    out.replace("</li></ul>\n<ul><li>", "</li>\n<li>")
}

/// A section of the report: a title, an id for the contents list, and HTML.
pub struct Section {
    pub id: String,
    pub title: String,
    pub body: String,
}

/// A figure: an image with a link to its SVG (when there is one) and a caption.
pub fn figure(png: &str, svg: Option<&str>, caption: &str) -> String {
    let link = svg.map_or(String::new(), |s| {
        format!(" <a href=\"{}\">SVG</a>", escape(s))
    });
    format!(
        "<figure><a href=\"{p}\"><img src=\"{p}\" alt=\"{c}\"></a><figcaption>{c}{link}</figcaption></figure>\n",
        p = escape(png),
        c = escape(caption)
    )
}

const STYLE: &str = "body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1250px;color:#222;padding:0 1em}\
h1{margin-bottom:0}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}\
table{border-collapse:collapse;margin:.8em 0;font-size:.85em}td,th{border:1px solid #ccc;padding:.25em .5em;text-align:right}\
th{background:#f2f2f2}td:first-child,th:first-child,td:nth-child(2){text-align:left}\
figure{display:inline-block;margin:.5em;vertical-align:top}figure img{max-width:100%;border:1px solid #ddd}\
figcaption{font-size:.85em;color:#555;max-width:1200px}.row img{width:290px;image-rendering:pixelated}\
#check{padding:.3em .6em;border-radius:4px;display:inline-block;font-size:.85em}\
#check[data-images-ok=true]{background:#e3f5e1}#check[data-images-ok=false]{background:#fbd9d9}\
nav li{display:inline;margin-right:1em}.meta td{text-align:left}";

/// On load: every image decoded with a non-zero size, and none shown twice
/// (a chart listed once per data point put two charts on the page 528 times
/// each, and "1093 images loaded" passed).
const CHECK_SCRIPT: &str = "<script>window.addEventListener('load',function(){\
var imgs=Array.prototype.slice.call(document.images);\
var srcs=imgs.map(function(i){return i.getAttribute('src');});\
var bad=imgs.filter(function(i){return !(i.complete&&i.naturalWidth>0);});\
var dup=srcs.filter(function(s,k){return srcs.indexOf(s)!==k;});\
var el=document.getElementById('check');el.setAttribute('data-images-ok',(bad.length||dup.length)?'false':'true');\
el.textContent=bad.length?('images that did not load: '+bad.map(function(i){return i.getAttribute('src');}).join(', ')):\
dup.length?('images shown more than once: '+dup.join(', ')):(imgs.length+' images loaded, each once');});</script>";

/// The `src` of every `<img>` in `html`, in order.
pub fn image_sources(html: &str) -> Vec<&str> {
    html.split("<img src=\"")
        .skip(1)
        .filter_map(|s| s.split('"').next())
        .collect()
}

/// The first of `names` given more than once, if any.
pub fn first_duplicate<'a>(names: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let mut seen = std::collections::HashSet::new();
    names.into_iter().find(|n| !seen.insert(*n))
}

/// The whole page.
pub fn page(title: &str, meta: &[(String, String)], sections: &[Section]) -> String {
    let mut out = String::from("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">");
    out.push_str(&format!(
        "<title>{}</title><style>{STYLE}</style></head><body>\n",
        escape(title)
    ));
    out.push_str(&format!("<h1>{}</h1>\n", escape(title)));
    out.push_str(
        "<p><span id=\"check\" data-images-ok=\"pending\">checking images...</span></p>\n",
    );
    out.push_str("<table class=\"meta\">\n");
    for (k, v) in meta {
        out.push_str(&format!(
            "<tr><th>{}</th><td>{}</td></tr>\n",
            escape(k),
            escape(v)
        ));
    }
    out.push_str("</table>\n<nav><ul>");
    for s in sections {
        out.push_str(&format!(
            "<li><a href=\"#{}\">{}</a></li>",
            s.id,
            escape(&s.title)
        ));
    }
    out.push_str("</ul></nav>\n");
    for s in sections {
        out.push_str(&format!(
            "<h2 id=\"{}\">{}</h2>\n{}\n",
            s.id,
            escape(&s.title),
            s.body
        ));
    }
    out.push_str(CHECK_SCRIPT);
    out.push_str("\n</body></html>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markdown_tables_and_headings_become_html() {
        let html =
            markdown_to_html("### A <b>\n\n| x | y |\n|---|---:|\n| 1 | 2 |\n\ntext & more\n");
        assert!(html.contains("<h3>A &lt;b&gt;</h3>"), "{html}");
        assert!(html.contains("<tr><th>x</th><th>y</th></tr>"), "{html}");
        assert!(html.contains("<tr><td>1</td><td>2</td></tr>"), "{html}");
        assert!(!html.contains("---"), "{html}");
        assert!(html.contains("<p>text &amp; more</p>"), "{html}");
        assert_eq!(
            markdown_to_html("- a\n- b\n"),
            "<ul><li>a</li>\n<li>b</li></ul>\n"
        );
    }

    #[test]
    fn page_lists_sections_and_checks_images() {
        let p = page(
            "T",
            &[("cpu".into(), "x".into())],
            &[Section {
                id: "s".into(),
                title: "S".into(),
                body: figure("a.png", Some("a.svg"), "cap"),
            }],
        );
        assert!(p.contains("href=\"#s\"") && p.contains("<img src=\"a.png\""));
        assert!(p.contains("data-images-ok"));
        assert_eq!(image_sources(&p), ["a.png"]);
    }

    #[test]
    fn duplicates_are_found() {
        assert_eq!(first_duplicate(["a", "b", "c"]), None);
        assert_eq!(first_duplicate(["a", "b", "a", "b"]), Some("a"));
        let twice = format!(
            "{}{}",
            figure("x.png", None, "x"),
            figure("x.png", None, "x")
        );
        assert_eq!(first_duplicate(image_sources(&twice)), Some("x.png"));
    }
}
