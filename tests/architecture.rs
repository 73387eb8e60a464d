//! `docs/ARCHITECTURE.md` held to the tree: it names every product source file, and every `.rs`
//! file it names exists.
//!
//! **Product source files** are all `.rs` files under the crates' `src/` folders: the root
//! package's `src/`, `sampleio/src/`, `shading/src/`, `tracer/src/`, `recon/src/` and
//! `probes/src/`. Nothing under them is excluded (unit-test support such as
//! `tlfr/test_scenes.rs` lives there too, and is named like the rest); files under `tests/`,
//! `benches/`, `examples/` and `fuzz/` are outside `src/` and not product.
//!
//! **Named.** Each crate has one section of the document: the `## ` heading that
//! [`CRATE_SECTIONS`] gives, up to the next `## ` heading. A line of the section that starts
//! with a folder in backticks (`` `tlfr/` — … ``, `` `compare/stages/` — … ``) opens that
//! folder's block, which runs to the next such line or the end of the section; the lines before
//! the first such line are the block of `src/` itself. A file whose path below its crate's
//! `src/` is `DIR/NAME.rs` is named when the section holds `` `DIR/NAME.rs` `` in backticks
//! anywhere, or `` `NAME.rs` `` in the block of `DIR/` (for a file directly in `src/`: its block).
//!
//! **Exists.** Every path ending in `.rs` that the document names, in backticks or not, is a
//! path from the repository root or the end (after a `/`) of the path of a file in the
//! repository; and every `.rs` file in the first cell of a table row of a crate section is, in
//! that crate, the file the row's block gives it (`DIR/NAME.rs`), or the path below `src/` as
//! written.
//!
//! **No import cycle** among a crate's modules (files), and no comment in any Rust file cites an
//! issue or a session by number. **No product file over 1,000 code lines** unless its module
//! documentation says why, in a paragraph that starts "Why one file".

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// Each crate's `src/` folder (from the repository root) and the heading of its section.
const CRATE_SECTIONS: [(&str, &str); 6] = [
    ("sampleio/src", "## sampleio, file by file"),
    ("shading/src", "## shading, file by file"),
    ("tracer/src", "## The tracer, file by file (one concept per file)"),
    ("recon/src", "## recon, folder by folder"),
    ("probes/src", "## probes, file by file"),
    ("src", "## The command, file by file"),
];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn document() -> String {
    let path = root().join("docs/ARCHITECTURE.md");
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Every file below `dir`, as paths relative to `base` with `/` separators. Skips `target`
/// and hidden folders (`.git`, `.ci`).
fn files_below(base: &Path, dir: &Path, out: &mut Vec<String>) {
    let entries = std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    for entry in entries {
        let entry = entry.unwrap();
        let name = entry.file_name().to_string_lossy().into_owned();
        let path = entry.path();
        let kind = entry.file_type().unwrap();
        if kind.is_dir() {
            if name.starts_with('.') || name == "target" {
                continue;
            }
            files_below(base, &path, out);
        } else if kind.is_file() {
            let relative = path.strip_prefix(base).unwrap();
            let parts: Vec<_> = relative.components().map(|c| c.as_os_str().to_string_lossy()).collect();
            out.push(parts.join("/"));
        }
    }
}

/// The product source files of the crate whose `src/` is `src`, relative to it, sorted.
fn product_files(src: &str) -> Vec<String> {
    let base = root().join(src);
    let mut files = Vec::new();
    files_below(&base, &base, &mut files);
    files.retain(|f| f.ends_with(".rs"));
    files.sort();
    files
}

/// The lines of the section under `heading`, up to the next `## ` heading.
fn section<'a>(doc: &'a str, heading: &str) -> Option<Vec<&'a str>> {
    let mut lines = doc.lines().skip_while(|l| l.trim_end() != heading);
    lines.next()?;
    Some(lines.take_while(|l| !l.starts_with("## ")).collect())
}

/// The spans in backticks on `line`.
fn backticked(line: &str) -> Vec<&str> {
    line.split('`').skip(1).step_by(2).collect()
}

