//! The report page: run folders found and read, sections for calibrations,
//! a diagnosis and emulators, assembled into one self-contained HTML file.

use super::*;

pub fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// Finds calibration folders (with summary.json) in `dirs` and one level below.
pub(super) fn find_runs(dirs: &[PathBuf]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for d in dirs {
        if d.join("summary.json").exists() {
            out.push(d.clone());
        }
        if let Ok(rd) = std::fs::read_dir(d) {
            let mut subs: Vec<PathBuf> =
                rd.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.join("summary.json").exists()).collect();
            subs.sort();
            out.extend(subs);
        }
    }
    out
}

pub(super) fn figure(html: &mut String, caption: &str, svg: &str) {
    html.push_str(&format!("<figure>{svg}<figcaption>{}</figcaption></figure>\n", html_escape(caption)));
}

pub(super) const HEAD: &str = "<style>body{font-family:sans-serif;max-width:1250px;margin:2em auto;color:#222} figure{display:inline-block;margin:8px;vertical-align:top} figcaption{font-size:13px;color:#444;max-width:560px} table{border-collapse:collapse;font-size:13px} td,th{border:1px solid #bbb;padding:3px 6px} .verdict{font-size:17px;background:#f4f4e8;padding:10px;border-left:4px solid #c80}</style>";

/// Builds `report.html` from run folders; returns its text. `systems` add
/// their own figures to the runs they claim.
pub fn build(dirs: &[PathBuf], title: &str, systems: &[&dyn SystemFigures]) -> Result<String> {
    let runs: Vec<RunArtifacts> = find_runs(dirs).iter().map(|d| RunArtifacts::load(d)).collect::<Result<_>>()?;
    let mut html = format!(
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{0}</title>{HEAD}</head><body><h1>{0}</h1>\n",
        html_escape(title)
    );
    // Diagnosis first: it is the story.
    for d in dirs {
        let p = d.join("diagnosis.json");
        if p.exists() {
            let diag: Diagnosis = serde_json::from_str(&std::fs::read_to_string(&p)?)
                .with_context(|| format!("parsing {}", p.display()))?;
            diagnosis_section(&mut html, &diag, &runs)?;
            simulator_check_section(&mut html, &d.join("verify.json"))?;
        }
    }
    posterior_sections(&mut html, &runs, systems)?;
    emulator_section(&mut html, dirs)?;
    if let Some(r) = runs.first() {
        let p = &r.summary.provenance;
        // What the model chose from the data (an ODE's tolerances) belongs with how the run was made.
        let numerics = r.summary.numerics.as_deref().map(|n| format!(" · {}", html_escape(n))).unwrap_or_default();
        html.push_str(&format!(
            "<p style=\"font-size:12px;color:#666\">mdpipe {} · config {} · seed {}{numerics}</p>",
            p.mdpipe_version,
            &p.config_hash.get(..12).unwrap_or(""),
            p.seed
        ));
    }
    // Records each figure's rendered size on the page, so a headless browser
    // can check that every figure actually laid out (tests/it/diagnose.rs).
    html.push_str("<script>window.addEventListener('load',function(){var s=[];document.querySelectorAll('figure svg').forEach(function(e){var r=e.getBoundingClientRect();s.push(Math.round(r.width)+'x'+Math.round(r.height));});document.body.setAttribute('data-figure-sizes',s.join(','));});</script>\n");
    html.push_str("</body></html>\n");
    Ok(html)
}

/// The diagnosis's final fit run through the simulator (`verify.json`,
/// written by `mdpipe run`'s diagnose stage), when there is one.
fn simulator_check_section(html: &mut String, path: &Path) -> Result<()> {
    if !path.exists() {
        return Ok(());
    }
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path)?).with_context(|| format!("parsing {}", path.display()))?;
    let text = |k: &str| html_escape(v[k].as_str().unwrap_or(""));
    html.push_str(&format!(
        "<h3>Checked against the simulator</h3><p>{} ({}, {}).</p>\n",
        text("outcome"),
        text("fit"),
        text("model")
    ));
    let points = v["points"].as_array().cloned().unwrap_or_default();
    if !points.is_empty() {
        html.push_str(
            "<table><tr><th>θ</th><th>values</th><th>χ² from the simulator</th><th>χ² from the emulator</th><th>points</th></tr>\n",
        );
        for p in &points {
            let values: Vec<String> = p["theta"]
                .as_object()
                .into_iter()
                .flatten()
                .map(|(name, v)| format!("{name} = {:.4}", v.as_f64().unwrap_or(f64::NAN)))
                .collect();
            html.push_str(&format!(
                "<tr><td>{}</td><td>{}</td><td>{:.1}</td><td>{:.1}</td><td>{}</td></tr>\n",
                html_escape(p["label"].as_str().unwrap_or("")),
                html_escape(&values.join(", ")),
                p["chi2_simulator"].as_f64().unwrap_or(f64::NAN),
                p["chi2_emulator"].as_f64().unwrap_or(f64::NAN),
                p["points"].as_u64().unwrap_or(0)
            ));
        }
        html.push_str("</table>\n");
    }
    for advice in v["advice"].as_array().into_iter().flatten().filter_map(|a| a.as_str()) {
        html.push_str(&format!("<p>{}</p>\n", html_escape(advice)));
    }
    Ok(())
}

