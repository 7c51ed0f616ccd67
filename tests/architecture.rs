//! The dependency rules of `docs/architecture.md`, checked on the source text: which top-level
//! module of `src/` uses which (`crate::NAME` anywhere in its production code), and that
//! these edges form no cycle. Test code (`tests.rs` files and everything from a
//! `#[cfg(test)]` module on) may use more, as the page says, and is left out.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

/// Every `.rs` file below `dir`, in a fixed order.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The crate's `src/` directory.
fn src_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file below `dir` but the `tests.rs` files (test code), in a fixed order.
fn production_files(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    rust_files(dir, &mut files);
    files.retain(|f| f.file_name().is_none_or(|n| n != "tests.rs"));
    files
}

/// The production lines of a source file: everything before the first `#[cfg(test)]` that
/// opens a module (test modules stand at the end of a file).
fn production_lines(text: &str) -> Vec<&str> {
    let lines: Vec<&str> = text.lines().collect();
    let end = (0..lines.len())
        .find(|&i| {
            lines[i].trim_start().starts_with("#[cfg(test)]")
                && lines[i + 1..]
                    .iter()
                    .map(|l| l.trim_start())
                    .find(|l| !l.starts_with("#["))
                    .is_some_and(|l| l.starts_with("mod ") || l.starts_with("pub mod "))
        })
        .unwrap_or(lines.len());
    lines[..end].to_vec()
}

/// The production code of a source file without its comment lines.
fn production_code(text: &str) -> String {
    let mut code = String::new();
    for line in production_lines(text) {
        if !line.trim_start().starts_with("//") {
            code.push_str(line);
            code.push('\n');
        }
    }
    code
}

/// The top-level modules named as `crate::NAME` in `code`.
fn crate_uses(code: &str) -> BTreeSet<String> {
    let mut used = BTreeSet::new();
    for (at, _) in code.match_indices("crate::") {
        if at > 0 {
            let before = code.as_bytes()[at - 1];
            if before.is_ascii_alphanumeric() || before == b'_' {
                continue; // `terratile_crate::` or similar, not this crate's root
            }
        }
        let name: String = code[at + "crate::".len()..]
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        if !name.is_empty() {
            used.insert(name);
        }
    }
    used
}

/// Top-level module of `src/` → the other top-level modules its production code uses.
fn module_edges() -> BTreeMap<String, BTreeSet<String>> {
    let src = src_dir();
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for file in production_files(&src) {
        let rel = file.strip_prefix(&src).unwrap();
        let first = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let module = first.trim_end_matches(".rs").to_string();
        let code = production_code(&fs::read_to_string(&file).unwrap());
        let used = edges.entry(module.clone()).or_default();
        used.extend(crate_uses(&code).into_iter().filter(|m| *m != module));
    }
    // Names re-exported at the root (`crate::Error`, `crate::NoProgress`) are not modules.
    let modules: BTreeSet<String> = edges.keys().cloned().collect();
    for used in edges.values_mut() {
        used.retain(|m| modules.contains(m));
    }
    edges
}

/// The cycles among the modules: each strongly connected component of more than one module
/// (Tarjan 1972), its members in order.
fn cycles(edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    struct Walk<'a> {
        edges: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        found: Vec<Vec<String>>,
    }
    impl<'a> Walk<'a> {
        fn visit(&mut self, v: &'a str) {
            let i = self.index.len();
            self.index.insert(v, i);
            self.low.insert(v, i);
            self.stack.push(v);
            for w in self.edges.get(v).into_iter().flatten() {
                let w = w.as_str();
                if !self.index.contains_key(w) {
                    self.visit(w);
                    let l = self.low[v].min(self.low[w]);
                    self.low.insert(v, l);
                } else if self.stack.contains(&w) {
                    let l = self.low[v].min(self.index[w]);
                    self.low.insert(v, l);
                }
            }
            if self.low[v] == self.index[v] {
                let mut component = Vec::new();
                loop {
                    let w = self.stack.pop().unwrap();
                    component.push(w.to_string());
                    if w == v {
                        break;
                    }
                }
                if component.len() > 1 {
                    component.sort();
                    self.found.push(component);
                }
            }
        }
    }
    let mut walk = Walk {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        found: Vec::new(),
    };
    for v in edges.keys() {
        if !walk.index.contains_key(v.as_str()) {
            walk.visit(v);
        }
    }
    walk.found
}

