//! Every `cargo test` command quoted in README.md and docs/ runs at least one
//! test: each is listed (`--list`) with its own filters and flags, and a
//! command whose matches are all second-tier tests but which lacks
//! `--ignored` (so runs none of them) fails here, as does a filter that
//! matches nothing. Integration-test commands are listed by this binary
//! itself; `--lib` commands through cargo.

use std::path::Path;
use std::process::Command;

/// Inline code spans and code-block lines that start with `cargo test`,
/// whitespace (line breaks inside a span) collapsed.
fn quoted_commands(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced && line.trim_start().starts_with("cargo test") {
            let command = line.split('#').next().unwrap_or("");
            out.push(command.split_whitespace().collect::<Vec<_>>().join(" "));
        }
    }
    let unfenced: String = {
        let mut keep = String::new();
        let mut fenced = false;
        for line in text.lines() {
            if line.trim_start().starts_with("```") {
                fenced = !fenced;
            } else if !fenced {
                keep.push_str(line);
                keep.push('\n');
            }
        }
        keep
    };
    for (k, span) in unfenced.split('`').enumerate() {
        let span = span.split_whitespace().collect::<Vec<_>>().join(" ");
        if k % 2 == 1 && span.starts_with("cargo test") {
            out.push(span);
        }
    }
    out
}

fn documents() -> Vec<(String, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![root.join("README.md")];
    let mut docs: Vec<_> = std::fs::read_dir(root.join("docs"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    files.extend(docs);
    files.into_iter().map(|f| (f.display().to_string(), std::fs::read_to_string(&f).unwrap())).collect()
}

/// Test names a libtest binary lists for `args` (plus `--list`).
fn listed(program: &mut Command) -> Vec<String> {
    let out = program.output().expect("listing tests");
    assert!(out.status.success(), "{:?}: {}", program, String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).lines().filter_map(|l| l.strip_suffix(": test")).map(String::from).collect()
}

/// The tests `command` runs: its matches, less the ignored ones unless it
/// asks for them (`--ignored` runs only those).
fn selected(command: &str) -> Vec<String> {
    let words: Vec<&str> = command.split_whitespace().skip(2).collect();
    let split = words.iter().position(|w| *w == "--").unwrap_or(words.len());
    let (cargo_args, test_args) = (&words[..split], words.get(split + 1..).unwrap_or(&[]));
    let lib = cargo_args.contains(&"--lib");
    // Filters: cargo's positional argument, or the harness's plain words.
    let mut harness: Vec<String> = cargo_args
        .iter()
        .enumerate()
        .filter(|(i, w)| !w.starts_with("--") && (*i == 0 || cargo_args[i - 1] != "--test"))
        .map(|(_, w)| w.to_string())
        .collect();
    harness
        .extend(test_args.iter().filter(|w| **w != "--ignored" && **w != "--include-ignored").map(|w| w.to_string()));
    let list = |ignored: bool| {
        let mut args = harness.clone();
        args.push("--list".into());
        if ignored {
            args.push("--ignored".into());
        }
        let mut program = if lib {
            let mut c = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
            c.args(["test", "--release", "--lib", "--"]).args(&args).current_dir(env!("CARGO_MANIFEST_DIR"));
            c
        } else {
            let mut c = Command::new(std::env::current_exe().unwrap());
            c.args(&args);
            c
        };
        listed(&mut program)
    };
    let ignored = list(true);
    if test_args.contains(&"--ignored") {
        ignored
    } else if test_args.contains(&"--include-ignored") {
        list(false)
    } else {
        list(false).into_iter().filter(|t| !ignored.contains(t)).collect()
    }
}

#[test]
fn every_cargo_test_command_in_the_docs_runs_a_test() {
    let mut seen = Vec::new();
    let mut empty = Vec::new();
    for (file, text) in documents() {
        for command in quoted_commands(&text) {
            if seen.contains(&command) {
                continue;
            }
            seen.push(command.clone());
            // The whole tiers are what CI and the second-tier run execute.
            if command == "cargo test --release" || command == "cargo test --release -- --ignored" {
                continue;
            }
            if selected(&command).is_empty() {
                empty.push(format!("{file}: `{command}`"));
            }
        }
    }
    println!("{} distinct cargo test commands in README.md and docs/ checked", seen.len());
    assert!(seen.len() >= 20, "found only {} commands: is the extraction broken?", seen.len());
    assert!(empty.is_empty(), "commands that run no test:\n{}", empty.join("\n"));
}
