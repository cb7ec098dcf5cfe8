//! The crate's modules import each other without a cycle, and `error.rs` imports nothing of
//! the crate (read from the sources: every `crate::<module>` outside comments).

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

/// Each top-level module of `src/` (its submodules under `src/<module>/` included) and the
/// modules of the crate it names.
fn dependencies() -> BTreeMap<String, BTreeSet<String>> {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files: Vec<(String, PathBuf)> = Vec::new();
    for entry in std::fs::read_dir(&src).expect("src/") {
        let path = entry.unwrap().path();
        let module = path.file_stem().unwrap().to_string_lossy().into_owned();
        if path.is_dir() {
            for sub in std::fs::read_dir(&path).expect("a module directory") {
                files.push((module.clone(), sub.unwrap().path()));
            }
        } else if module != "lib" {
            files.push((module, path)); // the root declares and re-exports every module
        }
    }
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (module, path) in files {
        let text = std::fs::read_to_string(&path).expect("a source file");
        let uses = graph.entry(module.clone()).or_default();
        for line in text.lines().filter(|l| !l.trim_start().starts_with("//")) {
            for (at, _) in line.match_indices("crate::") {
                let name: String = line[at + "crate::".len()..]
                    .chars()
                    .take_while(|c| c.is_ascii_lowercase() || *c == '_')
                    .collect();
                if !name.is_empty() && name != module {
                    uses.insert(name);
                }
            }
        }
    }
    graph
}

#[test]
fn modules_import_each_other_without_a_cycle() {
    let graph = dependencies();
    assert!(graph.len() >= 10, "read {graph:?}");
    assert!(
        graph["messages"].contains("checks"),
        "src/messages/ not read: {graph:?}"
    );
    assert_eq!(graph["error"], BTreeSet::new(), "error.rs must be a leaf");
    // Peel off modules whose dependencies are all peeled; what is left holds a cycle.
    let mut left = graph.clone();
    while let Some(leaf) = left
        .iter()
        .find(|(_, uses)| uses.iter().all(|m| !left.contains_key(m)))
        .map(|(module, _)| module.clone())
    {
        left.remove(&leaf);
    }
    assert!(left.is_empty(), "modules in or above a cycle: {left:?}");
}
