//! Reads what `src/metis.rs` must agree on with the system's METIS from its `metis.h` (Debian's
//! libmetis-dev, `deploy/install-deps.sh`): the index width, the length of the options array and
//! where the two options glissade sets sit in it (METIS 5.2 moved them one place from 5.1). A
//! METIS elsewhere: `METIS_DIR` (its `include/` and `lib/`).

use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-env-changed=METIS_DIR");
    let mut includes = vec![PathBuf::from("/usr/include"), PathBuf::from("/usr/local/include")];
    if let Some(dir) = std::env::var_os("METIS_DIR").map(PathBuf::from) {
        println!("cargo:rustc-link-search=native={}", dir.join("lib").display());
        includes.insert(0, dir.join("include"));
    }
    let Some(header) = includes.iter().map(|d| d.join("metis.h")).find(|h| h.is_file()) else {
        fail(
            "metis.h not found in /usr/include or /usr/local/include: install libmetis-dev (deploy/install-deps.sh) or set METIS_DIR",
        )
    };
    println!("cargo:rerun-if-changed={}", header.display());
    let text = std::fs::read_to_string(&header).unwrap_or_else(|e| fail(&format!("{}: {e}", header.display())));
    let width = define(&text, "IDXTYPEWIDTH");
    let noptions = define(&text, "METIS_NOPTIONS");
    let options = options_enum(&text);
    let place =
        |name: &str| options.iter().position(|o| o == name).unwrap_or_else(|| fail(&format!("metis.h has no {name}")));
    let idx = match width {
        32 => "i32",
        64 => "i64",
        w => fail(&format!("metis.h: IDXTYPEWIDTH {w}")),
    };
    let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR")).join("metis_h.rs");
    let code = format!(
        "// from {}\npub type Idx = {idx};\nconst NOPTIONS: usize = {noptions};\nconst OPTION_SEED: usize = {};\nconst OPTION_CONTIG: usize = {};\n",
        header.display(),
        place("METIS_OPTION_SEED"),
        place("METIS_OPTION_CONTIG"),
    );
    std::fs::write(&out, code).unwrap_or_else(|e| fail(&format!("{}: {e}", out.display())));
}

fn fail(why: &str) -> ! {
    eprintln!("glissade-solver: {why}");
    std::process::exit(1);
}

/// The value of `#define NAME value`.
fn define(text: &str, name: &str) -> usize {
    text.lines()
        .filter_map(|l| l.trim().strip_prefix("#define"))
        .find_map(|l| {
            let mut words = l.split_whitespace();
            (words.next() == Some(name)).then(|| words.next()?.parse().ok())?
        })
        .unwrap_or_else(|| fail(&format!("metis.h has no #define {name} with a number")))
}

/// The names of `enum { ... } moptions_et`, in order (their values are their places).
fn options_enum(text: &str) -> Vec<String> {
    let end = text.find("} moptions_et;").unwrap_or_else(|| fail("metis.h has no moptions_et"));
    let start = text[..end].rfind('{').unwrap_or_else(|| fail("metis.h: moptions_et has no opening brace"));
    let mut body = String::new();
    let mut rest = &text[start + 1..end];
    // comments out
    while let Some(open) = rest.find("/*") {
        body.push_str(&rest[..open]);
        rest = rest[open..].find("*/").map_or("", |close| &rest[open + close + 2..]);
    }
    body.push_str(rest);
    let names: Vec<String> = body.split(',').map(|n| n.trim().to_owned()).filter(|n| !n.is_empty()).collect();
    if names.iter().any(|n| n.contains('=')) {
        fail("metis.h: moptions_et gives values of its own");
    }
    names
}
