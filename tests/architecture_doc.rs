//! docs/architecture.md against the tree: every `src/` path the page names exists, every folder
//! of `src/` is named in its "Where things live" table, and every source file is named there
//! (by its path, or by its file name in its folder's row).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The page's text.
fn page() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/architecture.md"))
        .expect("docs/architecture.md is there")
}

/// The code spans (`...`) of `text`.
fn code_spans(text: &str) -> Vec<&str> {
    text.split('`').skip(1).step_by(2).collect()
}

/// Every file and folder under `src/`, relative to the crate root (`src/sim/`, `src/sim/guards.rs`).
fn tree() -> (BTreeSet<String>, BTreeSet<String>) {
    fn walk(root: &Path, dir: &Path, folders: &mut BTreeSet<String>, files: &mut BTreeSet<String>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            let rel = path.strip_prefix(root).unwrap().to_string_lossy().replace('\\', "/");
            if path.is_dir() {
                folders.insert(format!("{rel}/"));
                walk(root, &path, folders, files);
            } else if rel.ends_with(".rs") {
                files.insert(rel);
            }
        }
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let (mut folders, mut files) = (BTreeSet::new(), BTreeSet::new());
    walk(&root, &root.join("src"), &mut folders, &mut files);
    (folders, files)
}

/// The rows of the "Where things live" table: (the path cell's code spans, the description).
fn table_rows(text: &str) -> Vec<(Vec<String>, String)> {
    let start = text.find("## Where things live").expect("the page has its table");
    let section = &text[start..];
    let end = section[3..].find("\n## ").map_or(section.len(), |i| i + 3);
    section[..end]
        .lines()
        .filter(|l| l.starts_with("| `"))
        .map(|l| {
            let cells: Vec<&str> = l.split(" | ").collect();
            let paths = code_spans(cells[0]).into_iter().map(String::from).collect();
            (paths, cells[1..].join(" | "))
        })
        .collect()
}

#[test]
fn every_src_path_the_page_names_exists() {
    let text = page();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let missing: Vec<&str> = code_spans(&text)
        .into_iter()
        .filter(|s| s.starts_with("src/") && !s.contains("NAME") && !s.contains(' '))
        .filter(|s| !root.join(s).exists())
        .collect();
    assert!(missing.is_empty(), "docs/architecture.md names paths that are not in the tree: {missing:?}");
}

#[test]
fn every_folder_and_file_of_src_is_in_the_table() {
    let text = page();
    let rows = table_rows(&text);
    assert!(rows.len() > 10, "the table has its rows");
    let (folders, files) = tree();
    let named: BTreeSet<&str> = rows.iter().flat_map(|(paths, _)| paths.iter().map(String::as_str)).collect();
    let unnamed: Vec<&String> = folders.iter().filter(|f| !named.contains(f.as_str())).collect();
    assert!(unnamed.is_empty(), "folders of src/ the table does not name: {unnamed:?}");

    // a file is named by its path in a row's path cell, or by its name in the description of its
    // folder's row (`mod.rs` of a folder the table names counts as named by its folder)
    let in_folder_row = |file: &str| {
        let (folder, name) = file.rsplit_once('/').map(|(d, n)| (format!("{d}/"), n)).unwrap();
        rows.iter().any(|(paths, description)| {
            paths.contains(&folder)
                && (name == "mod.rs"
                    || code_spans(description).iter().any(|s| *s == name || s.ends_with(&format!("/{name}"))))
        })
    };
    let unlisted: Vec<&String> =
        files.iter().filter(|f| !named.contains(f.as_str()) && !in_folder_row(f)).collect();
    assert!(unlisted.is_empty(), "source files the table does not name: {unlisted:?}");

    // and every file a folder's row names is in that folder
    for (paths, description) in &rows {
        let [folder] = paths.as_slice() else { continue };
        if !folder.ends_with('/') {
            continue;
        }
        for span in code_spans(description) {
            if span.ends_with(".rs") && !span.contains('/') && !span.contains("NAME") {
                let path = format!("{folder}{span}");
                assert!(files.contains(&path), "the row of {folder} names {span}, which is not there");
            }
        }
    }
}
