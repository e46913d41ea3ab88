//! Every heading the sources and docs cite exists: a citation `docs/<name>.md, "Heading"` (comma
//! optional, across comment lines too) must name the beginning of a heading of that file (after
//! a section number such as `4.` or `4d.`), a citation `docs/<name>.md 4d` a heading numbered
//! so, and the file must exist. And the README's Architecture table names the crate graph.

use std::path::{Path, PathBuf};

fn repository() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("core/ sits in the repository").to_path_buf()
}

/// Source and doc files of the repository (not target/ or hidden directories).
fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable directory").flatten() {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') || name == "target" || name == "node_modules" {
            continue;
        }
        if path.is_dir() {
            files(&path, out);
        } else if ["rs", "md", "toml", "sh", "py", "proto"].iter().any(|e| name.ends_with(&format!(".{e}"))) {
            out.push(path);
        }
    }
}

/// The text with line breaks and the comment markers that follow them folded into spaces, so a
/// citation wrapped over two comment lines reads as one.
fn folded(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for line in text.lines() {
        let line = line.trim_start();
        let line = ["//!", "///", "//", "#", ">"].iter().find_map(|m| line.strip_prefix(m)).unwrap_or(line);
        out.push_str(line.trim());
        out.push(' ');
    }
    out
}

/// What a citation names in its doc: the beginning of a heading, or a section number.
#[derive(Debug, PartialEq)]
enum Cited {
    Heading(String),
    Section(String),
}

/// (doc file, what is cited) pairs in a text.
fn citations(text: &str) -> Vec<(String, Cited)> {
    let mut found = Vec::new();
    let mut rest = text;
    while let Some(at) = rest.find("docs/") {
        rest = &rest[at + 5..];
        let name: String = rest.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_').collect();
        let after = &rest[name.len()..];
        let Some(after) = after.strip_prefix(".md") else { continue };
        let after = after.strip_prefix(',').unwrap_or(after);
        let Some(after) = after.strip_prefix(' ') else { continue };
        if let Some(quoted) = after.strip_prefix('"') {
            if let Some(end) = quoted.find('"') {
                let heading = quoted[..end].split_whitespace().collect::<Vec<_>>().join(" ");
                found.push((format!("{name}.md"), Cited::Heading(heading)));
            }
            continue;
        }
        // a section number: digits and at most one letter (4, 11, 4d), not a year or a count
        let word: String = after.chars().take_while(|c| c.is_ascii_alphanumeric()).collect();
        let digits = word.chars().take_while(|c| c.is_ascii_digit()).count();
        if (1..=2).contains(&digits)
            && word.len() - digits <= 1
            && word[digits..].chars().all(|c| c.is_ascii_lowercase())
        {
            found.push((format!("{name}.md"), Cited::Section(word)));
        }
    }
    found
}

/// The section numbers of a markdown file's numbered headings (`## 4d. Sliding`: `4d`).
fn sections(text: &str) -> Vec<String> {
    text.lines()
        .filter(|l| l.starts_with('#'))
        .filter_map(|l| l.trim_start_matches('#').trim().split_once(". ").map(|(n, _)| n.to_string()))
        .collect()
}

/// The headings of a markdown file, without their #s and section numbers.
fn headings(text: &str) -> Vec<String> {
    text.lines()
        .filter(|l| l.starts_with('#'))
        .map(|l| {
            let h = l.trim_start_matches('#').trim();
            match h.split_once(' ') {
                Some((n, rest)) if n.ends_with('.') && n.starts_with(|c: char| c.is_ascii_digit()) => rest.to_string(),
                _ => h.to_string(),
            }
        })
        .collect()
}

#[test]
fn every_cited_heading_exists() {
    let root = repository();
    let mut all = Vec::new();
    files(&root, &mut all);
    let mut missing = Vec::new();
    let mut checked = 0;
    for path in &all {
        let Ok(text) = std::fs::read_to_string(path) else { continue };
        for (doc, cited) in citations(&folded(&text)) {
            let Ok(doc_text) = std::fs::read_to_string(root.join("docs").join(&doc)) else {
                missing.push(format!("{}: docs/{doc} does not exist", path.display()));
                continue;
            };
            checked += 1;
            let found = match &cited {
                Cited::Heading(heading) => headings(&doc_text).iter().any(|h| h.starts_with(heading)),
                Cited::Section(number) => sections(&doc_text).contains(number),
            };
            if !found {
                missing.push(format!(
                    "{}: docs/{doc} has no heading {cited:?}",
                    path.strip_prefix(&root).unwrap_or(path).display()
                ));
            }
        }
    }
    assert!(checked > 20, "only {checked} citations found: the scan is broken");
    assert!(missing.is_empty(), "dangling citations:\n{}", missing.join("\n"));
}

#[test]
fn citations_are_found_across_comment_lines() {
    let text = "// see docs/performance.md, \"Locking, and\n    // the static search direction\") and docs/a.md \"B\"";
    assert_eq!(
        citations(&folded(text)),
        vec![
            ("performance.md".to_string(), Cited::Heading("Locking, and the static search direction".to_string())),
            ("a.md".to_string(), Cited::Heading("B".to_string()))
        ]
    );
    assert_eq!(headings("## 4d. Sliding\n### Time windows (x)\ntext"), vec!["Sliding", "Time windows (x)"]);
}

