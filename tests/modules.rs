//! The modules of `src/` import one way: no module imports a module that imports it back, directly
//! or through a chain, neither between files (`lights::kmeans` → `lights::light`) nor between the
//! top-level stages (`capture` → `sky`). DESIGN.md "The pipeline" and "Layout": one module per
//! pipeline stage, data flowing one way, each stage depending only on the stages above it, so a
//! reader can read the stages in order and a stage can be changed without reading the ones below.
//!
//! The scan reads the sources as text (std only, no parser crate): comments, string and char
//! literals and `#[cfg(test)] mod tests { … }` blocks are blanked out (unit tests may reach
//! anywhere); `pub(crate)`, `pub(super)`, `pub(in …)` are visibility, not imports. A module's
//! imports are its paths starting with `crate::`, `super::` or `self::` (grouped `use crate::{a,
//! b::c}` forms included) and its bare paths `child::` to a child declared with `mod child;` in
//! the same file; each resolves to the longest module (file) that exists. `src/main.rs` is the
//! binary's own crate (it reaches the library as `vemlight::`), so it is not scanned.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::{Path, PathBuf};

/// Every module of the library: `a::b` for `src/a/b.rs` or `src/a/b/mod.rs`, `""` for lib.rs.
fn modules() -> BTreeMap<String, PathBuf> {
    let root = Path::new("src");
    let mut out = BTreeMap::new();
    let mut dirs = vec![root.to_path_buf()];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                dirs.push(path);
                continue;
            }
            if path.extension().and_then(|e| e.to_str()) != Some("rs")
                || path == root.join("main.rs")
            {
                continue;
            }
            let mut parts: Vec<String> = path
                .strip_prefix(root)
                .unwrap()
                .with_extension("")
                .iter()
                .map(|p| p.to_str().unwrap().to_string())
                .collect();
            if matches!(parts.last().map(String::as_str), Some("mod" | "lib")) {
                parts.pop();
            }
            out.insert(parts.join("::"), path);
        }
    }
    out
}

/// The source with comments and the contents of string and char literals replaced by spaces
/// (newlines kept), so braces and paths inside them are not read as code.
fn code_only(text: &str) -> String {
    let c: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let blank = |out: &mut String, ch: char| out.push(if ch == '\n' { '\n' } else { ' ' });
    let mut i = 0;
    while i < c.len() {
        let at = |k: usize| c.get(k).copied().unwrap_or('\0');
        if c[i] == '/' && at(i + 1) == '/' {
            while i < c.len() && c[i] != '\n' {
                blank(&mut out, c[i]);
                i += 1;
            }
        } else if c[i] == '/' && at(i + 1) == '*' {
            let mut depth = 0;
            while i < c.len() {
                if c[i] == '/' && at(i + 1) == '*' {
                    depth += 1;
                    out.push_str("  ");
                    i += 2;
                } else if c[i] == '*' && at(i + 1) == '/' {
                    depth -= 1;
                    out.push_str("  ");
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    blank(&mut out, c[i]);
                    i += 1;
                }
            }
        } else if (c[i] == 'r' || (c[i] == 'b' && at(i + 1) == 'r'))
            && !is_ident(at(i.wrapping_sub(1)))
            && {
                let mut k = i + if c[i] == 'b' { 2 } else { 1 };
                while at(k) == '#' {
                    k += 1;
                }
                at(k) == '"'
            }
        {
            // Raw string: r"…", r#"…"#, br"…".
            let mut k = i + if c[i] == 'b' { 2 } else { 1 };
            let mut hashes = 0;
            while at(k) == '#' {
                hashes += 1;
                k += 1;
            }
            out.extend(std::iter::repeat_n(' ', k + 1 - i));
            i = k + 1;
            while i < c.len() {
                if c[i] == '"' && (1..=hashes).all(|h| at(i + h) == '#') {
                    out.extend(std::iter::repeat_n(' ', hashes + 1));
                    i += hashes + 1;
                    break;
                }
                blank(&mut out, c[i]);
                i += 1;
            }
        } else if c[i] == '"' {
            out.push(' ');
            i += 1;
            while i < c.len() && c[i] != '"' {
                let n = if c[i] == '\\' { 2 } else { 1 };
                for _ in 0..n {
                    if i < c.len() {
                        blank(&mut out, c[i]);
                        i += 1;
                    }
                }
            }
            out.push(' ');
            i += 1;
        } else if c[i] == '\'' && (at(i + 1) == '\\' || at(i + 2) == '\'') {
            // A char literal ('x', '\n', '\''); a lifetime ('a) is left alone.
            let mut k = if at(i + 1) == '\\' { i + 3 } else { i + 2 };
            while k < c.len() && c[k] != '\'' {
                k += 1;
            }
            out.extend(std::iter::repeat_n(' ', k + 1 - i));
            i = k + 1;
        } else {
            out.push(c[i]);
            i += 1;
        }
    }
    out
}

fn is_ident(ch: char) -> bool {
    ch.is_ascii_alphanumeric() || ch == '_'
}