/// The folder (`tlfr/`, `compare/stages/`) whose block `line` opens, if it opens one.
fn opened_block(line: &str) -> Option<&str> {
    let rest = line.strip_prefix('`')?;
    let folder = &rest[..rest.find('`')?];
    (folder.ends_with('/') && !folder.contains(' ')).then_some(folder)
}

/// A section split into its blocks: (folder, `""` for `src/` itself; the block's lines).
fn blocks<'a>(lines: &[&'a str]) -> Vec<(&'a str, Vec<&'a str>)> {
    let mut out = vec![("", Vec::new())];
    for &line in lines {
        if let Some(folder) = opened_block(line) {
            out.push((folder, Vec::new()));
        }
        out.last_mut().unwrap().1.push(line);
    }
    out
}

/// Every path ending in `.rs` that `text` names: a run of letters, digits, `_`, `-`, `.` and
/// `/` that ends in `.rs` not followed by a letter or digit.
fn rs_paths(text: &str) -> BTreeSet<String> {
    let is_path_char = |c: char| c.is_ascii_alphanumeric() || "_-./".contains(c);
    let mut out = BTreeSet::new();
    let mut current = String::new();
    for c in text.chars().chain(std::iter::once(' ')) {
        if is_path_char(c) {
            current.push(c);
            continue;
        }
        let word = current.trim_end_matches('.').trim_start_matches(['.', '/']);
        if word.ends_with(".rs") && word.len() > 3 {
            out.insert(word.to_string());
        }
        current.clear();
    }
    out
}

