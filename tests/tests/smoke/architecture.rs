//! The architecture's rules that the compiler does not see (docs/design.md): one wire schema,
//! one interface law, a light CLI. Read from the sources and from `cargo tree`.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Every `.rs` file under the library and binary crates' `src/` (the end-to-end tests, which
/// play hostile clients with messages of their own, are not the product).
fn product_sources() -> Vec<(PathBuf, String)> {
    let mut out = Vec::new();
    let mut dirs: Vec<PathBuf> = ["proto", "core", "plot", "server", "solver", "worker", "client"]
        .iter()
        .map(|c| root().join(c).join("src"))
        .collect();
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
            let path = entry.expect("a directory entry").path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|x| x == "rs") {
                let text = std::fs::read_to_string(&path).expect("a source file");
                out.push((path, text));
            }
        }
    }
    assert!(out.len() > 100, "found only {} sources under {}", out.len(), root().display());
    out
}

/// Wire messages are declared in `proto/proto/*.proto` (the API, and the job rank 0 sends the
/// other ranks of a pool), never by hand beside them (issue 50, item 1: the ranks' job was).
#[test]
fn wire_messages_are_declared_in_the_proto_files_only() {
    let by_hand: Vec<String> = product_sources()
        .into_iter()
        .filter(|(_, text)| text.contains("prost::Message)") || text.contains("prost::Oneof)"))
        .map(|(path, _)| path.display().to_string())
        .collect();
    assert!(by_hand.is_empty(), "prost messages declared by hand in {by_hand:?}");
}

/// An interface law at a design point has one type, made in one place (docs/design.md 1; core's
/// `LawValues` and the solver's `InterfaceLaw` were two enums of one shape).
#[test]
fn an_interface_law_has_one_type() {
    let sources = product_sources();
    let declared: Vec<String> = sources
        .iter()
        .filter(|(_, text)| text.contains("pub enum InterfaceLaw"))
        .map(|(path, _)| path.display().to_string())
        .collect();
    assert_eq!(declared.len(), 1, "InterfaceLaw declared in {declared:?}");
    assert!(declared[0].ends_with("core/src/contact.rs"), "{declared:?}");
    let makers = sources.iter().filter(|(_, text)| text.contains("pub fn interface_law(")).count();
    assert_eq!(makers, 1, "interface_law defined {makers} times");
}

/// The `glissade` CLI links no HDF5, sled, axum or faer (issue 50, item 3): those are the
/// worker's and the server's.
#[test]
fn the_cli_links_no_hdf5_sled_axum_or_faer() {
    let out = Command::new(env!("CARGO"))
        .current_dir(root())
        .args(["tree", "-p", "glissade", "-e", "normal", "--prefix", "none", "--offline"])
        .output()
        .expect("run cargo tree");
    assert!(out.status.success(), "cargo tree: {}", String::from_utf8_lossy(&out.stderr));
    let tree = String::from_utf8_lossy(&out.stdout);
    let packages: std::collections::BTreeSet<&str> = tree.lines().filter_map(|l| l.split_whitespace().next()).collect();
    for heavy in ["hdf5", "hdf5-sys", "sled", "axum", "faer"] {
        assert!(!packages.contains(heavy), "the CLI links {heavy}");
    }
    assert!(packages.len() < 250, "the CLI links {} packages", packages.len());
}
