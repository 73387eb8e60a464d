//! `report.html` in a real browser: a tiny `lfr compare` writes the page, headless Chromium opens
//! it as `file://…/report.html#selftest`, and the page's self-test drives every control (split
//! slider and grip, wheel zoom, drag pan, exposure, error-map toggle, pair selection, legend,
//! table sorting, point hover) and writes PASS or FAIL into `<pre id="selftest">`, which
//! `--dump-dom` hands back. Two broken variants show that the check can fail.
//!
//! Without Chromium (`chromium`, or the binary in `$LFR_CHROMIUM`) the test is skipped with a
//! `SKIPPED` line (`testkit::skip`), and fails under CI (`LFR_CI=1`).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The browser to use, if one runs.
fn chromium() -> Option<PathBuf> {
    let candidates: Vec<PathBuf> = match std::env::var_os("LFR_CHROMIUM") {
        Some(path) => vec![path.into()],
        None => vec!["chromium".into(), "chromium-browser".into()],
    };
    candidates.into_iter().find(|browser| {
        Command::new(browser).arg("--version").output().map(|out| out.status.success()).unwrap_or(false)
    })
}

/// Opens `page#selftest` headless and returns the DOM after the self-test, and stderr.
fn run_selftest(browser: &Path, page: &Path, profile: &Path) -> (String, String) {
    let url = format!("file://{}#selftest", page.canonicalize().unwrap().display());
    let mut child = Command::new(browser)
        .args([
            "--headless=new",
            "--no-sandbox", // as root in CI containers
            "--disable-gpu",
            "--disable-dev-shm-usage", // containers often have a small /dev/shm
            "--no-first-run",
            "--allow-file-access-from-files",
            // The console on stderr, so that an uncaught error shows there too.
            "--enable-logging=stderr",
            "--v=0",
            // Virtual time runs the page's timers and image loads, then the DOM is dumped.
            "--virtual-time-budget=15000",
            "--dump-dom",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(&url)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the browser starts");
    // Read both pipes on threads so that neither can fill up and block the browser.
    let mut stdout = child.stdout.take().unwrap();
    let mut stderr = child.stderr.take().unwrap();
    let out = std::thread::spawn(move || {
        let mut s = String::new();
        stdout.read_to_string(&mut s).ok();
        s
    });
    let err = std::thread::spawn(move || {
        let mut s = String::new();
        stderr.read_to_string(&mut s).ok();
        s
    });
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(120) {
            child.kill().ok();
            panic!("the browser did not finish within 120 s on {url}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    (out.join().unwrap(), err.join().unwrap())
}

/// The text of `<pre id="selftest">` in a dumped DOM.
fn outcome(dom: &str) -> String {
    let open = r#"<pre id="selftest">"#;
    let Some(start) = dom.rfind(open).map(|i| i + open.len()) else {
        return format!("no self-test element in the DOM ({} bytes)", dom.len());
    };
    let end = start + dom[start..].find("</pre>").expect("the element ends");
    dom[start..end].replace("&lt;", "<").replace("&gt;", ">").replace("&quot;", "\"").replace("&amp;", "&")
}

#[test]
fn report_html_passes_its_self_test_in_chromium() {
    let Some(browser) = chromium() else {
        testkit::skip("no Chromium runs (apt-get install chromium, or set LFR_CHROMIUM)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let cache = dir.path().join("cache");
    // A tiny comparison: the path-tracing ladder and `box`, so the plot has two curves.
    let result = Command::new(env!("CARGO_BIN_EXE_lfr"))
        .args(["compare", "--effect", "indirect", "--methods", "box", "--width", "16", "--height", "16"])
        .args(["--spp", "1,4", "--reference-spp", "64", "--pt-max-spp", "8", "--seed", "3", "--quiet"])
        .arg("--out")
        .arg(&out)
        .arg("--cache-dir")
        .arg(&cache)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("lfr runs");
    assert!(result.status.success(), "lfr compare failed: {}", String::from_utf8_lossy(&result.stderr));
    let page = out.join("report.html");
    let html = std::fs::read_to_string(&page).expect("report.html is written");
    assert!(html.contains(r#"<script type="application/json" id="results">"#));

    let started = Instant::now();
    let (dom, stderr) = run_selftest(&browser, &page, &dir.path().join("profile"));
    let result = outcome(&dom);
    eprintln!("report.html self-test in Chromium ({:.1} s): {result}", started.elapsed().as_secs_f64());
    assert!(result.starts_with("PASS"), "report.html self-test: {result}\nbrowser stderr:\n{stderr}");
    assert!(!stderr.contains("Uncaught"), "script errors on the browser's console:\n{stderr}");

    // The check can fail. The page away from its images: the image checks fail.
    let alone = dir.path().join("alone");
    std::fs::create_dir(&alone).unwrap();
    std::fs::copy(&page, alone.join("report.html")).unwrap();
    let (dom, _) = run_selftest(&browser, &alone.join("report.html"), &dir.path().join("profile"));
    let result = outcome(&dom);
    assert!(result.starts_with("FAIL") && result.contains("image loads"), "without images: {result}");

    // A script error anywhere on the page is reported.
    let broken = out.join("broken.html");
    let marker = r#"<script type="application/json" id="results">"#;
    std::fs::write(&broken, html.replacen(marker, &format!("<script>window.noSuchFunction()</script>\n{marker}"), 1))
        .unwrap();
    let (dom, stderr) = run_selftest(&browser, &broken, &dir.path().join("profile"));
    let result = outcome(&dom);
    assert!(result.starts_with("FAIL") && result.contains("noSuchFunction"), "with a script error: {result}");
    assert!(stderr.contains("Uncaught"), "the console shows no script error:\n{stderr}");
}
