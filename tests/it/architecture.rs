//! docs/ARCHITECTURE.md names files and types; each one must exist where the document puts it,
//! so that the code map cannot drift from the code.
//!
//! A backticked token is checked when it looks like a path (`crates/gather/src/render.rs`,
//! `src/solution/`, or `render.rs` inside a crate's section) or a type (`CamelCase`, checked
//! to be declared as a struct, enum, trait or type alias in the section's crate, or anywhere
//! in the workspace for the sections that span crates).

use crate::fixtures::root;
use std::fs;
use std::path::{Path, PathBuf};

/// Every `.rs` file below `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            if path.file_name().is_some_and(|n| n == "target") {
                continue;
            }
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The document's sections (`### \`crates/x\`` or `### \`src/\``) with the directory each
/// names; text before the first such heading belongs to the whole workspace.
fn sections(doc: &str) -> Vec<(Option<PathBuf>, String)> {
    let mut out: Vec<(Option<PathBuf>, String)> = vec![(None, String::new())];
    for line in doc.lines() {
        if let Some(rest) = line.strip_prefix("### `") {
            let name = rest.split('`').next().unwrap_or("").trim_end_matches('/');
            out.push((Some(root().join(name)), String::new()));
        } else if line.starts_with("## ") {
            out.push((None, String::new()));
        }
        let last = out.last_mut().unwrap();
        last.1.push_str(line);
        last.1.push('\n');
    }
    out
}

fn backticked(text: &str) -> Vec<String> {
    text.split('`')
        .enumerate()
        .filter(|(i, _)| i % 2 == 1)
        .map(|(_, t)| t.to_string())
        .collect()
}

fn looks_like_path(token: &str) -> bool {
    !token.contains(' ')
        && !token.contains("::")
        && (token.ends_with(".rs")
            || token.ends_with(".md")
            || token.ends_with(".toml")
            || token.ends_with(".html")
            || token.ends_with(".json")
            || (token.ends_with('/') && token.len() > 1))
}

fn looks_like_type(token: &str) -> bool {
    let mut chars = token.chars();
    chars.next().is_some_and(|c| c.is_ascii_uppercase())
        && token.chars().all(|c| c.is_ascii_alphanumeric())
        && token.chars().any(|c| c.is_ascii_lowercase())
        && token.len() > 2
}

/// Standard-library traits and types the document may name.
const STD: [&str; 7] = [
    "FromStr", "Display", "Default", "Vec", "String", "Option", "Arc",
];

/// Whether `source` declares `name` as a struct, enum, trait, type alias or enum variant.
fn declares(source: &str, name: &str) -> bool {
    let variant = source.lines().any(|line| {
        let line = line.trim_start();
        line.strip_prefix(name)
            .and_then(|rest| rest.chars().next())
            .is_some_and(|c| matches!(c, ' ' | '{' | '(' | ','))
            && !line.starts_with("//")
    });
    variant
        || ["struct", "enum", "trait", "type"].iter().any(|kind| {
            source
                .match_indices(&format!("{kind} {name}"))
                .any(|(i, _)| {
                    let after = source[i + kind.len() + 1 + name.len()..].chars().next();
                    !after.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_')
                })
        })
}

#[test]
fn every_path_and_type_in_architecture_md_exists() {
    let doc = fs::read_to_string(root().join("docs/ARCHITECTURE.md")).unwrap();
    let (missing, checked) = missing_names(&doc);
    assert!(
        missing.is_empty(),
        "ARCHITECTURE.md names what does not exist: {missing:#?}"
    );
    // The document does name files and types: a parser that matched nothing would pass vacuously.
    assert!(checked.0 >= 20 && checked.1 >= 20, "checked {checked:?}");
}

/// The paths and types a document names that do not exist, and how many of each it checked.
fn missing_names(doc: &str) -> (Vec<String>, (usize, usize)) {
    let mut all_files = Vec::new();
    rust_files(&root().join("crates"), &mut all_files);
    rust_files(&root().join("src"), &mut all_files);
    let all_source: String = all_files
        .iter()
        .map(|p| fs::read_to_string(p).unwrap())
        .collect();
    let mut missing = Vec::new();
    let mut checked = (0, 0);
    for (dir, text) in sections(doc) {
        let (files, source) = match &dir {
            Some(d) => {
                let mut files = Vec::new();
                rust_files(d, &mut files);
                let source: String = files
                    .iter()
                    .map(|p| fs::read_to_string(p).unwrap())
                    .collect();
                (files, source)
            }
            None => (all_files.clone(), all_source.clone()),
        };
        for token in backticked(&text) {
            if looks_like_path(&token) {
                checked.0 += 1;
                let rel = token.trim_end_matches('/');
                let found = root().join(rel).exists()
                    || dir.as_ref().is_some_and(|d| {
                        d.join(rel).exists()
                            || d.join("src").join(rel).exists()
                            || (!rel.contains('/')
                                && files.iter().any(|f| f.file_name().unwrap() == rel))
                            || (rel.contains('/')
                                && files.iter().any(|f| {
                                    f.ends_with(rel) || f.starts_with(d.join("src").join(rel))
                                }))
                    });
                if !found {
                    missing.push(format!(
                        "path {token} ({})",
                        dir.as_ref()
                            .map_or("workspace".into(), |d| d.display().to_string())
                    ));
                }
            } else if looks_like_type(&token) {
                checked.1 += 1;
                if !STD.contains(&token.as_str())
                    && !declares(&source, &token)
                    && !declares(&all_source, &token)
                {
                    missing.push(format!("type {token}"));
                }
            }
        }
    }
    (missing, checked)
}

#[test]
fn the_checker_refuses_what_does_not_exist() {
    // A section naming real and invented files and types: only the invented ones are reported.
    let doc = "### `crates/scene`\n\n`sections.rs` and `no_such_file.rs`; `SceneError` and \
               `NoSuchType`; `src/engine/pipeline.rs` and `src/no_such_dir/`.\n";
    let (missing, checked) = missing_names(doc);
    assert_eq!(checked, (4, 2));
    assert_eq!(
        missing.len(),
        3,
        "expected no_such_file.rs, src/no_such_dir/ and NoSuchType: {missing:?}"
    );
    assert!(missing.iter().any(|m| m.contains("no_such_file.rs")));
    assert!(missing.iter().any(|m| m.contains("no_such_dir")));
    assert!(missing.iter().any(|m| m.contains("NoSuchType")));
    assert!(looks_like_path("src/solution/records.rs"));
    assert!(looks_like_type("SolveMethod"));
    assert!(!looks_like_type("I0"));
    assert!(declares("pub enum SolveMethod {", "SolveMethod"));
    assert!(!declares("pub enum SolveMethodX {", "SolveMethod"));
    assert!(declares(
        "enum M {\n    CoarseCorrected { inner: S },\n}",
        "CoarseCorrected"
    ));
    assert!(!declares("// CoarseCorrected {", "CoarseCorrected"));
}
