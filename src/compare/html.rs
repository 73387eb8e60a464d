//! `report.html`: the interactive, self-contained report beside report.md. The page
//! (`report.html`, embedded) is static HTML, CSS and JavaScript; this module only fills in the
//! title and the results as a JSON block. Nothing is fetched: the page works offline from the
//! output folder opened as `file://`, and refers to the PNG previews and EXRs by relative path.
//! `report.html#selftest` drives the page's controls and reports PASS or FAIL
//! (tests/report_html.rs runs it in headless Chromium).

use std::path::Path;

use super::results::Results;

/// The page template: `{{TITLE}}` (HTML text) and `{{RESULTS}}` (the JSON) are filled in.
const TEMPLATE: &str = include_str!("report.html");

/// The report page for `results`.
pub fn html(results: &Results) -> String {
    let scene = Path::new(&results.scene).file_name().and_then(|n| n.to_str()).unwrap_or(&results.scene);
    let title = format!("{scene} — {} ({}×{})", results.effect, results.width, results.height);
    let json = serde_json::to_value(results).expect("results serialise to JSON");
    page(&title, &json)
}

/// Fills the template. The JSON goes into a `<script type="application/json">` element, whose
/// content ends at the first `</script` whatever the quoting, and where `<!--` changes how the
/// parser reads on: so every `<` (which in JSON text only appears inside strings) is written as
/// the JSON escape `\u003c`. JSON.parse gives the same strings back.
fn page(title: &str, json: &serde_json::Value) -> String {
    let json = serde_json::to_string(json).expect("JSON values serialise").replace('<', "\\u003c");
    // Split first, so that neither filling can touch the other's placeholder.
    let (head, tail) = TEMPLATE.split_once("{{RESULTS}}").expect("the template has {{RESULTS}}");
    format!("{}{json}{tail}", head.replacen("{{TITLE}}", &escape_html(title), 1))
}

fn escape_html(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::{json, Value};

    /// The text of the results block in a page.
    fn results_block(page: &str) -> &str {
        let open = r#"<script type="application/json" id="results">"#;
        let start = page.find(open).expect("the results block") + open.len();
        // What an HTML parser does: the script's content ends at the first `</script`.
        let end = start + page[start..].to_ascii_lowercase().find("</script").expect("the block ends");
        &page[start..end]
    }

    #[test]
    fn the_json_block_parses_back_and_strings_cannot_break_out() {
        let nasty = "a </script><script>alert(1)</script> b <!-- c </SCRIPT > {{TITLE}} d & é";
        let value = json!({
            "scene": "scenes/x.toml", "effect": "indirect", "width": 16, "height": 8,
            "runs": [{"method": "pt", "notes": [nasty], "stats": {"x": 1.5}}],
            "skipped": [{"method": "oidn", "reason": nasty}],
        });
        let page = page("a <b> & \"c\" {{RESULTS}}", &value);
        // The block ends exactly where the template ends it: the notes did not close it.
        let block = results_block(&page);
        assert!(!block.contains('<'), "a raw < in the JSON block");
        let back: Value = serde_json::from_str(block).expect("the block is JSON");
        assert_eq!(back, value);
        assert_eq!(back["runs"][0]["notes"][0], nasty);
        // The page holds one results block and one title, and the title is escaped text.
        assert_eq!(page.matches(r#"id="results""#).count(), 1);
        assert!(page.contains("<title>a &lt;b&gt; &amp; &quot;c&quot; {{RESULTS}}</title>"));
        assert!(!page.contains("<title>{{TITLE}}"));
    }

    #[test]
    fn the_template_is_self_contained_and_small() {
        // No network: no absolute URLs, no fetch, no external script or style sheet, nothing from a CDN.
        for needle in ["http://", "https://", "fetch(", "src=\"//", "href=\"//", "@import", "<script src", "<link"] {
            let allowed = needle == "http://"
                && TEMPLATE.matches(needle).count() == 1
                && TEMPLATE.contains("'http://www.w3.org/2000/svg'");
            assert!(!TEMPLATE.contains(needle) || allowed, "the template contains {needle}");
        }
        assert!(TEMPLATE.len() < 40_000, "the template is {} bytes", TEMPLATE.len());
        assert_eq!(TEMPLATE.matches("{{RESULTS}}").count(), 1);
        assert_eq!(TEMPLATE.matches("{{TITLE}}").count(), 1);
    }
}