/// The verdict, the mismatch map, the candidates and the repair's before/after.
pub(super) fn diagnosis_section(html: &mut String, diag: &Diagnosis, runs: &[RunArtifacts]) -> Result<()> {
    let units = runs.first().map(|r| r.summary.units.clone()).unwrap_or_default();
    html.push_str("<h2>Diagnosis</h2>\n");
    html.push_str(&format!(
        "<p class=\"verdict\"><b>{}</b> ({}): {}</p>\n",
        html_escape(&diag.verdict.best),
        html_escape(&diag.verdict.confidence_phrase()),
        // A discovered term's [[candidates]] block follows the first line; it is shown under Discovery.
        html_escape(diag.verdict.statement.lines().next().unwrap_or(""))
    ));
    figure(
        html,
        "Where the model misses: posterior-mean discrepancy of the MD fit at each measurement, in units of its error.",
        &mismatch_map(diag, &units.x)?,
    );
    figure(
        html,
        "Every model's SMC evidence against the leader's: candidates (the verdict's in orange), the MD fit (green) and the model without MD (red). Bars beyond the axis are cut and carry their value.",
        &bayes_factor_chart(diag)?,
    );
    candidate_table(html, diag);
    discovery_section(html, diag);
    if let Some(imp) = &diag.improvement {
        html.push_str("<h3>Before and after the repair</h3><p>χ²/dof is of the model part η alone: for a fit with δ it is what δ had to absorb, not that fit's misfit.</p><table><tr><th>fit</th><th>χ²/dof of η</th><th>log Z</th><th>max |δ|/σ</th><th>parameters</th></tr>\n");
        for f in imp.before.iter().chain(&imp.after) {
            let dmax = f.delta_max_sigma.values().cloned().fold(0.0, f64::max);
            html.push_str(&format!(
                "<tr><td>{}</td><td>{:.2}</td><td>{:.2} ± {:.2}</td><td>{:.1}</td><td>{}</td></tr>\n",
                f.label,
                f.chi2_per_dof,
                f.log_evidence,
                f.log_evidence_err,
                dmax,
                intervals(&f.parameters)
            ));
        }
        html.push_str("</table>\n");
        let narrowing: Vec<String> = imp
            .interval_narrowing
            .iter()
            .map(|(n, r)| {
                let change = if *r >= 1.0 { format!("{r:.2}× narrower") } else { format!("{:.2}× wider", 1.0 / r) };
                match imp.information_limit.get(n) {
                    Some(l) => format!("{n}: {change} (Cramér–Rao limit of these data {l:.2}×)"),
                    None => format!("{n}: {change}"),
                }
            })
            .collect();
        html.push_str(&format!(
            "<p>95% intervals of the repaired model against model + δ: {}.</p>\n",
            narrowing.join("; ")
        ));
    }
    for (name, label) in [("base_md", "before: model + δ"), ("repaired_md", "after: repaired model + δ")] {
        let Some(run) = runs.iter().find(|r| r.dir.file_name().map(|f| f == name).unwrap_or(false)) else { continue };
        let u = &run.summary.units;
        for obs in &run.summary.observables {
            figure(
                html,
                &format!("{label}: δ({obs}) with its 95% band; after the repair it should hug zero."),
                &delta_plot(run, obs, &u.x, u.observable(obs))?,
            );
        }
        for obs in &run.summary.observables {
            figure(
                html,
                &format!("{label}: {obs}, data and predictions (the grid extends beyond the data)."),
                &prediction_plot(run, obs, &u.x, u.observable(obs), &format!("{label}: {obs}"))?,
            );
        }
    }
    Ok(())
}

/// "name = median [q025, q975], …".
pub(super) fn intervals(parameters: &BTreeMap<String, ParamSummary>) -> String {
    parameters.iter().map(|(n, p)| format!("{n} = {}", p.interval())).collect::<Vec<_>>().join(", ")
}