#[test]
fn no_import_cycle_among_top_level_modules() {
    let edges = module_edges();
    let listing: Vec<String> = edges
        .iter()
        .map(|(m, used)| {
            format!(
                "{m}: {}",
                used.iter().cloned().collect::<Vec<_>>().join(", ")
            )
        })
        .collect();
    let found = cycles(&edges);
    assert!(
        found.is_empty(),
        "import cycles among src/ modules: {found:?}\nedges:\n{}",
        listing.join("\n")
    );
}

#[test]
fn the_cycle_check_finds_a_cycle() {
    let edges: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a", "d"]),
        ("d", vec![]),
    ]
    .into_iter()
    .map(|(m, u)| (m.to_string(), u.into_iter().map(String::from).collect()))
    .collect();
    assert_eq!(cycles(&edges), vec![vec!["a", "b", "c"]]);
    let code = "use crate::x::Y;\n// crate::z\nfn f() { crate::w::g() }\n#[cfg(test)]\nmod tests { use crate::v; }\n";
    let used = crate_uses(&production_code(code));
    assert_eq!(used.into_iter().collect::<Vec<_>>(), vec!["w", "x"]);
}

/// The stage functions `code` calls or imports: `terrain::STAGE::name` with `name` in lower
/// case, or `terrain::STAGE` imported whole (types and constants in capitals are products and
/// settings, not stage calls).
fn stage_calls(code: &str) -> Vec<String> {
    const STAGES: [&str; 8] = [
        "denoise", "resample", "fill", "voidfill", "tiles", "quadtree", "extract", "ground",
    ];
    let mut calls = Vec::new();
    for stage in STAGES {
        let path = format!("terrain::{stage}");
        for (at, _) in code.match_indices(&path) {
            let rest = &code[at + path.len()..];
            let called = rest
                .strip_prefix("::")
                .is_some_and(|r| r.starts_with(|c: char| c.is_ascii_lowercase()));
            let whole =
                rest.starts_with(';') || rest.starts_with("::{self") || rest.starts_with(',');
            if called || whole {
                calls.push(path.clone());
            }
        }
    }
    calls
}

#[test]
fn the_encoders_call_no_stage() {
    for file in production_files(&src_dir().join("output")) {
        let code = production_code(&fs::read_to_string(&file).unwrap());
        let calls = stage_calls(&code);
        assert!(
            calls.is_empty(),
            "{} uses the stages {calls:?}",
            file.display()
        );
    }
    assert_eq!(
        stage_calls("use crate::terrain::extract::extract_meshes;\nuse crate::terrain::fill;\n"),
        vec!["terrain::fill", "terrain::extract"]
    );
    assert!(stage_calls("crate::terrain::extract::DEFAULT_TOLERANCE_M").is_empty());
}

/// The functions of `lines` longer than `limit` lines, as (name, first line, lines): from a
/// line opening `fn` to the first later line that closes a block at the same indentation
/// (rustfmt's layout).
fn long_functions(lines: &[&str], limit: usize) -> Vec<(String, usize, usize)> {
    let mut found = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let t = line.trim_start();
        let indent = &line[..line.len() - t.len()];
        let mut words = t
            .split_whitespace()
            .skip_while(|w| w.starts_with("pub") || ["const", "async", "unsafe"].contains(w));
        // One-line functions and declarations without a body are short.
        if words.next() != Some("fn") || t.ends_with('}') || t.ends_with(';') {
            continue;
        }
        let name: String = words
            .next()
            .unwrap_or("")
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        let close = |l: &&str| {
            l.strip_prefix(indent)
                .is_some_and(|r| ["}", "};", "})", "},"].contains(&r.trim_end()))
        };
        if let Some(end) = lines[i + 1..].iter().position(close) {
            let n = end + 2;
            if n > limit {
                found.push((name, i + 1, n));
            }
        }
    }
    found
}

#[test]
fn no_function_over_150_lines_outside_tests() {
    let mut long = Vec::new();
    for file in production_files(&src_dir()) {
        let text = fs::read_to_string(&file).unwrap();
        for (name, line, n) in long_functions(&production_lines(&text), 150) {
            long.push(format!("{}:{line} {name}: {n} lines", file.display()));
        }
    }
    assert!(
        long.is_empty(),
        "functions over 150 lines:\n{}",
        long.join("\n")
    );
    let body: Vec<String> = (0..151).map(|i| format!("    let a{i} = {i};")).collect();
    let text = format!(
        "pub(crate) fn long() {{\n{}\n}}\nfn short() {{\n}}\n",
        body.join("\n")
    );
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(
        long_functions(&lines, 150),
        vec![("long".to_string(), 1, 153)]
    );
}
