//! The one SVG plot writer of the reports: grouped bar charts, plain or stacked (the
//! build and trace parts of a frame's energy), and labelled scatter plots (tree quality
//! against build time), self-contained (no fonts or scripts fetched), with every bar's or
//! point's value in a tooltip (`<title>`).
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

/// One point of a [`scatter_svg`]: its coordinates and its label (drawn beside it).
#[derive(Clone, Debug, PartialEq)]
pub struct Point {
    /// Horizontal value (drawn on a log scale when the plot asks for it).
    pub x: f64,
    /// Vertical value.
    pub y: f64,
    /// Label drawn beside the point and in its tooltip.
    pub label: String,
}

/// A labelled scatter plot: every point drawn with its label beside it, `x` on a log-10
/// scale when `log_x` (points with a non-positive or non-finite coordinate are left out),
/// axes with five ticks each, the axis names `x_name` and `y_name`.
pub fn scatter_svg(
    title: &str,
    x_name: &str,
    y_name: &str,
    log_x: bool,
    points: &[Point],
) -> String {
    const COLORS: [&str; 6] = [
        "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf",
    ];
    let (w, h, left, right, bottom, top) = (760.0, 420.0, 70.0, 170.0, 50.0, 40.0);
    let fx = |x: f64| if log_x { x.log10() } else { x };
    let shown: Vec<&Point> = points
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite() && (!log_x || p.x > 0.0))
        .collect();
    let range = |v: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        });
        if !lo.is_finite() {
            (0.0, 1.0)
        } else {
            let pad = ((hi - lo) * 0.08).max(1e-3 * hi.abs().max(1.0));
            (lo - pad, hi + pad)
        }
    };
    let (x0, x1) = range(&mut shown.iter().map(|p| fx(p.x)));
    let (y0, y1) = range(&mut shown.iter().map(|p| p.y));
    let (pw, ph) = (w - left - right, h - top - bottom);
    let px = |x: f64| left + (fx(x) - x0) / (x1 - x0) * pw;
    let py = |y: f64| h - bottom - (y - y0) / (y1 - y0) * ph;
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"11\">\n\
         <rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n<text x=\"{left}\" y=\"20\" font-size=\"13\">{}</text>\n",
        xml(title)
    );
    for k in 0..=4 {
        let t = k as f64 / 4.0;
        let (gx, gy) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
        let xv = if log_x { 10f64.powf(gx) } else { gx };
        let (lx, ly) = (left + pw * t, h - bottom - ph * t);
        let _ = writeln!(
            s,
            "<line x1=\"{lx:.1}\" y1=\"{top}\" x2=\"{lx:.1}\" y2=\"{:.1}\" stroke=\"#eee\"/><text x=\"{lx:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>\n\
             <line x1=\"{left}\" y1=\"{ly:.1}\" x2=\"{:.1}\" y2=\"{ly:.1}\" stroke=\"#eee\"/><text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{gy:.3}</text>",
            h - bottom,
            h - bottom + 14.0,
            tick(xv),
            left + pw,
            left - 4.0,
            ly + 4.0
        );
    }
    let _ = writeln!(
        s,
        "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>\n\
         <text x=\"14\" y=\"{:.1}\" text-anchor=\"middle\" transform=\"rotate(-90 14 {:.1})\">{}</text>",
        left + pw / 2.0,
        h - 14.0,
        xml(x_name),
        top + ph / 2.0,
        top + ph / 2.0,
        xml(y_name)
    );
    for (i, p) in shown.iter().enumerate() {
        let (cx, cy) = (px(p.x), py(p.y));
        let _ = writeln!(
            s,
            "<circle cx=\"{cx:.1}\" cy=\"{cy:.1}\" r=\"4\" fill=\"{c}\"><title>{l}: {}, {}</title></circle><text x=\"{:.1}\" y=\"{:.1}\" fill=\"{c}\">{l}</text>",
            tick(p.x),
            tick(p.y),
            cx + 6.0,
            cy + 4.0,
            c = COLORS[i % COLORS.len()],
            l = xml(&p.label)
        );
    }
    s.push_str("</svg>\n");
    s
}

/// A tick or tooltip value with about three significant digits.
fn tick(v: f64) -> String {
    let a = v.abs();
    if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.1}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
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

    #[test]
    fn scatter_places_and_labels_points() {
        let pt = |x: f64, y: f64, l: &str| Point {
            x,
            y,
            label: l.into(),
        };
        let svg = scatter_svg(
            "SAH & time",
            "ms",
            "SAH",
            true,
            &[
                pt(10.0, 1.2, "a<"),
                pt(1000.0, 0.9, "b"),
                pt(0.0, 1.0, "dropped"),
            ],
        );
        assert!(svg.contains("SAH &amp; time") && svg.ends_with("</svg>\n"));
        // The zero-time point cannot sit on a log axis: two points, labelled.
        assert_eq!(svg.matches("<circle").count(), 2);
        assert!(svg.contains(">a&lt;</text>") && !svg.contains("dropped"));
        // The slower, better point sits right of and below the other.
        let cx = |l: &str| -> (f64, f64) {
            let at = svg.find(&format!("<title>{l}:")).unwrap();
            let c = &svg[svg[..at].rfind("<circle").unwrap()..at];
            let num = |k: &str| -> f64 {
                let i = c.find(k).unwrap() + k.len();
                c[i..].split('"').next().unwrap().parse().unwrap()
            };
            (num("cx=\""), num("cy=\""))
        };
        let (a, b) = (cx("a&lt;"), cx("b"));
        assert!(b.0 > a.0 && b.1 > a.1, "{a:?} {b:?}");
        // Nothing to show still gives a valid, empty plot.
        let empty = scatter_svg("e", "x", "y", false, &[]);
        assert!(empty.ends_with("</svg>\n") && !empty.contains("<circle"));
    }
}
