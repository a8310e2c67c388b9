//! PNG copies of the report's figures, rasterised from the same SVG with
//! resvg (pure Rust; text uses the system's fonts).

use anyhow::{anyhow, Context, Result};
use std::path::{Path, PathBuf};

/// Each inline `<svg …>…</svg>` of an HTML page, in order.
fn inline_svgs(html: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = html;
    while let Some(start) = rest.find("<svg") {
        let Some(len) = rest[start..].find("</svg>") else { break };
        let end = start + len + "</svg>".len();
        out.push(&rest[start..end]);
        rest = &rest[end..];
    }
    out
}

/// Writes `figure_01.png`, `figure_02.png`, … (at twice the SVG size) into
/// `dir`, one per figure of `html`; returns their paths.
pub fn write_figures(html: &str, dir: &Path) -> Result<Vec<PathBuf>> {
    use resvg::{tiny_skia, usvg};
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut options = usvg::Options::default();
    let fonts = options.fontdb_mut();
    fonts.load_system_fonts();
    // fontdb maps "sans-serif" to Arial; use a sans face that is installed.
    let installed: Vec<String> = fonts.faces().flat_map(|f| f.families.iter().map(|(name, _)| name.clone())).collect();
    match ["DejaVu Sans", "Liberation Sans", "Noto Sans", "Arial"]
        .into_iter()
        .find(|f| installed.iter().any(|i| i == f))
        .or_else(|| installed.first().map(String::as_str))
    {
        Some(family) => {
            let family = family.to_string();
            fonts.set_sans_serif_family(family.clone());
            options.font_family = family;
        }
        None => crate::base::messages::note!(
            "warning: no system fonts found, so the PNG figures have no text (install e.g. fonts-dejavu-core)"
        ),
    }
    let scale = 2.0;
    let mut written = Vec::new();
    for (k, svg) in inline_svgs(html).into_iter().enumerate() {
        let tree = usvg::Tree::from_str(svg, &options).map_err(|e| anyhow!("figure {}: not valid SVG: {e}", k + 1))?;
        let size = tree.size().to_int_size().scale_by(scale).ok_or_else(|| anyhow!("figure {}: empty size", k + 1))?;
        let mut pixmap = tiny_skia::Pixmap::new(size.width(), size.height())
            .ok_or_else(|| anyhow!("figure {}: cannot allocate {}x{}", k + 1, size.width(), size.height()))?;
        pixmap.fill(tiny_skia::Color::WHITE);
        resvg::render(&tree, tiny_skia::Transform::from_scale(scale, scale), &mut pixmap.as_mut());
        let bytes = pixmap.encode_png().map_err(|e| anyhow!("figure {}: PNG encoding: {e}", k + 1))?;
        let path = dir.join(format!("figure_{:02}.png", k + 1));
        crate::base::artifacts::write_atomic(&path, |f| {
            use std::io::Write;
            f.write_all(&bytes).with_context(|| format!("writing {}", path.display()))
        })?;
        written.push(path);
    }
    Ok(written)
}