/// Per observable set: the corner plot of every kernel's run, the system's
/// own figures, a table, and (for the largest set) each run's predictions.
pub(super) fn posterior_sections(
    html: &mut String,
    runs: &[RunArtifacts],
    systems: &[&dyn SystemFigures],
) -> Result<()> {
    let mut sets: Vec<Vec<String>> = Vec::new();
    for r in runs {
        if !sets.contains(&r.summary.observables) {
            sets.push(r.summary.observables.clone());
        }
    }
    if !runs.is_empty() {
        html.push_str("<h2>Posteriors</h2>\n");
    }
    let largest = sets.iter().map(|s| s.len()).max().unwrap_or(0);
    // Candidate-augmented fits have extra parameters; diagnose shows them above.
    let is_candidate = |r: &RunArtifacts| {
        r.dir.file_name().and_then(|f| f.to_str()).is_some_and(|f| f.starts_with("candidate_") || f == "repaired_md")
    };
    for set in &sets {
        let group: Vec<&RunArtifacts> =
            runs.iter().filter(|r| &r.summary.observables == set && !is_candidate(r)).collect();
        if group.is_empty() {
            continue;
        }
        let system = systems.iter().find(|s| s.claims(group[0]));
        let theta: Vec<String> =
            group[0].summary.parameter_order.iter().filter(|n| !n.contains('.')).cloned().collect();
        let truth = group[0].summary.truth.clone();
        let units = group[0].summary.units.clone();
        let kernels: Vec<&str> = group.iter().map(|r| r.summary.kernel.as_str()).collect();
        figure(
            html,
            &format!("Observables {}: posteriors for kernels {} (no MD red, Kernel I blue, Kernel II green; truth dashed grey; coloured bands: median ± 68%; grey: the uniform prior's density).", set.join(", "), kernels.join(", ")),
            &corner_plot(&group, &theta, &truth, &|p| units.parameter(p).to_string())?,
        );
        for (caption, svg) in system.map(|s| s.posterior_figures(&group, &truth)).transpose()?.unwrap_or_default() {
            figure(html, &caption, &svg);
        }
        posterior_table(html, &group, &theta);
        if set.len() == largest {
            for r in &group {
                for obs in set {
                    let own = system.map(|s| s.prediction_figure(r, obs)).transpose()?.flatten();
                    let (caption, svg) = match own {
                        Some(f) => f,
                        None => (
                            format!(
                                "Kernel {}: {obs}, data with 1σ errors and 95% posterior-predictive bands.",
                                r.summary.kernel
                            ),
                            prediction_plot(
                                r,
                                obs,
                                &r.summary.units.x,
                                r.summary.units.observable(obs),
                                &format!("kernel {}: {obs}", r.summary.kernel),
                            )?,
                        ),
                    };
                    figure(html, &caption, &svg);
                }
            }
        }
    }
    Ok(())
}

pub(super) fn posterior_table(html: &mut String, group: &[&RunArtifacts], theta: &[String]) {
    html.push_str("<table><tr><th>kernel</th>");
    for t in theta {
        html.push_str(&format!("<th>{t} median [95%]</th>"));
    }
    html.push_str("<th>log Z</th><th>converged</th></tr>\n");
    for r in group {
        html.push_str(&format!("<tr><td>{}</td>", r.summary.kernel));
        for t in theta {
            let p = &r.summary.parameters[t];
            html.push_str(&format!("<td>{}</td>", p.interval()));
        }
        let z = r
            .summary
            .log_evidence
            .map(|z| format!("{z:.2} ± {:.2}", r.summary.log_evidence_err.unwrap_or(f64::NAN)))
            .unwrap_or_else(|| "–".into());
        html.push_str(&format!(
            "<td>{z}</td><td>{}</td></tr>\n",
            if r.summary.diagnostics.converged { "yes" } else { "NO" }
        ));
    }
    html.push_str("</table>\n");
}

/// Parity plots and z-score histograms for every emulator folder (with
/// `validation_parity.parquet`) in `dirs` or one level below.
pub(super) fn emulator_section(html: &mut String, dirs: &[PathBuf]) -> Result<()> {
    let mut found = Vec::new();
    for d in dirs {
        let mut candidates = vec![d.clone()];
        if let Ok(rd) = std::fs::read_dir(d) {
            let mut subs: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
            subs.sort();
            candidates.extend(subs);
        }
        found.extend(candidates.into_iter().filter(|c| c.join("validation_parity.parquet").exists()));
    }
    for dir in found {
        let rows = emulator::load_parity(&dir.join("validation_parity.parquet"))?;
        html.push_str(&format!("<h2>Emulator validation: {}</h2>\n", html_escape(&dir.display().to_string())));
        let mut sets: Vec<String> = Vec::new();
        for r in &rows {
            if !sets.contains(&r.set) {
                sets.push(r.set.clone());
            }
        }
        for set in &sets {
            let subset: Vec<&emulator::ParityRow> = rows.iter().filter(|r| &r.set == set).collect();
            figure(
                html,
                &format!("{set}: z-scores of every output; a calibrated emulator follows N(0, 1)."),
                &emulator::z_histogram(&subset, set)?,
            );
        }
        // Parity per observable, on the held-out design if there is one.
        let set = if sets.iter().any(|s| s == "holdout") {
            "holdout".to_string()
        } else {
            sets.first().cloned().unwrap_or_default()
        };
        let mut observables: Vec<String> = Vec::new();
        for r in rows.iter().filter(|r| r.set == set) {
            if !observables.contains(&r.observable) {
                observables.push(r.observable.clone());
            }
        }
        for obs in &observables {
            let subset: Vec<&emulator::ParityRow> =
                rows.iter().filter(|r| r.set == set && &r.observable == obs).collect();
            figure(
                html,
                &format!("{set}: emulated against simulated {obs}, every pT bin and design point."),
                &emulator::parity_plot(&subset, obs)?,
            );
        }
    }
    Ok(())
}

