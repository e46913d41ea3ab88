//! Citations inside the repository point somewhere: every `docs/NAME.md "Heading"` (or
//! `docs/NAME.md, "Heading"`, `docs/NAME.md 4d`) in a source file, script or doc names a file that
//! exists and a heading it has. A heading renamed or removed breaks this test, not a reader.

use std::path::{Path, PathBuf};

/// Files that may cite the docs: sources, scripts, docs and scenes, outside build outputs.
fn citing_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("the tree reads").flatten() {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if path.is_dir() {
            if !(name.starts_with('.') || name == "target" || name == "node_modules" || name == "__pycache__") {
                citing_files(&path, out);
            }
        } else if ["rs", "md", "py", "sh", "toml", "proto", "sbatch", "service"]
            .iter()
            .any(|e| name.ends_with(&format!(".{e}")))
        {
            out.push(path);
        }
    }
}

/// The text with comment markers and line breaks folded into single spaces, so that a citation
/// wrapped across comment lines reads as one.
fn folded(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for line in text.lines() {
        let line = line.trim_start();
        let line = ["///", "//!", "//", "#", ">"].iter().find_map(|m| line.strip_prefix(m)).unwrap_or(line);
        out.push_str(line.trim());
        out.push(' ');
    }
    out
}

/// What a citation names after the file: a quoted heading or a section number.
#[derive(Debug, PartialEq)]
enum Cited {
    Heading(String),
    Section(String),
}

/// Every citation of a doc in `text`: (the doc's path, what it names).
fn citations(text: &str) -> Vec<(String, Cited)> {
    let mut found = Vec::new();
    let mut rest = text;
    while let Some(at) = rest.find("docs/") {
        let tail = &rest[at..];
        rest = &rest[at + 5..];
        let Some(end) = tail.find(".md") else { break };
        let doc = &tail[..end + 3];
        if doc.len() > 60 || !doc[5..end].chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_') {
            continue;
        }
        let after = tail[end + 3..].trim_start_matches([',', ':']).trim_start();
        let after = after.strip_prefix("section ").unwrap_or(after);
        if let Some(quoted) = after.strip_prefix('"') {
            if let Some(close) = quoted.find('"') {
                let heading = quoted[..close].trim().trim_end_matches(['.', ',']).to_string();
                if !heading.is_empty() && heading.len() < 120 {
                    found.push((doc.to_string(), Cited::Heading(heading)));
                }
            }
        } else {
            let number: String = after.chars().take_while(|c| c.is_ascii_alphanumeric()).collect();
            let is_section = number.chars().next().is_some_and(|c| c.is_ascii_digit())
                && number.chars().all(|c| c.is_ascii_digit() || c.is_ascii_lowercase())
                && number.len() <= 3;
            if is_section {
                found.push((doc.to_string(), Cited::Section(number)));
            }
        }
    }
    found
}

fn headings(doc: &str) -> Vec<String> {
    doc.lines().filter(|l| l.starts_with('#')).map(|l| l.trim_start_matches('#').trim().to_string()).collect()
}

#[test]
fn the_citation_reader_finds_headings_sections_and_wrapped_ones() {
    let text = folded(
        "/// see docs/method.md, \"Two windowings\"; docs/verification.md 4d and\n/// docs/performance.md\n/// \"The prestress's error\".",
    );
    assert_eq!(
        citations(&text),
        [
            ("docs/method.md".into(), Cited::Heading("Two windowings".into())),
            ("docs/verification.md".into(), Cited::Section("4d".into())),
            ("docs/performance.md".into(), Cited::Heading("The prestress's error".into())),
        ]
    );
    assert!(citations("docs/method.md 2026 docs/x.md").is_empty(), "a year or a bare file is no section");
}

#[test]
fn every_cited_doc_heading_exists() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut files = Vec::new();
    citing_files(&root, &mut files);
    let mut dangling = Vec::new();
    let mut checked = 0;
    // (this file's examples are not citations)
    for file in files.iter().filter(|f| !f.ends_with("tests/smoke/citations.rs")) {
        let Ok(text) = std::fs::read_to_string(file) else { continue };
        for (doc, cited) in citations(&folded(&text)) {
            checked += 1;
            let shown = file.strip_prefix(&root).unwrap_or(file).display().to_string();
            let Ok(target) = std::fs::read_to_string(root.join(&doc)) else {
                dangling.push(format!("{shown}: {doc} does not exist"));
                continue;
            };
            let heads = headings(&target);
            let found = match &cited {
                // a heading cited by its words (headings carry dates and issue numbers besides)
                Cited::Heading(h) => heads.iter().any(|x| x.contains(h.as_str())),
                Cited::Section(n) => {
                    heads.iter().any(|x| x.starts_with(&format!("{n}.")) || x.starts_with(&format!("{n} ")))
                }
            };
            if !found {
                dangling.push(format!("{shown}: {doc} has no heading {cited:?}"));
            }
        }
    }
    eprintln!("{checked} citations in {} files", files.len());
    assert!(checked > 50, "only {checked} citations found: the reader is broken");
    assert!(dangling.is_empty(), "{} citations point nowhere:\n{}", dangling.len(), dangling.join("\n"));
}
