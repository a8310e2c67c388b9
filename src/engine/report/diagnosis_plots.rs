//! A diagnosis's figures: the mismatch map and the Bayes-factor chart.

use super::*;

/// Heat map: observable × x, coloured by posterior-mean δ/σ.
pub fn mismatch_map(d: &Diagnosis, x_units: &str) -> Result<String> {
    let rows = &d.mismatch;
    let max = rows.iter().flat_map(|m| m.map.iter().map(|p| p.1.abs())).fold(1.0, f64::max);
    let caption = if rows.iter().any(|m| m.map.iter().any(|p| p.1.is_nan())) {
        "mismatch map: posterior-mean δ / σ (grey: not computed)"
    } else {
        "mismatch map: posterior-mean δ / σ"
    };
    svg(
        |root| {
            let (main, bar) = root.split_horizontally(W + 40);
            let n = rows.len();
            let xr = range_of(rows.iter().flat_map(|m| m.map.iter().map(|p| p.0)));
            let mut chart = p!(ChartBuilder::on(&main)
                .caption(caption, ("sans-serif", 16))
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(110)
                .build_cartesian_2d(xr.0..xr.1, 0.0..n as f64));
            let names: Vec<String> = rows.iter().map(|m| m.observable.clone()).collect();
            let xd = axis("x", x_units);
            p!(chart
                .configure_mesh()
                .disable_mesh()
                .x_desc(xd.as_str())
                .y_desc("observable")
                .y_labels(n * 2 + 1)
                .y_label_formatter(&|v| category_label(&names, *v))
                .draw());
            for (k, m) in rows.iter().enumerate() {
                let xs: Vec<f64> = m.map.iter().map(|p| p.0).collect();
                for (i, &(x, z)) in m.map.iter().enumerate() {
                    let left =
                        if i == 0 { x - (xs.get(1).unwrap_or(&(x + 0.1)) - x) / 2.0 } else { (x + xs[i - 1]) / 2.0 };
                    let right = if i + 1 == xs.len() { x + (x - left) } else { (x + xs[i + 1]) / 2.0 };
                    p!(chart.draw_series(std::iter::once(Rectangle::new(
                        [(left, k as f64 + 0.05), (right, k as f64 + 0.95)],
                        diverging(z / max).filled()
                    ))));
                }
            }
            // Colour bar.
            let mut cb = p!(ChartBuilder::on(&bar)
                .margin(8)
                .margin_top(40)
                .margin_right(30)
                .y_label_area_size(75)
                .build_cartesian_2d(0.0..1.0, -max..max));
            p!(cb
                .configure_mesh()
                .disable_x_axis()
                .disable_mesh()
                .y_labels(5)
                .y_label_style(("sans-serif", 15))
                .axis_desc_style(("sans-serif", 15))
                .y_desc("δ/σ")
                .draw());
            p!(cb.draw_series((0..100).map(|i| {
                let v0 = -max + 2.0 * max * i as f64 / 100.0;
                let v1 = v0 + 2.0 * max / 100.0;
                Rectangle::new([(0.0, v0), (1.0, v1)], diverging(v0 / max).filled())
            })));
            Ok(())
        },
        W + 200,
        60 + 70 * rows.len() as u32 + 60,
    )
}

/// Axis label for categories drawn at k + 0.5 on a numeric axis; blank elsewhere.
pub(super) fn category_label(names: &[String], v: f64) -> String {
    let k = v.floor() as usize;
    if (v - k as f64 - 0.5).abs() < 0.26 && k < names.len() {
        names[k].clone()
    } else {
        String::new()
    }
}

/// Grey: a value that could not be computed (NaN). Cast to u8, NaN gave 0
/// and painted such a cell the deepest blue, a strong negative δ.
const NOT_COMPUTED: RGBColor = RGBColor(170, 170, 170);

/// Blue (negative) – white – red (positive); grey where not computed.
pub(super) fn diverging(t: f64) -> RGBColor {
    if t.is_nan() {
        return NOT_COMPUTED;
    }
    let t = t.clamp(-1.0, 1.0);
    if t >= 0.0 {
        RGBColor(255, (255.0 * (1.0 - t)) as u8, (255.0 * (1.0 - t)) as u8)
    } else {
        RGBColor((255.0 * (1.0 + t)) as u8, (255.0 * (1.0 + t)) as u8, 255)
    }
}