pub fn write(dirs: &[PathBuf], out: &Path, title: &str, systems: &[&dyn SystemFigures]) -> Result<()> {
    let html = build(dirs, title, systems)?;
    artifacts::write_text_atomic(out, &html)
}

/// Each candidate's evidence, fit and parameters; or why there are none.
fn candidate_table(html: &mut String, diag: &Diagnosis) {
    if diag.candidates.is_empty() {
        // After a search the Discovery section says what it tried.
        if diag.discovery.is_some() {
            return;
        }
        html.push_str("<p>No candidate was weighed: none was declared, and the search for physics nobody declared runs only when a mismatch is unexplained (<code>--discover</code>, or <code>[run] discover = true</code>, asks for it always).</p>\n");
        return;
    }
    // For emulated models, how much of each fit's predictive variance is the emulator's own.
    let emulated = diag.candidates.iter().any(|c| c.emulator_share > 0.0);
    let share_head = if emulated { "<th>emulator share of variance (worst observable)</th>" } else { "" };
    html.push_str(&format!("<table><tr><th>candidate</th><th>log BF</th><th>χ²/dof</th>{share_head}<th>parameters (median [95%])</th></tr>\n"));
    for c in &diag.candidates {
        let share = if emulated {
            format!("<td>{:.0}% {}</td>", 100.0 * c.emulator_share, c.emulator_share_observable)
        } else {
            String::new()
        };
        html.push_str(&format!(
            "<tr><td>{}</td><td>{:.1} ± {:.1}</td><td>{:.2}</td>{share}<td>{}</td></tr>\n",
            breakable(&c.name),
            c.log_bayes_factor,
            c.log_bayes_factor_err,
            c.chi2_per_dof,
            intervals(&c.parameters)
        ));
    }
    html.push_str("</table>\n");
}

/// A candidate's name, escaped, free to wrap after each `+` (each
/// observable's correction together is one long name).
fn breakable(name: &str) -> String {
    html_escape(name).replace('+', "+<wbr>")
}

/// Odds as a reader takes them in: 1:92, 1:4.6e7.
fn odds(against: f64) -> String {
    if against < 1e5 {
        format!("{against:.0}")
    } else {
        format!("{against:.1e}")
    }
}

/// What the search for undeclared terms tried, and the discovered term's
/// `[[candidates]]` block.
fn discovery_section(html: &mut String, diag: &Diagnosis) {
    let Some(d) = &diag.discovery else { return };
    html.push_str(&format!(
        "<h3>Discovery</h3><p>{} terms built from the model's own symbols were screened by least squares (forms: {}); the best went on to full calibration, each paying prior odds for the search:</p>\n",
        d.searched,
        html_escape(&d.forms.join("; "))
    ));
    html.push_str(
        "<table><tr><th>term</th><th>where</th><th>Δχ² (screening)</th><th>ΔBIC</th><th>prior odds</th></tr>\n",
    );
    for t in &d.screened {
        html.push_str(&format!(
            "<tr><td>{}</td><td>{}</td><td>{:.1}</td><td>{:.1}</td><td>1:{}</td></tr>\n",
            breakable(&t.name),
            html_escape(&t.formula).replace("; ", ";<br>"),
            t.delta_chi2,
            t.delta_bic,
            odds((-t.prior_log_odds).exp())
        ));
    }
    html.push_str("</table>\n");
    if let Some(t) = d.screened.iter().find(|t| Some(t.name.as_str()) == diag.verdict.named()) {
        html.push_str(&format!(
            "<p>Discovered: <b>{}</b> ({}). Declare it in the config to use it from now on:</p><pre>{}</pre>\n",
            html_escape(&t.formula),
            html_escape(&t.meaning),
            html_escape(&t.toml)
        ));
    }
}
