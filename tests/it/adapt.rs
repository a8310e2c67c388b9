//! Convergence by default, end to end: a calibration whose configured
//! sampling is too small to converge (2 × 100 particles: 200 draws cannot
//! hold an ESS of 400) is sampled again with more, says so on the terminal,
//! and lists every run in summary.json; with `[sampler] adapt = false` it is
//! not, and is reported NOT CONVERGED.

use std::path::Path;

fn kinetics(dir: &Path, adapt: bool) -> std::path::PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("pipeline/examples/kinetics.toml")).unwrap();
    let data = root.join("pipeline/examples/kinetics_data.csv");
    let text = text
        .replace("\"kinetics_data.csv\"", &format!("{data:?}"))
        .replace("kind = \"smc\"", &format!("kind = \"smc\"\nadapt = {adapt}"))
        .replace("particles = 2000", "particles = 100")
        .replace("replicates = 4", "replicates = 2");
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join(format!("kinetics_{adapt}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

fn calibrate(config: &Path, out: &Path) -> (serde_json::Value, String) {
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_mdpipe"))
        .args(["calibrate", config.to_str().unwrap(), "--kernel", "none", "--seed", "3"])
        .args(["--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr).to_string();
    assert!(run.status.success(), "{stderr}");
    let summary = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    (summary, stderr)
}

#[test]
fn a_fit_too_small_to_converge_is_sampled_again_with_more() {
    let dir = std::env::temp_dir().join(format!("mdpipe-adapt-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (summary, stderr) = calibrate(&kinetics(&dir, true), &dir.join("adapted"));
    let d = &summary["diagnostics"];
    let runs = d["adaptation"].as_array().expect("the runs are listed");
    assert!(runs.len() >= 2, "{runs:?}");
    assert!(runs[0]["min_ess"].as_f64().unwrap() < 400.0 && runs[0]["particles"] == 100);
    for pair in runs.windows(2) {
        assert!(pair[1]["particles"].as_u64() >= pair[0]["particles"].as_u64(), "{runs:?}");
    }
    let spent: u64 = runs.iter().map(|r| r["evaluations"].as_u64().unwrap()).sum();
    assert_eq!(d["likelihood_evaluations"].as_u64(), Some(spent));
    assert!(stderr.contains("not converged") && stderr.contains("sampling again"), "{stderr}");
    // The result is the last run's: its draws.
    let last = &runs[runs.len() - 1];
    assert_eq!(d["draws"].as_u64(), Some(last["particles"].as_u64().unwrap() * 2));
    if d["converged"] != serde_json::Value::Bool(true) {
        assert!(d["warnings"].to_string().contains("not converged after"), "{}", d["warnings"]);
    }
    println!("runs: {runs:?}; converged {}", d["converged"]);

    let (summary, stderr) = calibrate(&kinetics(&dir, false), &dir.join("as_configured"));
    let d = &summary["diagnostics"];
    assert!(d.get("adaptation").is_none() && !stderr.contains("sampling again"));
    assert_eq!(d["converged"], serde_json::Value::Bool(false));
    let _ = std::fs::remove_dir_all(&dir);
}
