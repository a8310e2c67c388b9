//! What the README tells a new user to run, run as it is written: `mdpipe
//! demo` (the README's first command, through the binary, its outputs under
//! the working folder's `outputs/demo/`), and the tutorial's `decay.toml`
//! and data copy taken from README.md itself, so the two cannot drift.

use std::path::{Path, PathBuf};
use std::process::Command;

fn tmpdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mdpipe-readme-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn readme() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md")).unwrap()
}

/// The first fenced block of `language` after the line containing `after`.
fn block_after(text: &str, after: &str, language: &str) -> String {
    let start = text.find(after).unwrap_or_else(|| panic!("README.md no longer says {after:?}"));
    let rest = &text[start..];
    let open = rest.find(&format!("```{language}\n")).expect("the block") + language.len() + 4;
    let close = rest[open..].find("```").unwrap();
    rest[open..open + close].to_string()
}

#[test]
fn the_demo_ends_with_its_verdict_and_the_report_path() {
    let dir = tmpdir("demo");
    let out = Command::new(env!("CARGO_BIN_EXE_mdpipe")).arg("demo").current_dir(&dir).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "mdpipe demo failed:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    let lines: Vec<&str> = stdout.lines().filter(|l| !l.trim().is_empty()).collect();
    let last = lines.last().unwrap();
    assert_eq!(*last, "Report: outputs/demo/report.html", "{stdout}");
    assert!(dir.join("outputs/demo/report.html").is_file());
    let verdict = lines.iter().find(|l| l.starts_with("Verdict: ")).expect("a verdict line");
    // The concealed physics is quadratic drag (a = g - 0.4 v|v|).
    assert!(verdict.contains("quadratic_drag"), "{verdict}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_tutorial_config_calibrates_as_the_readme_prints_it() {
    let text = readme();
    let dir = tmpdir("tutorial");
    // "cp PATH/TO/mdpipe/pipeline/examples/kinetics_data.csv data.csv", as the README says.
    let copy = block_after(&text, "Start from an empty folder beside the checkout", "sh");
    let source = copy
        .lines()
        .find_map(|l| l.trim().strip_prefix("cp PATH/TO/mdpipe/"))
        .and_then(|l| l.split_whitespace().next())
        .expect("the tutorial's cp line");
    std::fs::copy(Path::new(env!("CARGO_MANIFEST_DIR")).join(source), dir.join("data.csv")).unwrap();
    std::fs::write(dir.join("decay.toml"), block_after(&text, "Write `decay.toml`", "toml")).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_mdpipe"))
        .args(["calibrate", "decay.toml", "--out", "fit"])
        .current_dir(&dir)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("fit/summary.json")).unwrap()).unwrap();
    // The README quotes the posterior of u with MD (truth 1.7); this run
    // (seed 1, as the README's) must give a median inside that interval.
    let quoted = text.split("`calibrate` prints the posterior (u = ").nth(1).expect("the README's quoted posterior");
    let numbers: Vec<f64> = quoted
        .split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .filter(|w| !w.is_empty())
        .take(3)
        .map(|w| w.parse().unwrap())
        .collect();
    assert_eq!(summary["kernel"], "II");
    let median = summary["parameters"]["u"]["median"].as_f64().unwrap();
    assert!(numbers[1] <= median && median <= numbers[2], "u median {median} outside the README's {numbers:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