/// Bar chart of each model's log evidence relative to the leader's (the
/// best candidate or the MD fit), one horizontal bar per model, best on top.
/// The differences that decide a verdict are a few units while models that
/// miss sit hundreds below, so the axis stops at [`BF_AXIS_FLOOR`] and a
/// longer bar is cut there with its value written on it. The dashed line is
/// the decisive margin: a model to its right is not excluded by the leader.
pub fn bayes_factor_chart(d: &Diagnosis) -> Result<String> {
    let best = d.candidates.iter().map(|c| c.log_evidence).fold(f64::NEG_INFINITY, f64::max);
    let mut rows: Vec<(String, f64, RGBColor)> = d
        .candidates
        .iter()
        .map(|c| {
            let chosen = c.name == d.verdict.best || d.verdict.standing.contains(&c.name);
            let colour = if chosen { RGBColor(205, 120, 20) } else { RGBColor(110, 110, 160) };
            // Without a fit of the model itself, each against the best candidate.
            let against = if d.base_log_evidence.is_finite() { c.log_bayes_factor } else { c.log_evidence - best };
            (short_name(&c.name), against, colour)
        })
        .collect();
    if d.base_log_evidence.is_finite() {
        rows.push(("model + MD".into(), d.md_log_evidence - d.base_log_evidence, RGBColor(30, 150, 60)));
        rows.push(("model, no MD".into(), 0.0, RGBColor(200, 60, 50)));
    }
    rows.retain(|r| r.1.is_finite());
    rows.sort_by(|a, b| b.1.total_cmp(&a.1));
    let leader = rows.first().map(|r| r.1).unwrap_or(0.0);
    let margin = crate::engine::diagnose::DiagnoseSettings::default().strong_log_bf;
    let floor = rows.iter().map(|r| r.1 - leader).fold(0.0f64, f64::min).max(BF_AXIS_FLOOR).min(-3.0 * margin);
    let names: Vec<String> = rows.iter().map(|r| r.0.clone()).collect();
    let n = names.len();
    // Room for the longest name at about 7 px a character, and 26 px a bar.
    let label_width = 7 * names.iter().map(|s| s.chars().count()).max().unwrap_or(8) as u32 + 16;
    let height = H.max(26 * n as u32 + 90);
    svg(
        |root| {
            let mut chart = p!(ChartBuilder::on(root)
                .caption(
                    format!("log Bayes factor against the leader (dashed: the decisive margin, {margin})"),
                    ("sans-serif", 15)
                )
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(label_width)
                .build_cartesian_2d(floor * 1.02..0.5, 0.0..n as f64));
            // Row k from the top is category n - 1 - k on the axis.
            let row = |v: f64| category_label(&names, n as f64 - v);
            p!(chart
                .configure_mesh()
                .disable_y_mesh()
                .x_desc("log Z − log Z(leader)")
                .y_desc("model")
                .y_labels(2 * n + 1)
                .y_label_formatter(&|v| row(*v))
                .draw());
            for (k, (_, value, colour)) in rows.iter().enumerate() {
                let top = (n - k) as f64;
                let relative = value - leader;
                let end = relative.max(floor);
                p!(chart.draw_series(std::iter::once(Rectangle::new(
                    [(end, top - 0.15), (0.0, top - 0.85)],
                    colour.filled()
                ))));
                if k == 0 {
                    // The leader's bar has no length: name it and its own Bayes factor.
                    p!(chart.draw_series(std::iter::once(Rectangle::new(
                        [(floor * 0.004, top - 0.15), (0.0, top - 0.85)],
                        colour.filled()
                    ))));
                    p!(chart.draw_series(std::iter::once(Text::new(
                        format!("the leader: log BF {value:.1} against the model without MD"),
                        (floor * 0.99, top - 0.38),
                        ("sans-serif", 12).into_font()
                    ))));
                }
                if relative < floor {
                    p!(chart.draw_series(std::iter::once(Text::new(
                        format!("{relative:.1}"),
                        (floor * 0.99, top - 0.38),
                        ("sans-serif", 12).into_font().color(&WHITE)
                    ))));
                }
            }
            p!(chart.draw_series(DashedLineSeries::new(
                vec![(-margin, 0.0), (-margin, n as f64)],
                6,
                4,
                BLACK.stroke_width(1)
            )));
            Ok(())
        },
        W + 100 + label_width,
        height,
    )
}

/// How far below the leader the Bayes-factor chart's axis reaches.
pub(super) const BF_AXIS_FLOOR: f64 = -40.0;

/// A candidate's name as an axis label: a combination of many (each
/// observable's correction together) as its first and how many more.
fn short_name(name: &str) -> String {
    let members: Vec<&str> = name.split('+').collect();
    if name.chars().count() <= 40 || members.len() < 2 {
        return name.to_string();
    }
    format!("{} + {} more", members[0], members.len() - 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_not_computed_is_grey_never_a_colour_of_the_scale() {
        let grey = diverging(f64::NAN);
        assert_eq!((grey.0, grey.1, grey.2), (170, 170, 170));
        // The scale's ends and middle: deep blue, white, deep red.
        let ends = [diverging(-1.0), diverging(0.0), diverging(1.0)].map(|c| (c.0, c.1, c.2));
        assert_eq!(ends, [(0, 0, 255), (255, 255, 255), (255, 0, 0)]);
        assert!(!ends.contains(&(grey.0, grey.1, grey.2)));
    }
}
