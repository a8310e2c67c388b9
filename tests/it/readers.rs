//! Every reader, fed inputs made by mutating a valid file (flipped bytes,
//! cut and inserted runs, duplicated lines, awkward tokens such as `nan`,
//! `1e400` or an empty field), must return an error or a value, never panic.
//! The mutations are drawn by proptest with a fixed seed, so a run is
//! reproducible; inputs that once made a reader panic are kept under
//! `tests/fixtures/corpus/<reader>/` and replayed by the corpus test.

use mdpipe::calibrate::sampler::checkpoint::Checkpointing;
use mdpipe::calibrate::sampler::smc::ReplicateOutput;
use proptest::collection::vec;
use proptest::prelude::*;
use proptest::test_runner::{Config as RunnerConfig, RngSeed, TestCaseError, TestRunner};
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};

/// Mutations per reader: enough to reach every branch of these small
/// formats many times over, few enough to keep the test under a minute.
/// `MDPIPE_FUZZ_CASES` and `MDPIPE_FUZZ_SEED` run a longer or another hunt.
const CASES: u32 = 1000;

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Tokens that readers of numbers and tables trip on.
const TOKENS: [&str; 14] = [
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e400",
    "-1e-400",
    "",
    ",",
    "\n",
    "\"",
    "99999999999999999999999",
    "-0",
    "[",
    "\u{feff}",
];

#[derive(Clone, Debug)]
enum Edit {
    Flip(usize, u8),
    Delete(usize, usize),
    Insert(usize, Vec<u8>),
    Token(usize, usize),
    Truncate(usize),
    DuplicateLine(usize),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(p, b)| Edit::Flip(p, b)),
        (any::<usize>(), 1usize..64).prop_map(|(p, n)| Edit::Delete(p, n)),
        (any::<usize>(), vec(any::<u8>(), 1..12)).prop_map(|(p, b)| Edit::Insert(p, b)),
        (any::<usize>(), 0..TOKENS.len()).prop_map(|(p, t)| Edit::Token(p, t)),
        any::<usize>().prop_map(Edit::Truncate),
        any::<usize>().prop_map(Edit::DuplicateLine),
    ]
}

fn apply(seed: &[u8], edits: &[Edit]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for e in edits {
        let at = |p: usize, len: usize| if len == 0 { 0 } else { p % (len + 1) };
        match e {
            Edit::Flip(p, v) if !b.is_empty() => {
                let i = p % b.len();
                b[i] = *v;
            }
            Edit::Flip(..) => {}
            Edit::Delete(p, n) => {
                let i = at(*p, b.len());
                let j = (i + n).min(b.len());
                b.drain(i..j);
            }
            Edit::Insert(p, bytes) => {
                let i = at(*p, b.len());
                b.splice(i..i, bytes.iter().copied());
            }
            Edit::Token(p, t) => {
                let i = at(*p, b.len());
                b.splice(i..i, TOKENS[*t].bytes());
            }
            Edit::Truncate(p) => b.truncate(at(*p, b.len())),
            Edit::DuplicateLine(p) => {
                let i = at(*p, b.len());
                let start = b[..i].iter().rposition(|&c| c == b'\n').map(|k| k + 1).unwrap_or(0);
                let end = b[i..].iter().position(|&c| c == b'\n').map(|k| i + k + 1).unwrap_or(b.len());
                let line = b[start..end].to_vec();
                b.splice(end..end, line);
            }
        }
    }
    b
}

