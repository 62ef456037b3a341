//! Declared dependencies that nothing uses: each member's `[dependencies]` must be named in its
//! `src/`, each `[dev-dependencies]` entry in its sources, tests, examples or benches, and each
//! `[workspace.dependencies]` entry must be declared by some member.

#[cfg(test)]
mod tests {
    use std::path::{Path, PathBuf};

    fn root() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
    }

    fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else { return };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                rust_files(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }

    /// Whether `ident` occurs as a whole word in the Rust files under `dirs` of `member`.
    fn mentioned(member: &Path, dirs: &[&str], ident: &str) -> bool {
        let mut files = vec![];
        for d in dirs {
            rust_files(&member.join(d), &mut files);
        }
        files.iter().any(|f| {
            let text = std::fs::read_to_string(f).unwrap_or_default();
            text.match_indices(ident).any(|(i, _)| {
                let before = text[..i].chars().next_back();
                let after = text[i + ident.len()..].chars().next();
                let word = |c: Option<char>| c.is_some_and(|c| c.is_alphanumeric() || c == '_');
                !word(before) && !word(after)
            })
        })
    }

    fn members() -> Vec<PathBuf> {
        let mut m: Vec<PathBuf> =
            std::fs::read_dir(root().join("crates")).unwrap().flatten().map(|e| e.path()).collect();
        m.push(root().join("xtask"));
        m.sort();
        m
    }

    fn manifest(dir: &Path) -> toml::Table {
        toml::from_str(&std::fs::read_to_string(dir.join("Cargo.toml")).unwrap()).unwrap()
    }

    #[test]
    fn every_declared_dependency_is_used() {
        let mut unused = vec![];
        let mut declared = std::collections::BTreeSet::new();
        for member in members() {
            let m = manifest(&member);
            for (table, dirs) in
                [("dependencies", &["src"][..]), ("dev-dependencies", &["src", "tests", "examples", "benches"][..])]
            {
                for name in m.get(table).and_then(|t| t.as_table()).into_iter().flat_map(|t| t.keys()) {
                    declared.insert(name.clone());
                    if !mentioned(&member, dirs, &name.replace('-', "_")) {
                        unused.push(format!("{}: [{table}] {name}", member.display()));
                    }
                }
            }
        }
        let workspace = manifest(&root());
        for name in workspace["workspace"]["dependencies"].as_table().unwrap().keys() {
            if !declared.contains(name) {
                unused.push(format!("Cargo.toml: [workspace.dependencies] {name} (no member declares it)"));
            }
        }
        assert!(unused.is_empty(), "declared but unused:\n{}", unused.join("\n"));
    }

    #[test]
    fn no_dependency_is_declared_twice_in_one_member() {
        for member in members() {
            let m = manifest(&member);
            let normal: Vec<&String> =
                m.get("dependencies").and_then(|t| t.as_table()).map_or(vec![], |t| t.keys().collect());
            if let Some(dev) = m.get("dev-dependencies").and_then(|t| t.as_table()) {
                for name in dev.keys() {
                    assert!(
                        !normal.contains(&name),
                        "{}: {name} is both a dependency and a dev-dependency",
                        member.display()
                    );
                }
            }
        }
    }
}