/// The code with every `#[cfg(test)] mod tests { … }` block blanked out.
fn without_unit_tests(code: &str) -> String {
    let mut out = code.to_string();
    let mut from = 0;
    while let Some(found) = out[from..].find("#[cfg(test)]") {
        let start = from + found;
        let rest = &out[start + "#[cfg(test)]".len()..];
        let body = rest.trim_start();
        let Some(after) = body.strip_prefix("mod tests") else {
            from = start + 1;
            continue;
        };
        let Some(open) = after.trim_start().strip_prefix('{') else {
            from = start + 1;
            continue;
        };
        let mut end = out.len() - open.len();
        let mut depth = 1;
        for (k, ch) in open.char_indices() {
            match ch {
                '{' => depth += 1,
                '}' => depth -= 1,
                _ => {}
            }
            if depth == 0 {
                end = out.len() - open.len() + k + 1;
                break;
            }
        }
        let blanked: String = out[start..end]
            .chars()
            .map(|ch| if ch == '\n' { '\n' } else { ' ' })
            .collect();
        out.replace_range(start..end, &blanked);
        from = start + blanked.len();
    }
    out
}

/// The code with `pub(crate)`, `pub(super)`, `pub(self)` and `pub(in …)` written as `pub`.
fn without_restricted_visibility(code: &str) -> String {
    let mut out = String::with_capacity(code.len());
    let mut rest = code;
    while let Some(at) = rest.find("pub(") {
        let boundary = !rest[..at].ends_with(|ch: char| is_ident(ch));
        let close = rest[at..].find(')').map(|k| at + k);
        out.push_str(&rest[..at + 3]);
        match close {
            Some(close) if boundary => {
                out.extend(std::iter::repeat_n(' ', close + 1 - (at + 3)));
                rest = &rest[close + 1..];
            }
            _ => rest = &rest[at + 3..],
        }
    }
    out.push_str(rest);
    out
}

/// A use tree read from `c[*i..]`: a path, then optionally `::{…}` (recursively) or `::*`.
/// Pushes every full path it names onto `out`; `self` inside a group names the group's prefix.
fn use_tree(c: &[char], i: &mut usize, prefix: &[String], out: &mut Vec<Vec<String>>) {
    let skip_ws = |i: &mut usize| {
        while *i < c.len() && c[*i].is_whitespace() {
            *i += 1;
        }
    };
    let mut path = prefix.to_vec();
    let mut named = false;
    loop {
        skip_ws(i);
        if *i < c.len() && c[*i] == '{' {
            *i += 1;
            loop {
                skip_ws(i);
                if *i >= c.len() {
                    return;
                }
                if c[*i] == '}' {
                    *i += 1;
                    return;
                }
                if c[*i] == ',' {
                    *i += 1;
                    continue;
                }
                let before = *i;
                use_tree(c, i, &path, out);
                if *i == before {
                    *i += 1;
                }
            }
        }
        let start = *i;
        while *i < c.len() && is_ident(c[*i]) {
            *i += 1;
        }
        if *i == start {
            break;
        }
        let seg: String = c[start..*i].iter().collect();
        named = true;
        if seg != "self" || path.is_empty() {
            path.push(seg);
        }
        skip_ws(i);
        if c.get(*i) == Some(&':') && c.get(*i + 1) == Some(&':') {
            *i += 2;
            continue;
        }
        break;
    }
    // `… as name`: the alias is not a path.
    skip_ws(i);
    if c.get(*i..*i + 3) == Some(&['a', 's', ' ']) {
        *i += 3;
        skip_ws(i);
        while *i < c.len() && is_ident(c[*i]) {
            *i += 1;
        }
    }
    if named {
        out.push(path);
    }
}

/// Every path in `code` that starts with `crate::`, `super::` or `self::`, as segments.
fn rooted_paths(code: &str) -> Vec<Vec<String>> {
    let c: Vec<char> = code.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < c.len() {
        if !is_ident(c[i]) || (i > 0 && (is_ident(c[i - 1]) || c[i - 1] == ':')) {
            i += 1;
            continue;
        }
        let start = i;
        while i < c.len() && is_ident(c[i]) {
            i += 1;
        }
        let word: String = c[start..i].iter().collect();
        if matches!(word.as_str(), "crate" | "super" | "self")
            && c.get(i) == Some(&':')
            && c.get(i + 1) == Some(&':')
        {
            let mut k = start;
            use_tree(&c, &mut k, &[], &mut out);
            i = k.max(i);
        }
    }
    out
}

/// The children a file declares with `mod child;` (any visibility, any attributes).
fn declared_children(code: &str) -> Vec<String> {
    let words: Vec<&str> = code
        .split(|ch: char| !is_ident(ch) && ch != ';')
        .filter(|w| !w.is_empty())
        .collect();
    words
        .windows(2)
        .filter(|w| w[0] == "mod" && w[1].ends_with(';'))
        .map(|w| w[1].trim_end_matches(';').to_string())
        .filter(|name| !name.is_empty() && !name.contains(';'))
        .collect()
}

