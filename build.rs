//! Declares the stages of `mdpipe run`: every file in `src/pipeline/stage/`
//! but `mod.rs` is one stage (a module with a `STAGE`), so that a new stage
//! is one new file. Writes `$OUT_DIR/stages.rs`, included by that folder's
//! `mod.rs`.

use std::path::Path;

fn main() {
    let manifest = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let dir = Path::new(&manifest).join("src").join("pipeline").join("stage");
    println!("cargo:rerun-if-changed={}", dir.display());
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("listing {}: {e}", dir.display()))
        .filter_map(|entry| entry.ok()?.file_name().into_string().ok())
        .filter_map(|file| file.strip_suffix(".rs").map(str::to_string))
        .filter(|name| name != "mod")
        .collect();
    names.sort();
    let mut code = String::new();
    for name in &names {
        let path = dir.join(format!("{name}.rs"));
        code.push_str(&format!("#[path = {:?}]\nmod {name};\n", path.display().to_string()));
    }
    let list: Vec<String> = names.iter().map(|n| format!("&{n}::STAGE")).collect();
    code.push_str(&format!(
        "/// Every stage file's `STAGE`.\npub(in crate::pipeline) const FOUND: &[&StageDef] = &[{}];\n",
        list.join(", ")
    ));
    let out = Path::new(&std::env::var("OUT_DIR").expect("cargo sets OUT_DIR")).join("stages.rs");
    std::fs::write(&out, code).unwrap_or_else(|e| panic!("writing {}: {e}", out.display()));
}
