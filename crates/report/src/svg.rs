//! The one SVG plot writer of the reports: grouped bar charts, plain or stacked (the
//! build and trace parts of a frame's energy), self-contained (no fonts or scripts
//! fetched), with every bar's value in a tooltip (`<title>`).
//!
//! The MergeTree's cycle trace plot (`sim::mergetree::MergeTreeReport::trace_svg`) stays
//! beside its data in `sim`, which sits below this crate.

use std::fmt::Write as _;

/// A grouped bar chart: one group per label, one bar per series (missing values skipped).
pub fn bar_svg(title: &str, labels: &[String], series: &[(String, Vec<Option<f64>>)]) -> String {
    let stacked: Vec<(String, Vec<Option<Vec<f64>>>)> = series
        .iter()
        .map(|(n, v)| (n.clone(), v.iter().map(|x| x.map(|x| vec![x])).collect()))
        .collect();
    stacked_bar_svg(title, labels, &stacked, &[])
}

/// A grouped bar chart whose bars are stacks of parts (e.g. build and trace energy): one
/// group per label, one bar per series, the parts of a bar drawn bottom-up, the first in
/// the series' colour and later ones lighter; `parts` names them in the legend.
pub fn stacked_bar_svg(
    title: &str,
    labels: &[String],
    series: &[(String, Vec<Option<Vec<f64>>>)],
    parts: &[&str],
) -> String {
    const COLORS: [&str; 6] = [
        "#1f77b4", "#aec7e8", "#d62728", "#ff9896", "#2ca02c", "#98df8a",
    ];
    const OPACITY: [f64; 3] = [1.0, 0.45, 0.25];
    // Wide enough for the labels (about 7 px per character) and the legend (150 px per
    // series and part), and at least 760 px.
    let longest = labels.iter().map(|l| l.chars().count()).max().unwrap_or(0);
    let w = (80.0 + labels.len() as f64 * (7.0 * longest as f64 + 8.0))
        .max(80.0 + 150.0 * (series.len() + parts.len()) as f64)
        .max(760.0);
    let (h, left, bottom, top) = (360.0, 60.0, 40.0, 40.0);
    let max = series
        .iter()
        .flat_map(|s| s.1.iter().flatten())
        .map(|v| v.iter().sum::<f64>())
        .fold(0.0f64, f64::max)
        .max(1e-9);
    let plot_h = h - bottom - top;
    let group_w = (w - left - 20.0) / labels.len().max(1) as f64;
    let bar_w = group_w * 0.8 / series.len().max(1) as f64;
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"11\">\n\
         <rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n<text x=\"{left}\" y=\"20\" font-size=\"13\">{}</text>\n",
        xml(title)
    );
    for k in 0..=4 {
        let v = max * k as f64 / 4.0;
        let y = h - bottom - plot_h * k as f64 / 4.0;
        let _ = writeln!(
            s,
            "<line x1=\"{left}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"#ddd\"/><text x=\"4\" y=\"{:.1}\">{v:.3}</text>",
            w - 20.0,
            y + 4.0
        );
    }
    for (gi, l) in labels.iter().enumerate() {
        let gx = left + gi as f64 * group_w + group_w * 0.1;
        for (si, (name, vals)) in series.iter().enumerate() {
            let Some(Some(v)) = vals.get(gi) else {
                continue;
            };
            let mut base = h - bottom;
            for (pi, &part) in v.iter().enumerate() {
                let bh = plot_h * part / max;
                let what = parts.get(pi).map_or(String::new(), |p| format!(" {p}"));
                let _ = writeln!(
                    s,
                    "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{bh:.1}\" fill=\"{}\" fill-opacity=\"{}\"><title>{}{}: {part:.4}</title></rect>",
                    gx + si as f64 * bar_w,
                    base - bh,
                    bar_w.max(1.0),
                    COLORS[si % COLORS.len()],
                    OPACITY[pi.min(OPACITY.len() - 1)],
                    xml(name),
                    xml(&what)
                );
                base -= bh;
            }
        }
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            gx + group_w * 0.4,
            h - bottom + 14.0,
            xml(l)
        );
    }
    let legend = series
        .iter()
        .enumerate()
        .map(|(si, (name, _))| (COLORS[si % COLORS.len()], 1.0, name.as_str()))
        .chain(
            parts
                .iter()
                .enumerate()
                .map(|(pi, p)| ("#555", OPACITY[pi.min(OPACITY.len() - 1)], *p)),
        );
    for (i, (color, opacity, name)) in legend.enumerate() {
        let x = left + i as f64 * 150.0;
        let _ = writeln!(
            s,
            "<rect x=\"{x}\" y=\"{:.1}\" width=\"10\" height=\"10\" fill=\"{color}\" fill-opacity=\"{opacity}\"/><text x=\"{:.1}\" y=\"{:.1}\">{}</text>",
            h - 14.0,
            x + 14.0,
            h - 5.0,
            xml(name)
        );
    }
    s.push_str("</svg>\n");
    s
}

/// `t` with the XML special characters escaped.
pub fn xml(t: &str) -> String {
    t.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bars_stacks_and_escapes() {
        let svg = bar_svg("t<", &["a".into()], &[("s".into(), vec![Some(1.0)])]);
        assert!(svg.contains("t&lt;") && svg.ends_with("</svg>\n"));
        assert_eq!(svg.matches("<title>").count(), 1);
        // Missing values draw no bar.
        let svg = bar_svg(
            "t",
            &["a".into(), "b".into()],
            &[("s".into(), vec![Some(1.0), None])],
        );
        assert_eq!(svg.matches("<title>").count(), 1);
        // Stacked: two parts per bar, the second on top of the first.
        let svg = stacked_bar_svg(
            "s",
            &["a".into()],
            &[("x".into(), vec![Some(vec![1.0, 3.0])])],
            &["build", "trace"],
        );
        assert_eq!(svg.matches("<title>").count(), 2);
        assert!(svg.contains("x build: 1.0000") && svg.contains("x trace: 3.0000"));
        assert_eq!(xml("a&<b>"), "a&amp;&lt;b&gt;");
    }
}
