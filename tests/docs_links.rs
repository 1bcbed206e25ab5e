//! The README and every page under docs/ link only to files that exist in the repository, and
//! name no path outside it: a newcomer who follows a link finds the page (issue 21).

use std::path::{Path, PathBuf};

/// Every Markdown file of the user's documentation: README.md and docs/, recursively.
fn pages(root: &Path) -> Vec<PathBuf> {
    let mut out = vec![root.join("README.md")];
    let mut dirs = vec![root.join("docs")];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).expect("docs/ is readable") {
            let path = entry.expect("a docs/ entry").path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "md") {
                out.push(path);
            }
        }
    }
    out.sort();
    out
}

/// The targets of the inline links `[text](target)` of a Markdown text, with their line.
fn link_targets(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut in_code_block = false;
    for (line_no, line) in text.lines().enumerate() {
        if line.trim_start().starts_with("```") {
            in_code_block = !in_code_block;
            continue;
        }
        if in_code_block {
            continue;
        }
        let mut rest = line;
        while let Some(at) = rest.find("](") {
            let after = &rest[at + 2..];
            let Some(end) = after.find(')') else { break };
            out.push((line_no + 1, after[..end].trim().to_string()));
            rest = &after[end..];
        }
    }
    out
}

#[test]
fn every_relative_link_of_the_readme_and_docs_resolves() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let pages = pages(root);
    // README.md and the pages the issue asks for, at least.
    assert!(pages.len() >= 10, "found only {} pages", pages.len());
    let mut checked = 0;
    let mut broken = Vec::new();
    for page in &pages {
        let text = std::fs::read_to_string(page).expect("a page is UTF-8");
        for (line, target) in link_targets(&text) {
            if target.starts_with("http://")
                || target.starts_with("https://")
                || target.starts_with("mailto:")
                || target.starts_with('#')
            {
                continue;
            }
            let file = target.split('#').next().unwrap_or_default();
            let resolved = page.parent().expect("a page has a folder").join(file);
            checked += 1;
            let inside = resolved
                .canonicalize()
                .is_ok_and(|p| p.starts_with(root.canonicalize().expect("the checkout")));
            if !inside {
                broken.push(format!(
                    "{}:{line}: {target}",
                    page.strip_prefix(root).unwrap_or(page).display()
                ));
            }
        }
    }
    assert!(
        broken.is_empty(),
        "links that do not resolve to a file of the repository:\n{}",
        broken.join("\n")
    );
    // The README alone links to docs/ several times: a parser that found nothing would pass the
    // check above vacuously.
    assert!(checked >= 20, "only {checked} relative links found");
}

#[test]
fn no_page_names_a_path_outside_the_repository() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let outside = ["../shared", "/work/", "/tmp/", "/home/", "/root/"];
    let mut found = Vec::new();
    for page in pages(root) {
        let text = std::fs::read_to_string(&page).expect("a page is UTF-8");
        for (line_no, line) in text.lines().enumerate() {
            for pattern in outside {
                if line.contains(pattern) {
                    found.push(format!(
                        "{}:{}: {pattern}",
                        page.strip_prefix(root).unwrap_or(&page).display(),
                        line_no + 1
                    ));
                }
            }
        }
    }
    assert!(
        found.is_empty(),
        "paths outside the repository:\n{}",
        found.join("\n")
    );
}
