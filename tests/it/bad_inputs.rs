//! Bad input, command by command: each gets a clear error (exit code 1, or 2
//! for a command line the argument parser refuses; never a panic's 101),
//! says what is wrong, ends within 30 s, and writes no artifact. The test prints the README's table of what each input gets.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A bad input: what it is, the command line (`{d}` is a scratch folder
/// holding the files written first), a phrase the error must contain, and the
/// output that must not appear.
struct Case {
    what: &'static str,
    files: Vec<(&'static str, String)>,
    args: &'static str,
    says: &'static str,
    no_output: &'static str,
    /// 1 for a bad input, 2 for a command line the argument parser refuses
    /// (the usage-error convention of clap, getopt and argparse).
    exit: i32,
}

fn ball_drop_toml() -> String {
    crate::guard::without_bundled_inputs(&std::fs::read_to_string(root().join("pipeline/ball_drop.toml")).unwrap())
        .replace("ball_drop_data.csv", &root().join("pipeline/ball_drop_data.csv").display().to_string())
}

fn data(rows: &str) -> String {
    format!("observable,x,value,error\nheight,0,60,0.1\nheight,0.5,58.8,0.1\n{rows}")
}

fn shifted_data() -> String {
    let text = std::fs::read_to_string(root().join("pipeline/ball_drop_data.csv")).unwrap();
    let mut out = String::from("observable,x,value,error\n");
    for line in text.lines().filter(|l| !l.starts_with('#') && !l.starts_with("observable")) {
        let f: Vec<&str> = line.split(',').collect();
        out.push_str(&format!("{},{},{},{}\n", f[0], f[1].parse::<f64>().unwrap() - 0.5, f[2], f[3]));
    }
    out
}

fn cases() -> Vec<Case> {
    let cfg = ball_drop_toml();
    let with = |from: &str, to: &str| cfg.replace(from, to);
    let c = |what, files: Vec<(&'static str, String)>, args, says, no_output| Case {
        what,
        files,
        args,
        says,
        no_output,
        exit: 1,
    };
    let usage = |what, args, says| Case { what, files: vec![], args, says, no_output: "out", exit: 2 };
    vec![
        c("config file missing", vec![], "calibrate {d}/none.toml --out {d}/out", "reading config", "out"),
        c(
            "config not TOML",
            vec![("c.toml", "name = [".into())],
            "calibrate {d}/c.toml --out {d}/out",
            "c.toml",
            "out",
        ),
        c(
            "unknown model family",
            vec![("c.toml", with("kind = \"ode\"", "kind = \"pendulum\""))],
            "calibrate {d}/c.toml --out {d}/out",
            "unknown model family",
            "out",
        ),
        c(
            "formula with an unknown name",
            vec![("c.toml", with("v = \"g\"", "v = \"g - drag*v\""))],
            "calibrate {d}/c.toml --out {d}/out",
            "unknown name 'drag'",
            "out",
        ),
        c(
            "formula not finite at a prior corner",
            vec![("c.toml", with("h = \"h0\"", "h = \"h0/v0\""))],
            "calibrate {d}/c.toml --out {d}/out",
            "not finite",
            "out",
        ),
        c(
            "prior bounds min >= max",
            vec![("c.toml", with("max = 20.0", "max = -1.0"))],
            "calibrate {d}/c.toml --out {d}/out",
            "min < max",
            "out",
        ),
        c(
            "unknown kernel in config",
            vec![("c.toml", with("kernel = \"II\"", "kernel = \"III\""))],
            "calibrate {d}/c.toml --out {d}/out",
            "unknown kernel \"III\" (use none, I or II)",
            "out",
        ),
        usage(
            "unknown --kernel",
            "calibrate pipeline/ball_drop.toml --kernel III --out {d}/out",
            "[possible values: none, I, II]",
        ),
        usage(
            "unknown --sampler",
            "calibrate pipeline/ball_drop.toml --sampler gibbs --out {d}/out",
            "[possible values: smc, ensemble]",
        ),
        c(
            "ess_fraction = 1",
            vec![("c.toml", with("replicates = 4", "replicates = 4\ness_fraction = 1.0"))],
            "calibrate {d}/c.toml --out {d}/out",
            "smc.ess_fraction",
            "out",
        ),
        c(
            "unknown config field",
            vec![("c.toml", with("[predictions]", "[predictions]\nx_mn = 1.0"))],
            "calibrate {d}/c.toml --out {d}/out",
            "x_mn",
            "out",
        ),
        c(
            "parameter the model lacks",
            vec![("c.toml", format!("{cfg}\n[parameters.k]\nmin = 0.0\nmax = 1.0\n"))],
            "calibrate {d}/c.toml --out {d}/out",
            "the model has no parameter 'k'",
            "out",
        ),
        c(
            "shift/scale of the kernel input invalid",
            vec![("c.toml", format!("{cfg}\n[discrepancy.inputs]\nheight = {{ scale = -1.0 }}\n"))],
            "calibrate {d}/c.toml --out {d}/out",
            "positive scale",
            "out",
        ),
        c(
            "data file missing",
            vec![],
            "calibrate pipeline/ball_drop.toml --data {d}/none.csv --out {d}/out",
            "none.csv",
            "out",
        ),
        c(
            "data column missing",
            vec![("d.csv", "observable,x,value\nheight,0,60\n".into())],
            "calibrate pipeline/ball_drop.toml --data {d}/d.csv --out {d}/out",
            "missing column 'error'",
            "out",
        ),
        c(
            "data value NaN",
            vec![("d.csv", data("height,0.7,nan,0.1\n"))],
            "calibrate pipeline/ball_drop.toml --data {d}/d.csv --out {d}/out",
            "line 4",
            "out",
        ),
        c(
            "data error negative",
            vec![("d.csv", data("height,0.7,58,-0.1\n"))],
            "calibrate pipeline/ball_drop.toml --data {d}/d.csv --out {d}/out",
            "'error'",
            "out",
        ),
        c(
            "data observable unknown",
            vec![("d.csv", data("speed,0.7,5,0.1\n"))],
            "calibrate pipeline/ball_drop.toml --data {d}/d.csv --out {d}/out",
            "unknown observable 'speed'",
            "out",
        ),
        c(
            "one point of an observable",
            vec![("d.csv", "observable,x,value,error\nheight,0,60,0.1\n".into())],
            "calibrate pipeline/ball_drop.toml --data {d}/d.csv --observables height --out {d}/out",
            "at least 2",
            "out",
        ),
        c(
            "--observables not in the model",
            vec![],
            "calibrate pipeline/ball_drop.toml --observables speed --out {d}/out",
            "unknown observable 'speed'",
            "out",
        ),
        c(
            "data before the ODE's t0",
            vec![("d.csv", shifted_data())],
            "calibrate pipeline/ball_drop.toml --data {d}/d.csv --kernel II --out {d}/out",
            "before t0",
            "out/summary.json",
        ),
        c(
            "negative x under the (x·x')^r kernel",
            vec![("c.toml", with("t0 = 0.0", "t0 = -0.5")), ("d.csv", shifted_data())],
            "calibrate {d}/c.toml --data {d}/d.csv --kernel II --out {d}/out",
            "x ≥ 0",
            "out/summary.json",
        ),
        c(
            "negative --time-limit",
            vec![],
            "calibrate pipeline/ball_drop.toml --time-limit=-1 --out {d}/out",
            "--time-limit",
            "out",
        ),
        c(
            "compare --replicates with --data",
            vec![],
            "compare pipeline/ball_drop.toml --replicates 2 --data pipeline/ball_drop_data.csv --out {d}/out",
            "drop --data",
            "out",
        ),
        c(
            "compare --replicates without [truth]",
            vec![("c.toml", cfg.split("[truth]").next().unwrap().to_string())],
            "compare {d}/c.toml --replicates 2 --out {d}/out",
            "[truth]",
            "out/replicates.md",
        ),
        c(
            "diagnose on a missing data file",
            vec![],
            "diagnose pipeline/ball_drop.toml --data {d}/none.csv --out {d}/out",
            "none.csv",
            "out/diagnosis.json",
        ),
        c("ingest: runs folder missing", vec![], "ingest {d}/runs --out {d}/t.parquet", "runs", "t.parquet"),
        c(
            "ingest: a .dat table that is not the paper's",
            vec![("t.dat", "1 2 3\n4 5\n".into())],
            "ingest {d}/t.dat --out {d}/m.csv",
            "t.dat",
            "m.csv",
        ),
        c(
            "ingest: unknown --format",
            vec![],
            "ingest tests/fixtures/iebe_music/runs --format zip --out {d}/t.parquet",
            "unknown run format",
            "t.parquet",
        ),
        c(
            "ingest: pT bins not increasing",
            vec![],
            "ingest tests/fixtures/iebe_music/runs --pt-bins 1,0.5 --out {d}/t.parquet",
            "--pt-bins",
            "t.parquet",
        ),
        c(
            "train-emulator: no [emulator] table",
            vec![],
            "train-emulator pipeline/ball_drop.toml --training pipeline/ball_drop_data.csv --out {d}/emu",
            "no [emulator] table",
            "emu",
        ),
        c(
            "train-emulator: table value NaN",
            vec![
                ("e.toml", "[emulator]\nparameters = [\"a\"]\n".into()),
                ("t.csv", "design_id,observable,x,value,a\n0,y,0,1,0\n1,y,0,nan,1\n2,y,0,2,2\n".into()),
            ],
            "train-emulator {d}/e.toml --training {d}/t.csv --out {d}/emu",
            "'value'",
            "emu",
        ),
        c(
            "validate-emulator: not an emulator folder",
            vec![],
            "validate-emulator {d}",
            "emulator.json",
            "validation.json",
        ),
        c("design: spec missing", vec![], "design {d}/none.toml --points 10 --out {d}/design", "none.toml", "design"),
        c(
            "simulate ball-drop: bad --sigma",
            vec![],
            "simulate ball-drop --sigma 0.1,0 --out {d}/m.csv",
            "--sigma",
            "m.csv",
        ),
        c(
            "simulate heavy-ion: --point not a number",
            vec![],
            "simulate heavy-ion --point eta_s=abc,e_sw=0.2 --out {d}/m.csv",
            "not a number",
            "m.csv",
        ),
        c(
            "simulate heavy-ion: e_sw <= 0",
            vec![],
            "simulate heavy-ion --point eta_s=0.1,e_sw=-1 --out {d}/m.csv",
            "must be positive",
            "m.csv",
        ),
        c(
            "simulate heavy-ion: eta_s NaN",
            vec![],
            "simulate heavy-ion --point eta_s=NaN,e_sw=0.2 --events 5 --out {d}/runs",
            "must be finite and >= 0",
            "runs",
        ),
        c(
            "simulate heavy-ion: eta_s < 0",
            vec![],
            "simulate heavy-ion --point eta_s=-5,e_sw=0.2 --events 5 --out {d}/runs",
            "must be finite and >= 0",
            "runs",
        ),
        c(
            "simulate heavy-ion: --errors-from lacks a point",
            vec![("e.csv", "observable,x,value,error\nch_spectrum,0.1,1,0.5\n".into())],
            "simulate heavy-ion --point eta_s=0.1,e_sw=0.2 --errors-from {d}/e.csv --out {d}/m.csv",
            "no measurement of ch_spectrum at x = 0.3000",
            "m.csv",
        ),
        c(
            "simulate heavy-ion: --errors-from with a bad error",
            vec![("e.csv", "observable,x,value,error\nch_spectrum,0.1,1,-2\n".into())],
            "simulate heavy-ion --point eta_s=0.1,e_sw=0.2 --errors-from {d}/e.csv --out {d}/m.csv",
            "line 2, field 'error'",
            "m.csv",
        ),
        c(
            "simulate heavy-ion: --errors-from for runs",
            vec![("e.csv", "observable,x,value,error\nch_spectrum,0.1,1,0.5\n".into())],
            "simulate heavy-ion --point eta_s=0.1,e_sw=0.2 --errors-from {d}/e.csv --out {d}/runs",
            ".csv or .parquet",
            "runs",
        ),
        c(
            "run: config without [run]",
            vec![],
            "run pipeline/ball_drop.toml --out {d}/study",
            "no [run] table",
            "study",
        ),
        usage(
            "run: unknown --stage",
            "run pipeline/heavy_ion_2param.toml --stage fit --out {d}/study",
            "[possible values: design, simulate, ingest, emulator, mock, refine, calibrate, report, candidates, diagnose]",
        ),
        c(
            "report: damaged summary.json",
            vec![("r/summary.json", "{\"name\": 1".into())],
            "report {d}/r --out {d}/report.html",
            "summary.json",
            "report.html",
        ),
    ]
}

#[test]
fn every_bad_input_gets_a_clear_error_and_writes_nothing() {
    let base = std::env::temp_dir().join(format!("mdpipe-bad-inputs-{}", std::process::id()));
    let mut table = String::from("| bad input | command | exit | the error says (first line) |\n|---|---|---|---|\n");
    let mut failures = Vec::new();
    for (k, case) in cases().iter().enumerate() {
        let d: PathBuf = base.join(format!("{k:02}"));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        for (name, text) in &case.files {
            let p = d.join(name);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(p, text).unwrap();
        }
        let line = case.args.replace("{d}", &d.display().to_string());
        let start = Instant::now();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_mdpipe"))
            .args(line.split_whitespace())
            .current_dir(root())
            .output()
            .unwrap();
        let took = start.elapsed();
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        let message = stderr.lines().find(|l| l.starts_with("error:")).unwrap_or("").to_string();
        let code = out.status.code().unwrap_or(-1);
        let written = d.join(case.no_output).exists();
        let command = case.args.split_whitespace().next().unwrap_or("");
        table.push_str(&format!(
            "| {} | {command} | {code} | {} |\n",
            case.what,
            message.trim_start_matches("error: ").replace('|', "\\|").replace(&d.display().to_string(), "…")
        ));
        if code != case.exit || !stderr.contains(case.says) || written || took > Duration::from_secs(30) {
            failures
                .push(format!("{}: exit {code}, {took:?}, artifact written: {written}, stderr: {stderr}", case.what));
        }
    }
    println!("{} bad inputs:\n{table}", cases().len());
    let _ = std::fs::remove_dir_all(&base);
    assert!(cases().len() >= 25);
    assert!(failures.is_empty(), "{}", failures.join("\n---\n"));
}

/// A caller that is not the terminal finds what was wrong, typed: the file,
/// the line and the field of a bad value, the column a table lacks, and why
/// a sampler stopped, under whatever context the library added.
#[test]
fn bad_input_errors_are_typed_for_callers() {
    use mdpipe::base::error::{ColumnError, ConfigError, FieldError};
    let dir = std::env::temp_dir().join(format!("mdpipe-typed-errors-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.csv");
    std::fs::write(&bad, "observable,x,value,error\nh,0.1,1.0,0.1\nh,0.2,one,0.1\n").unwrap();
    let err = mdpipe::artifacts::read_measurements(&bad).unwrap_err();
    let field = err.chain().find_map(|e| e.downcast_ref::<FieldError>()).unwrap_or_else(|| panic!("{err:#}"));
    assert_eq!((field.file.as_path(), field.at.as_str(), field.field.as_str()), (bad.as_path(), "line 3", "value"));
    assert!(format!("{err:#}").contains("bad.csv: line 3, field 'value'"), "{err:#}");

    let lacking = dir.join("lacking.csv");
    std::fs::write(&lacking, "observable,x,value\nh,0.1,1.0\n").unwrap();
    let err = mdpipe::artifacts::read_measurements(&lacking).unwrap_err();
    match err.chain().find_map(|e| e.downcast_ref::<ColumnError>()) {
        Some(ColumnError::Missing { column, found, expected, .. }) => {
            assert_eq!(column, "error");
            assert_eq!(found, &["observable", "x", "value"]);
            assert_eq!(expected, &["observable", "x", "value", "error"]);
        }
        other => panic!("{other:?}: {err:#}"),
    }

    let config = dir.join("bad.toml");
    let text = ball_drop_toml().replace("cbar = [0.0, 10.0]", "cbar = [2.0, 1.0]");
    std::fs::write(&config, text).unwrap();
    let err = mdpipe::config::Config::load(&config).unwrap_err();
    let bad = err.chain().find_map(|e| e.downcast_ref::<ConfigError>()).unwrap_or_else(|| panic!("{err:#}"));
    assert_eq!((bad.file.as_path(), bad.place.as_str()), (config.as_path(), "[discrepancy.bounds] cbar"));
    let _ = std::fs::remove_dir_all(&dir);
}