#[test]
fn section_numbers_are_citations_and_years_are_not() {
    let text = "docs/verification.md 4d (and docs/method.md, 3), docs/performance.md 2026 docs/a.md 100 docs/b.md x";
    assert_eq!(
        citations(text),
        vec![
            ("verification.md".to_string(), Cited::Section("4d".to_string())),
            ("method.md".to_string(), Cited::Section("3".to_string()))
        ]
    );
    assert_eq!(sections("## 4d. Sliding\n## 11. The discretisation error\n### Time windows"), vec!["4d", "11"]);
}

/// The glissade crates a crate's `[dependencies]` name (`glissade-core`: `core`), and whether
/// each takes its default features.
fn workspace_dependencies(manifest: &str) -> Vec<(String, bool)> {
    let manifest: toml::Table = toml::from_str(manifest).expect("a Cargo.toml");
    let Some(deps) = manifest.get("dependencies").and_then(|d| d.as_table()) else { return Vec::new() };
    let mut found: Vec<(String, bool)> = deps
        .iter()
        .filter_map(|(name, spec)| {
            // (the CLI's package is `glissade`, its directory `client/`)
            let short = if name == "glissade" { "client" } else { name.strip_prefix("glissade-")? };
            let defaults = spec.get("default-features").and_then(|d| d.as_bool()).unwrap_or(true);
            Some((short.to_string(), defaults))
        })
        .collect();
    found.sort();
    found
}

/// The README's Architecture table says which glissade crates each crate may depend on (its
/// last column up to the first `;`): it names exactly those of the crate's Cargo.toml, and
/// "without `mpi`" exactly where the default features are off.
#[test]
fn the_architecture_table_is_the_crate_graph() {
    let root = repository();
    let readme = std::fs::read_to_string(root.join("README.md")).expect("README.md");
    let table = readme.split("## Architecture").nth(1).expect("an Architecture section");
    let crates = ["proto", "core", "plot", "solver", "worker", "server", "client", "tests"];
    let mut rows = 0;
    for line in table.lines().take_while(|l| !l.starts_with("## ")) {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        let Some(dir) = cells.get(1).and_then(|c| c.strip_prefix('`')).and_then(|c| c.split('/').next()) else {
            continue;
        };
        if !crates.contains(&dir) {
            continue;
        }
        rows += 1;
        let allowed = cells[3].split(';').next().unwrap_or("");
        let mut said: Vec<(String, bool)> = allowed
            .split(',')
            .filter_map(|item| {
                let item = item.trim();
                let name = item.split_whitespace().next()?;
                crates.contains(&name).then(|| (name.to_string(), !item.contains("without `mpi`")))
            })
            .collect();
        said.sort();
        let manifest = std::fs::read_to_string(root.join(dir).join("Cargo.toml")).expect("Cargo.toml");
        assert_eq!(
            said,
            workspace_dependencies(&manifest),
            "README's Architecture row of `{dir}/` against {dir}/Cargo.toml"
        );
    }
    assert_eq!(rows, crates.len(), "a row for every crate");
}

/// The CLI links what talking to a coordinator, drawing and printing take, and nothing of the
/// solver, HDF5, MPI, the database or the web server (issue 50: it linked all of them through
/// `fields` and `demo`, 292 packages): `fields` is glissade-worker's, `demo` runs the service's
/// binaries.
#[test]
fn the_cli_links_no_solver_hdf5_mpi_database_or_web_server() {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args(["tree", "-p", "glissade", "-e", "normal", "--prefix", "none", "--offline"])
        .current_dir(repository())
        .output()
        .expect("cargo tree runs");
    assert!(out.status.success(), "cargo tree: {}", String::from_utf8_lossy(&out.stderr));
    let mut packages: Vec<String> = String::from_utf8(out.stdout)
        .expect("utf-8")
        .lines()
        .map(|l| l.replace(" (*)", "").replace(" (proc-macro)", ""))
        .collect();
    packages.sort();
    packages.dedup();
    for heavy in
        ["glissade-solver", "glissade-worker", "glissade-server", "hdf5", "mpi", "sled", "axum", "faer", "metis"]
    {
        let found: Vec<&String> = packages
            .iter()
            .filter(|p| p.split(' ').next().is_some_and(|n| n == heavy || n.starts_with(&format!("{heavy}-"))))
            .collect();
        assert!(found.is_empty(), "the CLI links {found:?}");
    }
    assert!(packages.len() < 200, "the CLI links {} packages", packages.len());
}

#[test]
fn workspace_dependencies_are_read_with_their_features() {
    let manifest = "[dependencies]\nglissade-core.workspace = true\nserde = \"1\"\n\
        glissade-worker = { path = \"../worker\", default-features = false }\n[dev-dependencies]\nglissade-plot = \"0\"\n";
    assert_eq!(workspace_dependencies(manifest), vec![("core".to_string(), true), ("worker".to_string(), false)]);
}