/// Does `code` use a bare path `name::` (not itself after `::` or part of a longer name)?
fn uses_bare(code: &str, name: &str) -> bool {
    let needle = format!("{name}::");
    code.match_indices(&needle)
        .any(|(at, _)| !code[..at].ends_with(|ch: char| is_ident(ch) || ch == ':'))
}

/// The module a path from module `cur` names: the longest prefix that is a module of `mods`.
fn resolve(mods: &BTreeMap<String, PathBuf>, cur: &str, path: &[String]) -> Option<String> {
    let here: Vec<String> = if cur.is_empty() {
        Vec::new()
    } else {
        cur.split("::").map(str::to_string).collect()
    };
    let (mut base, mut segs) = match path.first()?.as_str() {
        "crate" => (Vec::new(), &path[1..]),
        "self" => (here, &path[1..]),
        "super" => (here[..here.len().saturating_sub(1)].to_vec(), &path[1..]),
        _ => return None,
    };
    while segs.first().map(String::as_str) == Some("super") {
        base.pop();
        segs = &segs[1..];
    }
    (0..=segs.len()).rev().find_map(|n| {
        let cand = [&base[..], &segs[..n]].concat().join("::");
        mods.contains_key(&cand).then_some(cand)
    })
}

/// Module → module import edges (no self-edges, none to the crate root).
fn edges(mods: &BTreeMap<String, PathBuf>) -> BTreeSet<(String, String)> {
    let mut edges = BTreeSet::new();
    for (m, file) in mods {
        let text = std::fs::read_to_string(file).unwrap();
        let code = without_restricted_visibility(&without_unit_tests(&code_only(&text)));
        for child in declared_children(&code) {
            let c = if m.is_empty() {
                child.clone()
            } else {
                format!("{m}::{child}")
            };
            if mods.contains_key(&c) && uses_bare(&code, &child) {
                edges.insert((m.clone(), c));
            }
        }
        for path in rooted_paths(&code) {
            if let Some(to) = resolve(mods, m, &path)
                && &to != m
                && !to.is_empty()
            {
                edges.insert((m.clone(), to));
            }
        }
    }
    edges
}

/// Every cycle the edges close: for each edge a → b, the shortest way from b back to a, written
/// `a -> b -> … -> a`, each cycle once (rotated to start at its smallest module).
fn cycles(edges: &BTreeSet<(String, String)>) -> Vec<String> {
    let mut graph: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for (a, b) in edges {
        graph.entry(a).or_default().push(b);
    }
    let mut found = BTreeSet::new();
    for (a, b) in edges {
        let mut prev: BTreeMap<&str, &str> = BTreeMap::new();
        let mut queue = VecDeque::from([b.as_str()]);
        prev.insert(b, b);
        while let Some(n) = queue.pop_front() {
            if n == a {
                let mut cycle = vec![n];
                let mut k = n;
                while k != b {
                    k = prev[k];
                    cycle.push(k);
                }
                cycle.reverse(); // b … a
                cycle.insert(0, a); // a b … a, the edge a → b first
                cycle.pop();
                let min = (0..cycle.len()).min_by_key(|&k| cycle[k]).unwrap();
                cycle.rotate_left(min);
                cycle.push(cycle[0]);
                found.insert(cycle.join(" -> "));
                break;
            }
            for &x in graph.get(n).into_iter().flatten() {
                if !prev.contains_key(x) {
                    prev.insert(x, n);
                    queue.push_back(x);
                }
            }
        }
    }
    found.into_iter().collect()
}

fn top(m: &str) -> &str {
    m.split("::").next().unwrap()
}

#[test]
fn no_module_imports_back() {
    let mods = modules();
    let edges = edges(&mods);
    let top_edges: BTreeSet<(String, String)> = edges
        .iter()
        .filter(|(a, b)| top(a) != top(b))
        .map(|(a, b)| (top(a).to_string(), top(b).to_string()))
        .collect();
    assert!(
        mods.len() > 40 && edges.len() > 100 && top_edges.len() > 20,
        "the scan found only {} modules, {} edges, {} between top-level modules: it is broken",
        mods.len(),
        edges.len(),
        top_edges.len()
    );
    let top_cycles = cycles(&top_edges);
    let module_cycles = cycles(&edges);
    let mut graph = String::new();
    for a in top_edges.iter().map(|(a, _)| a).collect::<BTreeSet<_>>() {
        let to: Vec<&str> = top_edges
            .iter()
            .filter(|(x, _)| x == a)
            .map(|(_, b)| b.as_str())
            .collect();
        graph.push_str(&format!("  {a} -> {}\n", to.join(", ")));
    }
    let list = |cycles: &[String]| {
        if cycles.is_empty() {
            "none".to_string()
        } else {
            cycles.join("\n  ")
        }
    };
    assert!(
        top_cycles.is_empty() && module_cycles.is_empty(),
        "import cycles (DESIGN.md \"The pipeline\": data flows one way)\n\
         between top-level modules:\n  {}\nbetween modules:\n  {}\ntop-level imports:\n{graph}",
        list(&top_cycles),
        list(&module_cycles)
    );
}
