//! Clear errors for bad declarations: each names the file, the table and
//! the formula at fault (`declared` holds the models that are accepted).

use crate::declared::{root, tmpdir};
use mdpipe::calibrate::{Overrides, Problem};
use std::path::Path;

fn error_of(dir: &Path, name: &str, text: &str) -> String {
    let path = dir.join(name);
    std::fs::write(
        &path,
        text.replace("\"ball_drop_data.csv\"", &format!("{:?}", root().join("pipeline/ball_drop_data.csv"))),
    )
    .unwrap();
    let result = mdpipe::systems::load(&path)
        .and_then(|a| Problem::new(&a, &Overrides::default()).map(|_| ()).and_then(|_| a.candidates().map(|_| ())));
    format!("{:#}", result.err().unwrap_or_else(|| panic!("{name} was accepted")))
}

#[test]
fn bad_declarations_get_errors_naming_file_table_and_formula() {
    let dir = tmpdir("bad");
    let base = std::fs::read_to_string(root().join("pipeline/ball_drop.toml")).unwrap();
    let cases = [
        (
            "unknown.toml",
            base.replace("v = \"g\"", "v = \"g - drag*v\""),
            vec!["unknown.toml", "[model.rates] v", "unknown name 'drag'", "g - drag*v"],
        ),
        (
            "syntax.toml",
            base.replace("height = \"h\"", "height = \"h*(\""),
            vec!["syntax.toml", "[model.observables] height", "not a formula", "h*("],
        ),
        (
            "prior.toml",
            base.replace("rates = { v = \"-b*v\" }", "rates = { v = \"-b*v*c\" }"),
            vec!["prior.toml", "[[candidates]] linear_drag", "unknown name 'c'"],
        ),
        (
            "corner.toml",
            base.replace("v = \"g\"", "v = \"g + 1/v0\""),
            vec!["corner.toml", "[model.rates] v", "g + 1/v0", "not finite", "v0 = "],
        ),
        (
            "state.toml",
            base.replace("[model.rates]\nh = \"-v\"\n", "[model.rates]\n"),
            vec!["state.toml", "[model.initial] h", "no rate for 'h'"],
        ),
        (
            "clash.toml",
            base.replace("constants = { h0 = 60.0 }", "constants = { h0 = 60.0, g = 9.8 }"),
            vec!["clash.toml", "'g' is both a parameter and a constant"],
        ),
        (
            "euler.toml",
            base.replace("constants = { h0 = 60.0 }", "constants = { h0 = 60.0, e = 1.0 }"),
            vec!["euler.toml", "'e' is a mathematical constant"],
        ),
        (
            "target.toml",
            base.replace("rates = { v = \"-f\" }", "rates = { w = \"-f\" }"),
            vec!["target.toml", "[[candidates]] constant_force", "no state variable 'w'"],
        ),
        (
            "truth.toml",
            base.replace(
                "candidates = { quadratic_drag = { k = 0.4 } }",
                "candidates = { quadratic_drag = { kk = 0.4 } }",
            ),
            vec!["truth.toml", "[truth.candidates] quadratic_drag", "'k'"],
        ),
        ("solver.toml", base.replace("rtol = 1e-8", "rtol = 0.0"), vec!["solver.toml", "[model.solver]", "rtol"]),
        (
            "unused.toml",
            base.replace("rates = { v = \"-b*v\" }", "rates = { v = \"-0.5*v\" }"),
            vec!["unused.toml", "[[candidates]] linear_drag: [candidates.parameters.b]", "no formula uses it"],
        ),
        (
            "shadow.toml",
            base.replace(
                "candidates = { quadratic_drag = { k = 0.4 } }",
                "candidates = { quadratic_drag = { k = 0.4 } }\nconstants = { g = 1.0 }",
            ),
            vec!["shadow.toml", "[truth.constants] g"],
        ),
    ];
    for (name, text, says) in cases {
        assert_ne!(text, base, "{name}: the replacement did not apply");
        let msg = error_of(&dir, name, &text);
        println!("{name}: {msg}");
        for s in says {
            assert!(msg.contains(s), "{name}: the error should say {s:?}: {msg}");
        }
    }
}
