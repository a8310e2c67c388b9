//! The layering of ARCHITECTURE.md, checked on the source: every `crate::`
//! path a file names must belong to its own unit or to a unit below it.
//! (Units of one rank, such as `compare` and `diagnose`, may not use each
//! other.) This keeps import cycles between units and upward imports out.
//! And the library does not print (`base::messages`).

use std::path::{Path, PathBuf};

/// Units from the bottom up, with their rank. `calibrate` is its rooms in
/// the order data flow: the sampler (which knows only its target's
/// interface), the likelihood that implements it, the analysis and the
/// problem built from it, the results, and the run above them all.
const UNITS: [(&str, u32); 28] = [
    ("base", 0),
    ("engine::gp", 10),
    ("engine::formula", 10),
    ("engine::maximin", 10),
    ("engine::model", 20),
    ("engine::execute", 20),
    ("engine::design", 30),
    ("engine::ingest", 30),
    ("engine::discover", 30),
    ("engine::emulator", 40),
    ("engine::calibrate::sampler", 50),
    ("engine::calibrate::likelihood", 51),
    ("engine::calibrate::analysis", 52),
    ("engine::calibrate::problem", 53),
    ("engine::calibrate::results", 54),
    ("engine::calibrate::guard", 54),
    ("engine::calibrate", 55),
    ("engine::compare", 60),
    ("engine::diagnose", 60),
    ("engine::refine", 60),
    ("engine::report", 70),
    ("systems::ball_drop", 80),
    ("systems::heavy_ion", 80),
    ("systems", 90),
    ("pipeline", 100),
    ("run_systems", 105),
    ("app", 110),
    ("engine", 120),
];

/// The unit of a module path such as `engine::calibrate::sampler::smc` (longest match).
fn unit_of(path: &str) -> Option<(&'static str, u32)> {
    UNITS
        .iter()
        .filter(|(u, _)| path == *u || path.starts_with(&format!("{u}::")))
        .max_by_key(|(u, _)| u.len())
        .copied()
}

/// The module path of a source file: `src/engine/calibrate/smc.rs` → `engine::calibrate::sampler::smc`.
fn module_of(file: &Path, src: &Path) -> String {
    let rel = file.strip_prefix(src).unwrap().with_extension("");
    let parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().to_string()).filter(|p| p != "mod").collect();
    parts.join("::")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// Every `crate::a::b` path on a line, with grouped imports
/// (`crate::engine::{compare, diagnose}`) expanded one level.
fn crate_paths(line: &str) -> Vec<String> {
    let ident = |c: char| c.is_alphanumeric() || c == '_' || c == ':';
    let mut out = Vec::new();
    for piece in line.split("crate::").skip(1) {
        let head: String = piece.chars().take_while(|c| ident(*c)).collect();
        let rest = &piece[head.len()..];
        let head = head.trim_end_matches(':').to_string();
        match rest.strip_prefix('{') {
            Some(group) => {
                let inner = group.split('}').next().unwrap_or("");
                for item in inner.split(',') {
                    let name: String = item.trim().chars().take_while(|c| ident(*c)).collect();
                    let name = name.trim_end_matches(':');
                    out.push(if name.is_empty() || name == "self" { head.clone() } else { format!("{head}::{name}") });
                }
            }
            None => out.push(head),
        }
    }
    out
}

#[test]
fn no_file_imports_from_a_layer_above_or_a_sibling_unit() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut violations = Vec::new();
    let mut checked = 0;
    for file in &files {
        let module = module_of(file, &src);
        // The crate root and the binary sit above every layer.
        if module == "lib" || module == "main" {
            continue;
        }
        let (unit, rank) = unit_of(&module)
            .unwrap_or_else(|| panic!("{}: module {module} belongs to no unit of ARCHITECTURE.md", file.display()));
        // Every engine module is a unit of its own rank; only the engine's
        // root falls to the catch-all `engine`.
        if unit == "engine" && module != "engine" {
            violations.push(format!("{}: engine module {module} is in no unit of the layering", file.display()));
        }
        let text = std::fs::read_to_string(file).unwrap();
        // Comments may name any module.
        for (line_no, line) in text.lines().enumerate().filter(|(_, l)| !l.trim_start().starts_with("//")) {
            for path in crate_paths(line) {
                let Some((target, target_rank)) = unit_of(&path) else { continue };
                checked += 1;
                let allowed = target == unit || target_rank < rank;
                if !allowed {
                    violations.push(format!(
                        "{}:{}: {unit} (rank {rank}) uses crate::{path} ({target}, rank {target_rank})",
                        file.display(),
                        line_no + 1
                    ));
                }
            }
        }
    }
    assert!(checked > 100, "only {checked} crate paths found: is the source where the test looks?");
    assert!(violations.is_empty(), "imports against the layering:\n{}", violations.join("\n"));
}

/// The engine and the pipeline never print: what they say goes through
/// `base::messages` (`say!`, `note!`), whose sink a caller that is not the
/// terminal replaces.
#[test]
fn the_engine_and_the_pipeline_never_print() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src.join("engine"), &mut files);
    rust_files(&src.join("pipeline"), &mut files);
    assert!(files.len() > 50, "only {} files found", files.len());
    let mut prints = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).unwrap();
        for (line_no, line) in text.lines().enumerate().filter(|(_, l)| !l.trim_start().starts_with("//")) {
            if ["println!", "eprintln!", "print!", "eprint!", "dbg!"].iter().any(|m| line.contains(m)) {
                prints.push(format!("{}:{}: {}", file.display(), line_no + 1, line.trim()));
            }
        }
    }
    assert!(prints.is_empty(), "printing in the library:\n{}", prints.join("\n"));
}

/// A caller captures what the library says by installing a sink.
#[test]
fn what_the_library_says_can_be_captured() {
    use mdpipe::base::messages::{self, Channel, Sink};
    use std::sync::{Arc, Mutex};
    #[derive(Default)]
    struct Capture(Mutex<Vec<(Channel, String)>>);
    impl Sink for Capture {
        fn emit(&self, channel: Channel, text: &str) {
            self.0.lock().unwrap().push((channel, text.to_string()));
        }
    }
    let capture = Arc::new(Capture::default());
    let before = messages::set_sink(capture.clone());
    mdpipe::emulator::validate::print("captured validation table", &[]);
    messages::set_sink(before.unwrap_or_else(|| Arc::new(messages::Terminal)));
    let said = capture.0.lock().unwrap();
    assert!(said.contains(&(Channel::Result, "captured validation table:".to_string())), "{said:?}");
    assert!(said.iter().any(|(c, t)| *c == Channel::Result && t.contains("RMSE/spr")), "{said:?}");
}
