//! The code's citations of the design documents resolve: every `ALGORITHMS.md §n` (and `§n.m`)
//! names a section of docs/ALGORITHMS.md, and every heading quoted after DESIGN.md is one of
//! docs/DESIGN.md's, so a reader can follow each one.

use std::path::{Path, PathBuf};

fn sources() -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut dirs = vec![
        PathBuf::from("src"),
        PathBuf::from("tests"),
        PathBuf::from("benches"),
        PathBuf::from("shaders"),
    ];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                dirs.push(path);
            } else if matches!(
                path.extension().and_then(|e| e.to_str()),
                Some("rs" | "wgsl" | "html" | "js")
            ) {
                out.push(path);
            }
        }
    }
    out
}

/// The headings of a markdown file, without their `#`s.
fn headings(doc: &Path) -> Vec<String> {
    std::fs::read_to_string(doc)
        .unwrap()
        .lines()
        .filter(|l| l.starts_with('#'))
        .map(|l| l.trim_start_matches('#').trim().to_string())
        .collect()
}

/// Every `ALGORITHMS.md §n` or `§n.m` after the file name, and every `§n–m` range's ends.
fn section_numbers(text: &str) -> Vec<(String, usize)> {
    let mut out = Vec::new();
    for (line_no, line) in text.lines().enumerate() {
        let Some(at) = line.find("ALGORITHMS.md") else {
            continue;
        };
        let rest = &line[at..];
        for part in rest.split('§').skip(1) {
            let num: String = part
                .chars()
                .take_while(|c| c.is_ascii_digit() || *c == '.')
                .collect();
            let num = num.trim_end_matches('.').to_string();
            let rest = &part[num.len()..];
            if !num.is_empty() {
                out.push((num, line_no + 1));
            }
            // A range such as §2–3.
            if let Some(end) = rest.strip_prefix('–') {
                let n: String = end.chars().take_while(|c| c.is_ascii_digit()).collect();
                if !n.is_empty() {
                    out.push((n, line_no + 1));
                }
            }
        }
    }
    out
}

#[test]
fn algorithms_citations_resolve() {
    let sections = headings(Path::new("docs/ALGORITHMS.md"));
    let has = |n: &str| {
        sections
            .iter()
            .any(|h| h.starts_with(&format!("{n} ")) || h.starts_with(&format!("{n}. ")))
    };
    let mut missing = Vec::new();
    let mut cited = 0;
    for file in sources() {
        let text = std::fs::read_to_string(&file).unwrap();
        for (n, line) in section_numbers(&text) {
            cited += 1;
            if !has(&n) {
                missing.push(format!("{}:{line}: §{n}", file.display()));
            }
        }
    }
    assert!(
        cited > 50,
        "only {cited} citations found: the scan is broken"
    );
    assert!(
        missing.is_empty(),
        "citations without a section in docs/ALGORITHMS.md:\n{}",
        missing.join("\n")
    );
}

#[test]
fn design_citations_resolve() {
    let sections = headings(Path::new("docs/DESIGN.md"));
    let mut missing = Vec::new();
    let mut cited = 0;
    for file in sources() {
        let text = std::fs::read_to_string(&file).unwrap();
        for (line_no, line) in text.lines().enumerate() {
            let Some(at) = line.find("DESIGN.md") else {
                continue;
            };
            let rest = line[at + "DESIGN.md".len()..].trim_start_matches([',', ' ']);
            let Some(quoted) = rest.strip_prefix('"') else {
                continue;
            };
            let Some(end) = quoted.find('"') else {
                continue;
            };
            let name = &quoted[..end];
            cited += 1;
            let found = sections
                .iter()
                .any(|h| h.to_lowercase().contains(&name.to_lowercase()));
            if !found {
                missing.push(format!("{}:{}: \"{name}\"", file.display(), line_no + 1));
            }
        }
    }
    assert!(
        cited > 5,
        "only {cited} citations found: the scan is broken"
    );
    assert!(
        missing.is_empty(),
        "citations without a heading in docs/DESIGN.md:\n{}",
        missing.join("\n")
    );
}