/// A reader under test: the file extension it expects and the call.
struct Reader {
    name: &'static str,
    ext: &'static str,
    read: fn(&Path) -> anyhow::Result<()>,
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn readers() -> Vec<Reader> {
    vec![
        Reader { name: "measurements_csv", ext: "csv", read: |p| mdpipe::artifacts::read_measurements(p).map(drop) },
        Reader {
            name: "measurements_parquet",
            ext: "parquet",
            read: |p| mdpipe::artifacts::read_measurements(p).map(drop),
        },
        Reader { name: "paper_table", ext: "dat", read: |p| mdpipe::paper_table::read(p).map(drop) },
        Reader {
            name: "training_table",
            ext: "csv",
            read: |p| mdpipe::emulator::read_training_table(p, &["g".into(), "v0".into()]).map(drop),
        },
        Reader {
            name: "iebe_music_text",
            ext: "dat",
            read: |p| {
                mdpipe::ingest::layout::parse_text_table(p, &String::from_utf8_lossy(&std::fs::read(p)?)).map(drop)
            },
        },
        Reader {
            name: "iebe_music_hdf5",
            ext: "h5",
            // An event group that cannot be read is reported and skipped by ingest: a refusal too.
            read: |p| match mdpipe::ingest::hdf5::read_events(p)? {
                (_, bad) if !bad.is_empty() => anyhow::bail!("{} unreadable events", bad.len()),
                _ => Ok(()),
            },
        },
        Reader { name: "config", ext: "toml", read: |p| mdpipe::systems::load(p).map(drop) },
        Reader {
            name: "checkpoint",
            ext: "json",
            read: |p| {
                // An unreadable or foreign checkpoint is ignored (a fresh start), not an error.
                let c = Checkpointing::new(p.parent().unwrap(), "key".into(), None);
                c.load::<ReplicateOutput>(p.file_stem().unwrap().to_str().unwrap())
                    .map(drop)
                    .ok_or_else(|| anyhow::anyhow!("ignored"))
            },
        },
    ]
}

/// A valid input of each reader.
fn seed_input(name: &str, dir: &Path) -> Vec<u8> {
    let fixture = |p: &str| std::fs::read(root().join(p)).unwrap();
    match name {
        "measurements_csv" => fixture("pipeline/ball_drop_data.csv"),
        "measurements_parquet" => {
            let data = mdpipe::artifacts::read_measurements(&root().join("pipeline/ball_drop_data.csv")).unwrap();
            let p = dir.join("seed.parquet");
            mdpipe::artifacts::write_measurements(&p, &data[..6], None).unwrap();
            std::fs::read(p).unwrap()
        }
        "paper_table" => fixture("pipeline/reference/iebe_music_grad_shear0p1_esw0p2.dat"),
        "training_table" => {
            let mut t = String::from("design_id,observable,x,value,g,v0\n");
            for i in 0..4 {
                for x in [0.0, 0.5] {
                    t.push_str(&format!(
                        "{i},velocity,{x},{},{},{}\n",
                        0.3 * i as f64 + x,
                        9.0 + i as f64,
                        0.1 * i as f64
                    ));
                }
            }
            t.into_bytes()
        }
        "iebe_music_text" => {
            fixture("tests/fixtures/iebe_music/runs/0001/spvn_results_6/particle_211_vndata_diff_y_-0.5_0.5.dat")
        }
        "iebe_music_hdf5" => fixture("tests/fixtures/iebe_music/runs/0003/spvn_results.h5"),
        "config" => {
            let data = root().join("pipeline/ball_drop_data.csv").display().to_string();
            String::from_utf8(fixture("pipeline/ball_drop.toml"))
                .unwrap()
                .replace("ball_drop_data.csv", &data)
                .into_bytes()
        }
        "checkpoint" => {
            let c = Checkpointing::new(dir, "key".into(), None);
            let out = ReplicateOutput {
                particles: vec![1.0, 2.0, 3.0, 4.0],
                log_evidence: -3.5,
                relative_variance: 0.01,
                steps: Vec::new(),
                likelihood_evaluations: 10,
                term_evaluations: 0,
                unique_fraction: 0.5,
                abandoned_at: None,
            };
            c.save("seed", &out);
            std::fs::read(dir.join("seed.json")).unwrap()
        }
        other => panic!("no seed input for {other}"),
    }
}

/// Runs `reader` on `bytes` written to a file: whether it read them (`true`)
/// or refused them with an error (`false`); `Err(message)` if it panicked.
fn outcome(reader: &Reader, bytes: &[u8], dir: &Path, tag: &str) -> Result<bool, String> {
    let path = dir.join(format!("{tag}.{}", reader.ext));
    std::fs::write(&path, bytes).unwrap();
    let result = std::panic::catch_unwind(AssertUnwindSafe(|| (reader.read)(&path)));
    let _ = std::fs::remove_file(&path);
    result.map(|r| r.is_ok()).map_err(|p| {
        p.downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default()
    })
}

fn tmp(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mdpipe-readers-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn mutated_inputs_give_errors_not_panics() {
    let dir = tmp("fuzz");
    let mut failures = Vec::new();
    let (cases, rng_seed) = (env_or("MDPIPE_FUZZ_CASES", CASES), env_or("MDPIPE_FUZZ_SEED", 20_261_123u64));
    for reader in readers() {
        let seed = seed_input(reader.name, &dir);
        assert!(
            matches!(outcome(&reader, &seed, &dir, "valid"), Ok(true)),
            "{}: the valid seed input is refused or panics",
            reader.name
        );
        let config = RunnerConfig {
            cases,
            rng_seed: RngSeed::Fixed(rng_seed),
            failure_persistence: None,
            ..RunnerConfig::default()
        };
        let mut runner = TestRunner::new(config);
        let refused = std::cell::Cell::new(0u32);
        let result = runner.run(&vec(edit(), 1..6), |edits| {
            let bytes = apply(&seed, &edits);
            let accepted =
                outcome(&reader, &bytes, &dir, "case").map_err(|m| TestCaseError::fail(format!("panicked: {m}")))?;
            refused.set(refused.get() + u32::from(!accepted));
            Ok(())
        });
        // The mutations must reach the readers' error paths, or the test proves little.
        println!("{}: {} of {cases} mutated inputs refused with an error, the rest read", reader.name, refused.get());
        assert!(
            refused.get() > cases / 10,
            "{}: only {} of {cases} mutated inputs were refused",
            reader.name,
            refused.get()
        );
        if let Err(e) = result {
            // Keep the shrunk input for the corpus, so the fix stays tested.
            let keep = dir.join(format!("failing_{}.{}", reader.name, reader.ext));
            if let proptest::test_runner::TestError::Fail(_, edits) = &e {
                std::fs::write(&keep, apply(&seed, edits)).unwrap();
            }
            failures.push(format!("{}: {e} (input kept in {})", reader.name, keep.display()));
        }
    }
    assert!(failures.is_empty(), "readers that panicked:\n{}", failures.join("\n"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Inputs that once made a reader panic: `tests/fixtures/corpus/<reader>/*`.
#[test]
fn corpus_inputs_give_errors_not_panics() {
    let dir = tmp("corpus");
    let mut replayed = 0;
    for reader in readers() {
        let folder = root().join("tests/fixtures/corpus").join(reader.name);
        let Ok(entries) = std::fs::read_dir(&folder) else { continue };
        for entry in entries {
            let path = entry.unwrap().path();
            let bytes = std::fs::read(&path).unwrap();
            if let Err(m) = outcome(&reader, &bytes, &dir, "corpus") {
                panic!("{}: {} panicked: {m}", reader.name, path.display());
            }
            replayed += 1;
        }
    }
    assert!(replayed > 0, "the corpus is empty");
    let _ = std::fs::remove_dir_all(&dir);
}
