//! The calibrate and report stages: every observable set × kernel as one
//! case, stamped on its own so an interrupted stage resumes case by case.

use super::stages::*;
use crate::base::artifacts::{self, Provenance};
use crate::base::config::Config;
use crate::base::progress::observer;
use crate::engine::calibrate::{self, Analysis, Overrides, Problem};
use crate::engine::compare;
use crate::engine::emulator::EmulatorFamily;
use crate::engine::execute::{self, Executor, OutputKind, SimulatorSpec};
use crate::engine::gp::DiscrepancyKernel;
use crate::engine::model::Registry;
use crate::systems::heavy_ion::family::HeavyIonFamily;
use crate::systems::heavy_ion::figures::HeavyIonFigures;
use anyhow::{anyhow, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// One calibration case of the calibrate stage.
pub(super) struct Case {
    index: usize,
    name: String,
    set: Vec<String>,
    kernel: Option<DiscrepancyKernel>,
    dir: PathBuf,
    seed: u64,
    key: String,
    stamp: PathBuf,
}

impl Study<'_> {
    /// The analysis config pointed at the study's emulator (refined, with
    /// `[run.refine]`) and mock data.
    pub(super) fn study_config(&self) -> Result<Config> {
        Ok(self.study_config_with(&self.study_emulator()?))
    }

    /// The analysis config pointed at `emulator` and this run's mock data.
    pub(super) fn study_config_with(&self, emulator: &Path) -> Config {
        let mut c = self.config.clone();
        // The config's own [model] keys (its units) stay; the study's emulator is the artifact.
        let emulator_kind = c.model.get("kind").and_then(|k| k.as_str()) == Some("emulator");
        let mut model = if emulator_kind { c.model.clone() } else { toml::Table::new() };
        model.extend(EmulatorFamily::model_table(&absolute(emulator)));
        c.model = model;
        if self.run.stand_in_study() {
            c.data.measurements = absolute(&self.paths.measurements());
            // The mock's bins are counted from the same events (correlated by
            // 0.6-0.95 within a spectrum); with errors alone the likelihood
            // is overconfident and the MD fits excluded ε_sw by 2-3 sd.
            let covariance = self.paths.mock().join("covariance.csv");
            c.data.covariance = covariance.exists().then(|| absolute(&covariance));
        }
        c
    }

    /// The study's analysis: the stand-in's emulator as the model, the
    /// stand-in itself as the `[truth]` process.
    pub(super) fn analysis(&self, config: &Config) -> Result<Analysis> {
        let mut families = Registry::new();
        families.register(Arc::new(EmulatorFamily)).register(Arc::new(HeavyIonFamily));
        let mut analysis = Analysis::resolve(config, &families)?;
        // The emulator knows no units; the stand-in's come first, as in its figures.
        if self.run.stand_in_study() {
            analysis.units = HeavyIonFamily::units().or(&analysis.units);
        }
        Ok(analysis)
    }

    /// The calibration cases: every observable set × kernel, with its seed and key.
    pub(super) fn cases(&self, keys: &Keys) -> Result<Vec<Case>> {
        let mut cases = Vec::new();
        for (i, set) in self.run.observable_sets.iter().enumerate() {
            for (j, k) in self.run.kernels.iter().enumerate() {
                let kernel = DiscrepancyKernel::parse(k)
                    .ok_or_else(|| anyhow!("[run] kernels: unknown kernel {k:?} (use none, I or II)"))?;
                let name = compare::case_dir_name(set, kernel);
                let seed = self.opts.seed.wrapping_add((i * 3 + j) as u64 * 1_000_003);
                let material = serde_json::json!({"config": self.analysis_hash()?, "data": self.data_hash()?, "set": set, "kernel": k, "seed": seed, "emulator": keys.upstream.get("emulator"), "mock": keys.upstream.get("mock"), "refine": keys.upstream.get("refine")});
                let key = artifacts::sha256_hex(material.to_string().as_bytes());
                cases.push(Case {
                    index: cases.len(),
                    dir: self.paths.calibrate().join(&name),
                    stamp: self.paths.stamp(&format!("calibrate/{name}")),
                    name,
                    set: set.clone(),
                    kernel,
                    seed,
                    key,
                });
            }
        }
        Ok(cases)
    }

    /// Whether a case finished earlier with the same key (so an interrupted stage resumes case by case).
    pub(super) fn case_done(&self, c: &Case) -> bool {
        !self.opts.force && read_stamp(&c.stamp).is_some_and(|s| s.key == c.key) && c.dir.join("summary.json").exists()
    }

    pub(super) fn calibrate_case(&self, analysis: &Analysis, c: &Case) -> Result<()> {
        let ov = Overrides { kernel: Some(c.kernel), observables: Some(c.set.clone()), ..Default::default() };
        let problem = Problem::new(analysis, &ov)?;
        // Killed mid-case, the case resumes from its last saved tempering step.
        let checkpoint = calibrate::checkpoint::Checkpointing::new(
            &c.dir.join(".checkpoint"),
            calibrate::checkpoint_key(&problem, c.seed),
            None,
        );
        let cal = calibrate::run_and_write(&problem, c.seed, observer(self.opts.show_progress), &checkpoint, &c.dir)?;
        let seconds = cal.summary.diagnostics.wall_seconds;
        let prov = Provenance::new(
            self.config.hash.clone(),
            String::new(),
            c.seed,
            &format!("run {} --stage calibrate ({})", self.config.path.display(), c.name),
        );
        artifacts::write_json_atomic(
            &c.stamp,
            &Stamp {
                stage: format!("calibrate/{}", c.name),
                key: c.key.clone(),
                output_key: String::new(),
                seconds,
                provenance: prov,
            },
        )?;
        println!("  {:<60} {seconds:>6.1} s", c.name);
        Ok(())
    }

    /// Under `--executor slurm`, the cases not yet done go out as one job
    /// array, each task `mdpipe run … --stage calibrate --case <index>`; a case
    /// whose task failed is then calibrated here, with the others kept.
    pub(super) fn calibrate_as_array(&self, cases: &[Case]) -> Result<()> {
        let todo: Vec<&Case> = cases.iter().filter(|c| !self.case_done(c)).collect();
        if todo.is_empty() {
            return Ok(());
        }
        let out = absolute(&self.paths.out);
        let command = format!(
            "{{mdpipe}} run {} --out {} --seed {} --stage calibrate --case {{id}}",
            execute::spec::shell_quote(&absolute(&self.config.path).display().to_string()),
            execute::spec::shell_quote(&out.display().to_string()),
            self.opts.seed
        );
        let template = self.run.simulator.clone();
        let spec = SimulatorSpec {
            command,
            placeholders: BTreeMap::new(),
            output: OutputKind::Exit,
            time_limit: self.run.calibration_time_limit.clone(),
            retries: template.as_ref().map_or(1, |t| t.retries),
            parallel: None,
            slurm: template.map(|t| t.slurm).unwrap_or_default(),
        };
        let runs = self.paths.calibrate().join(".array");
        let points = todo
            .iter()
            .map(|c| execute::Point { id: c.index as i64, values: BTreeMap::new(), param_file: runs.join("none") })
            .collect();
        let job = execute::Job {
            spec: &spec,
            workdir: out.clone(),
            design: runs.join("none"),
            runs: runs.clone(),
            points,
            label: "calibrations".into(),
            mdpipe: self.opts.mdpipe.clone(),
            seed: 0,
        };
        std::fs::create_dir_all(&runs)?;
        match execute::run(&job, Executor::Slurm, self.opts.show_progress) {
            Ok(report) if report.failed.is_empty() => {}
            Ok(report) => {
                report.print_failures();
                println!(
                    "  warning: {} calibration task(s) failed under Slurm; those cases run here",
                    report.failed.len()
                );
            }
            Err(e) => println!("  warning: {e:#}; the cases run here"),
        }
        Ok(())
    }

    pub(super) fn calibrate(&self, keys: &Keys) -> Result<()> {
        let config = self.study_config()?;
        let analysis = self.analysis(&config)?;
        let cases = self.cases(keys)?;
        if let Some(index) = self.opts.case {
            // One array task: this case only; the stage is assessed and stamped by the mdpipe that submitted it.
            let c = cases
                .get(index)
                .ok_or_else(|| anyhow!("--case {index}: the study has {} calibration cases", cases.len()))?;
            return if self.case_done(c) { Ok(()) } else { self.calibrate_case(&analysis, c) };
        }
        if self.opts.executor == Executor::Slurm {
            self.calibrate_as_array(&cases)?;
        }
        let mut dirs = Vec::new();
        for c in &cases {
            if self.case_done(c) {
                println!("  {:<60} done earlier, kept", c.name);
            } else {
                self.calibrate_case(&analysis, c)?;
            }
            dirs.push(c.dir.clone());
        }
        if !self.run.stand_in_study() {
            return self.write_cases(&dirs);
        }
        let truth_curve: BTreeMap<String, f64> = self.truth_named()?.into_iter().collect();
        let study = crate::systems::heavy_ion::study::assess(
            &config,
            &dirs,
            &truth_curve,
            &self.study_emulator()?,
            &self.paths.validation(),
            &self.paths.measurements(),
        )?;
        artifacts::write_json_atomic(&self.paths.out.join("study.json"), &study)?;
        let mut md = study.markdown();
        if let Some(rounds) = self.rounds()? {
            md.push_str(&rounds.study_section());
        }
        artifacts::write_text_atomic(&self.paths.out.join("study.md"), &md)?;
        println!("{md}");
        Ok(())
    }

    /// Without mock data there is no truth to assess: each case's parameters
    /// and evidence, as `calibrate/cases.json` and `cases.md`.
    pub(super) fn write_cases(&self, dirs: &[PathBuf]) -> Result<()> {
        let mut cases = Vec::new();
        let mut md = String::from(
            "| case | parameter | median | 95% interval | log evidence | converged |\n|---|---|---|---|---|---|\n",
        );
        for dir in dirs {
            let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json"))?)?;
            let case = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            for name in self.config.parameters.keys() {
                let p = &summary["parameters"][name];
                md.push_str(&format!(
                    "| {case} | {name} | {:.4} | [{:.4}, {:.4}] | {:.2} | {} |\n",
                    p["median"].as_f64().unwrap_or(f64::NAN),
                    p["q025"].as_f64().unwrap_or(f64::NAN),
                    p["q975"].as_f64().unwrap_or(f64::NAN),
                    summary["log_evidence"].as_f64().unwrap_or(f64::NAN),
                    summary["diagnostics"]["converged"]
                ));
            }
            cases.push(serde_json::json!({"case": case, "parameters": summary["parameters"], "log_evidence": summary["log_evidence"], "converged": summary["diagnostics"]["converged"]}));
        }
        let prov = Provenance::new(
            self.config.hash.clone(),
            self.data_hash()?,
            self.opts.seed,
            &format!("run {} --stage calibrate", self.config.path.display()),
        );
        let mut staged = artifacts::StagedWrites::new();
        staged.json(
            &self.paths.calibrate().join("cases.json"),
            &serde_json::json!({"cases": cases, "provenance": prov}),
        )?;
        staged.text(&self.paths.calibrate().join("cases.md"), &md)?;
        staged.commit()?;
        println!("{md}");
        Ok(())
    }

    /// SHA-256 of the measurements the calibrations use (the config's, when there is no mock stage).
    pub(super) fn data_hash(&self) -> Result<String> {
        if self.run.stand_in_study() {
            return Ok(String::new());
        }
        let path = self.config.resolve(&self.config.data.measurements);
        Ok(artifacts::sha256_hex(
            &std::fs::read(&path).with_context(|| format!("reading the measurements {}", path.display()))?,
        ))
    }

    pub(super) fn report(&self, _keys: &Keys) -> Result<()> {
        if !self.run.stand_in_study() {
            let html = crate::engine::report::build(
                &[self.paths.calibrate(), self.study_emulator()?],
                &format!("mdpipe run: {}", self.config.name),
                &[],
            )?;
            artifacts::write_text_atomic(&self.paths.out.join("report.html"), &html)?;
            println!("  {}", self.paths.out.join("report.html").display());
            return Ok(());
        }
        let study: crate::systems::heavy_ion::study::Study =
            serde_json::from_str(&std::fs::read_to_string(self.paths.out.join("study.json"))?)?;
        let mut dirs = vec![self.paths.calibrate(), self.study_emulator()?];
        dirs.dedup();
        let html =
            crate::engine::report::build(&dirs, &format!("mdpipe run: {}", self.config.name), &[&HeavyIonFigures])?;
        let html = html.replacen("</h1>\n", &format!("</h1>\n{}", study.html()), 1);
        artifacts::write_text_atomic(&self.paths.out.join("report.html"), &html)?;
        println!("  {}", self.paths.out.join("report.html").display());
        Ok(())
    }
}