#[test]
fn architecture_md_names_every_product_source_file() {
    let doc = document();
    let mut missing = Vec::new();
    for (src, heading) in CRATE_SECTIONS {
        let Some(lines) = section(&doc, heading) else {
            missing.push(format!("{src}/: no section `{heading}`"));
            continue;
        };
        let whole: BTreeSet<&str> = lines.iter().flat_map(|l| backticked(l)).collect();
        let blocks = blocks(&lines);
        for file in product_files(src) {
            let (folder, name) = match file.rfind('/') {
                Some(i) => (&file[..=i], &file[i + 1..]),
                None => ("", file.as_str()),
            };
            let in_block = blocks
                .iter()
                .filter(|(f, _)| *f == folder)
                .any(|(_, lines)| lines.iter().any(|l| backticked(l).contains(&name)));
            if !in_block && !whole.contains(file.as_str()) {
                missing.push(format!("{src}/{file} (under `{heading}`)"));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "docs/ARCHITECTURE.md does not name {} product source file(s) (see tests/architecture.rs \
         for the rule):\n  {}",
        missing.len(),
        missing.join("\n  ")
    );
}

#[test]
fn every_rs_file_architecture_md_names_exists() {
    let doc = document();
    let root = root();
    let mut all = Vec::new();
    files_below(&root, &root, &mut all);
    let mut missing = Vec::new();

    for path in rs_paths(&doc) {
        let exists = all.iter().any(|f| *f == path || f.ends_with(&format!("/{path}")));
        if !exists {
            missing.push(format!("`{path}`: no such file in the repository"));
        }
    }

    for (src, heading) in CRATE_SECTIONS {
        let Some(lines) = section(&doc, heading) else { continue };
        for (folder, lines) in blocks(&lines) {
            for line in lines {
                let Some(first_cell) = line.strip_prefix('|').and_then(|l| l.split('|').next()) else {
                    continue;
                };
                for name in backticked(first_cell).into_iter().filter(|n| n.ends_with(".rs")) {
                    let in_block = root.join(src).join(folder).join(name);
                    let below_src = root.join(src).join(name);
                    if !in_block.is_file() && !below_src.is_file() {
                        missing.push(format!("`{name}` in the row of `{src}/{folder}`: no such file"));
                    }
                }
            }
        }
    }

    assert!(
        missing.is_empty(),
        "docs/ARCHITECTURE.md names {} file(s) that do not exist:\n  {}",
        missing.len(),
        missing.join("\n  ")
    );
}

/// Whether `comment` cites an issue or a session by number (the word, a space, a digit): a
/// comment states the rule and the number; git keeps the story.
fn cites_an_issue_or_session(comment: &str) -> bool {
    let lower = comment.to_lowercase();
    ["issue ", "session "].iter().any(|word| {
        lower.match_indices(word).any(|(at, _)| {
            let before = lower[..at].chars().next_back();
            let after = lower[at + word.len()..].chars().next();
            !before.is_some_and(|c| c.is_alphanumeric()) && after.is_some_and(|c| c.is_ascii_digit())
        })
    })
}

/// No comment in the repository's Rust files, product or test (every `.rs` file outside
/// `target/`, hidden folders and `experiments/`), cites an issue or a session by number.
#[test]
fn no_comment_cites_an_issue_or_a_session() {
    assert!(cites_an_issue_or_session("fixed in issue 22, class 9"));
    assert!(cites_an_issue_or_session("Session 20: the default"));
    assert!(!cites_an_issue_or_session("the tissue 3 layers; an issue with 0-sized images"));
    let base = root();
    let mut files = Vec::new();
    files_below(&base, &base, &mut files);
    let mut citing = Vec::new();
    for file in files.iter().filter(|f| f.ends_with(".rs") && !f.starts_with("experiments/")) {
        let text = std::fs::read_to_string(base.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        for (number, line) in text.lines().enumerate() {
            if let Some(at) = line.find("//") {
                if cites_an_issue_or_session(&line[at..]) {
                    citing.push(format!("{file}:{}: {}", number + 1, line.trim()));
                }
            }
        }
    }
    assert!(citing.is_empty(), "{} comment(s) cite an issue or a session:\n  {}", citing.len(), citing.join("\n  "));
}

/// Lines that are neither blank nor only a comment.
fn code_lines(text: &str) -> usize {
    text.lines()
        .filter(|line| {
            let line = line.trim();
            !line.is_empty() && !line.starts_with("//")
        })
        .count()
}

/// The most code lines a product file holds without its module documentation saying why.
const LONG_FILE: usize = 1_000;

/// A product file over `LONG_FILE` code lines states why it is one file: a paragraph of its
/// module documentation (`//!`) that starts "Why one file".
#[test]
fn a_product_file_over_a_thousand_code_lines_says_why() {
    assert_eq!(code_lines("//! a\n\nfn f() {}\n    // b\n  x\n"), 2);
    let mut unexplained = Vec::new();
    for (src, _) in CRATE_SECTIONS {
        for file in product_files(src) {
            let path = root().join(src).join(&file);
            let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            let lines = code_lines(&text);
            let says_why = text.lines().take_while(|l| l.starts_with("//!")).any(|l| l.starts_with("//! Why one file"));
            if lines > LONG_FILE && !says_why {
                unexplained.push(format!("{src}/{file}: {lines} code lines"));
            }
        }
    }
    assert!(
        unexplained.is_empty(),
        "{} product file(s) over {LONG_FILE} code lines without a \"Why one file\" paragraph:\n  {}",
        unexplained.len(),
        unexplained.join("\n  ")
    );
}

/// The module path of a file below a crate's `src/` (`a/b.rs` → `a::b`, `a/mod.rs` → `a`,
/// `lib.rs` and `main.rs` → the root, ``).
fn module_of(file: &str) -> String {
    let path = file.trim_end_matches(".rs");
    let path = path.strip_suffix("/mod").unwrap_or(path);
    if path == "lib" || path == "main" || path == "mod" {
        return String::new();
    }
    path.replace('/', "::")
}

/// The module paths a file's code (of module `module`) refers to through `crate::…` and
/// `super::…` (any number of them) and their `{…}` groups, each resolved to the longest prefix
/// that is one of `modules`. Comments and everything from the first `#[cfg(test)]` on are left
/// out.
fn references(module: &str, text: &str, modules: &BTreeSet<String>) -> BTreeSet<String> {
    let code: String = text
        .lines()
        .take_while(|line| line.trim() != "#[cfg(test)]")
        .map(|line| line.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    // `super` is the module above this one (for a folder's `mod.rs` too).
    let mut above: Vec<&str> = if module.is_empty() { Vec::new() } else { module.split("::").collect() };
    above.pop();
    let mut out = BTreeSet::new();
    let mut resolve = |segments: Vec<&str>| {
        for k in (1..=segments.len()).rev() {
            let candidate = segments[..k].join("::");
            if modules.contains(&candidate) {
                out.insert(candidate);
                return;
            }
        }
    };
    let bytes = code.as_bytes();
    let is_path_char = |c: u8| c.is_ascii_alphanumeric() || c == b'_' || c == b':';
    for start in ["crate::", "super::"] {
        for (at, _) in code.match_indices(start) {
            if at > 0 && is_path_char(bytes[at - 1]) {
                continue;
            }
            let (base, rest) = match code[at..].strip_prefix("crate::") {
                Some(rest) => (Vec::new(), rest),
                None => {
                    let (mut base, mut rest) = (above.clone(), &code[at + "super::".len()..]);
                    while let Some(r) = rest.strip_prefix("super::") {
                        base.pop();
                        rest = r;
                    }
                    (base, rest)
                }
            };
            let end = rest.find(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == ':')).unwrap_or(rest.len());
            let mut prefix = base;
            prefix.extend(rest[..end].split("::").filter(|s| !s.is_empty()));
            match rest[end..].strip_prefix('{') {
                // A group: `prefix::{a, b::c, …}`.
                Some(group) if rest[..end].is_empty() || rest[..end].ends_with("::") => {
                    for item in group[..group.find('}').unwrap_or(group.len())].split(',') {
                        let mut segments = prefix.clone();
                        segments.extend(item.split("::").map(str::trim).filter(|s| !s.is_empty() && *s != "self"));
                        resolve(segments);
                    }
                }
                _ => resolve(prefix),
            }
        }
    }
    out
}

/// No import cycle among a crate's modules: in every crate the graph of the files' references
/// to other modules (a module to its own ancestors or descendants left out: a folder declares
/// its files) has no cycle. A cycle is printed as the modules it runs through.
#[test]
fn no_crate_has_an_import_cycle() {
    let modules: BTreeSet<String> = ["a", "a::c", "a::d", "f"].iter().map(|m| m.to_string()).collect();
    let text = "use super::{c, d::E};\nuse crate::f::G; // crate::a::x\n#[cfg(test)]\nuse super::super::a::b;";
    let found: Vec<String> = references("a::b", text, &modules).into_iter().collect();
    assert_eq!(found, ["a::c", "a::d", "f"], "groups, crate paths; comments and tests left out");
    for (src, _) in CRATE_SECTIONS {
        let files = product_files(src);
        let modules: BTreeSet<String> = files.iter().map(|f| module_of(f)).collect();
        let related = |a: &str, b: &str| {
            a == b
                || a.is_empty()
                || b.is_empty()
                || a.starts_with(&format!("{b}::"))
                || b.starts_with(&format!("{a}::"))
        };
        let mut edges: std::collections::BTreeMap<String, BTreeSet<String>> = Default::default();
        for file in &files {
            let module = module_of(file);
            let text = std::fs::read_to_string(root().join(src).join(file)).unwrap();
            let targets = references(&module, &text, &modules);
            edges.entry(module.clone()).or_default().extend(targets.into_iter().filter(|t| !related(&module, t)));
        }
        // Depth-first search for a back edge; the cycle is the stack from its target.
        fn visit(
            node: &str,
            edges: &std::collections::BTreeMap<String, BTreeSet<String>>,
            state: &mut std::collections::BTreeMap<String, u8>,
            stack: &mut Vec<String>,
        ) -> Option<Vec<String>> {
            state.insert(node.to_string(), 1);
            stack.push(node.to_string());
            for next in edges.get(node).into_iter().flatten() {
                match state.get(next.as_str()).copied().unwrap_or(0) {
                    1 => {
                        let from = stack.iter().position(|m| m == next).unwrap();
                        let mut cycle = stack[from..].to_vec();
                        cycle.push(next.clone());
                        return Some(cycle);
                    }
                    0 => {
                        if let Some(cycle) = visit(next, edges, state, stack) {
                            return Some(cycle);
                        }
                    }
                    _ => {}
                }
            }
            stack.pop();
            state.insert(node.to_string(), 2);
            None
        }
        let mut state = Default::default();
        for module in edges.keys() {
            if let Some(cycle) = visit(module, &edges, &mut state, &mut Vec::new()) {
                panic!("{src}: an import cycle: {}", cycle.join(" → "));
            }
        }
    }
}
