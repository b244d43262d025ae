//! SVG charts with plotters. Text metrics come from DejaVu Sans, embedded in the binary
//! (`assets/fonts/`, Bitstream Vera licence beside it), so labels are laid out the same on a
//! machine with no fonts installed.

use std::sync::OnceLock;

use anyhow::{anyhow, Result};
use plotters::prelude::*;

const FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
const W: u32 = 820;
const H: u32 = 480;

/// Registers the embedded font as `sans-serif` once per process.
fn font() -> Result<()> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(anyhow!("the embedded DejaVu Sans font could not be parsed"))
    }
}

fn err(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("drawing a chart: {e}")
}

/// One line of a line chart.
pub(crate) struct Line {
    pub(crate) name: String,
    pub(crate) points: Vec<(f64, f64)>,
    /// Dashed (for references such as the ideal speedup).
    pub(crate) dashed: bool,
}

fn color(i: usize) -> RGBColor {
    // Colour-blind-safe (Okabe–Ito) colours.
    const C: [RGBColor; 8] = [
        RGBColor(0, 114, 178),
        RGBColor(213, 94, 0),
        RGBColor(0, 158, 115),
        RGBColor(204, 121, 167),
        RGBColor(86, 180, 233),
        RGBColor(230, 159, 0),
        RGBColor(0, 0, 0),
        RGBColor(240, 228, 66),
    ];
    C[i % C.len()]
}

fn span(values: impl Iterator<Item = f64>, from_zero: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if from_zero {
        lo = lo.min(0.0);
    }
    let pad = ((hi - lo) * 0.08).max(1e-9);
    if from_zero && lo >= 0.0 {
        (lo, hi + pad)
    } else {
        (lo - pad, hi + pad)
    }
}

/// Where a chart's legend goes.
#[derive(Clone, Copy)]
pub(crate) enum Legend {
    UpperLeft,
    LowerLeft,
}

impl Legend {
    fn pos(self) -> SeriesLabelPosition {
        match self {
            Legend::UpperLeft => SeriesLabelPosition::UpperLeft,
            Legend::LowerLeft => SeriesLabelPosition::LowerLeft,
        }
    }
}

/// Axis numbers without a trailing `.0`, and without float noise.
fn tick(v: &f64) -> String {
    if (v - v.round()).abs() < 1e-9 {
        format!("{}", v.round())
    } else {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// A line chart with markers and a legend; the y axis starts at 0 when `y_from_zero`.
pub(crate) fn line_chart(
    title: &str,
    x_label: &str,
    y_label: &str,
    lines: &[Line],
    y_from_zero: bool,
    legend: Legend,
) -> Result<String> {
    font()?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let (x0, x1) = span(
            lines.iter().flat_map(|l| l.points.iter().map(|p| p.0)),
            false,
        );
        let (y0, y1) = span(
            lines.iter().flat_map(|l| l.points.iter().map(|p| p.1)),
            y_from_zero,
        );
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .x_label_formatter(&tick)
            .y_label_formatter(&tick)
            .label_style(("sans-serif", 13))
            .axis_desc_style(("sans-serif", 15))
            .draw()
            .map_err(err)?;
        for (i, l) in lines.iter().enumerate() {
            let c = color(i);
            let style = c.stroke_width(2);
            if l.dashed {
                chart
                    .draw_series(DashedLineSeries::new(l.points.iter().copied(), 6, 4, style))
                    .map_err(err)?
                    .label(l.name.as_str())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
            } else {
                chart
                    .draw_series(LineSeries::new(l.points.iter().copied(), style))
                    .map_err(err)?
                    .label(l.name.as_str())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
                chart
                    .draw_series(l.points.iter().map(|p| Circle::new(*p, 3, c.filled())))
                    .map_err(err)?;
            }
        }
        chart
            .configure_series_labels()
            .label_font(("sans-serif", 13))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(legend.pos())
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(svg)
}

/// One layer of stacked bars: a value per category.
pub(crate) struct Stack {
    pub(crate) name: String,
    pub(crate) values: Vec<f64>,
}

/// Stacked bars, one bar per category, layers bottom to top in `stacks` order.
pub(crate) fn stacked_bars(
    title: &str,
    categories: &[String],
    x_label: &str,
    y_label: &str,
    stacks: &[Stack],
) -> Result<String> {
    font()?;
    let n = categories.len().max(1);
    let totals: Vec<f64> = (0..n)
        .map(|i| {
            stacks
                .iter()
                .map(|s| s.values.get(i).copied().unwrap_or(0.0).max(0.0))
                .sum()
        })
        .collect();
    let ymax = totals.iter().copied().fold(0.0, f64::max).max(1e-9) * 1.25;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let n_i = n as i32;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(70)
            // n − 1 as the last value gives exactly n segments.
            .build_cartesian_2d((0..n_i - 1).into_segmented(), 0.0..ymax)
            .map_err(err)?;
        let names = categories.to_vec();
        let fmt = move |v: &SegmentValue<i32>| match v {
            SegmentValue::CenterOf(i) | SegmentValue::Exact(i) => usize::try_from(*i)
                .ok()
                .and_then(|i| names.get(i).cloned())
                .unwrap_or_default(),
            SegmentValue::Last => String::new(),
        };
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(n.min(40))
            .x_label_formatter(&fmt)
            .x_desc(x_label)
            .y_desc(y_label)
            .y_label_formatter(&tick)
            .label_style(("sans-serif", 12))
            .axis_desc_style(("sans-serif", 15))
            .draw()
            .map_err(err)?;
        let mut base = vec![0.0; n];
        for (k, s) in stacks.iter().enumerate() {
            let c = color(k);
            let bars: Vec<Rectangle<(SegmentValue<i32>, f64)>> = (0..n)
                .map(|i| {
                    let v = s.values.get(i).copied().unwrap_or(0.0).max(0.0);
                    let i32_ = i as i32;
                    let mut r = Rectangle::new(
                        [
                            (SegmentValue::Exact(i32_), base[i]),
                            (SegmentValue::Exact(i32_ + 1), base[i] + v),
                        ],
                        c.filled(),
                    );
                    r.set_margin(0, 0, 4, 4);
                    base[i] += v;
                    r
                })
                .collect();
            chart
                .draw_series(bars)
                .map_err(err)?
                .label(s.name.as_str())
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], c.filled()));
        }
        chart
            .configure_series_labels()
            .label_font(("sans-serif", 13))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(svg)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn texts(svg: &str) -> Vec<String> {
        let doc = roxmltree::Document::parse(svg).expect("SVG is XML");
        doc.descendants()
            .filter(|n| n.has_tag_name("text"))
            .filter_map(|n| n.text().map(|t| t.trim().to_string()))
            .collect()
    }

    #[test]
    fn line_chart_has_title_axes_and_legend() {
        let svg = line_chart(
            "T",
            "xs",
            "ys",
            &[
                Line {
                    name: "a".into(),
                    points: vec![(0.0, 1.0), (20.0, 3.0)],
                    dashed: false,
                },
                Line {
                    name: "ideal".into(),
                    points: vec![(0.0, 0.0), (20.0, 20.0)],
                    dashed: true,
                },
            ],
            true,
            Legend::UpperLeft,
        )
        .unwrap();
        let t = texts(&svg);
        for want in ["T", "xs", "ys", "a", "ideal", "20"] {
            assert!(t.iter().any(|x| x == want), "{want} missing from {t:?}");
        }
        assert!(!t.iter().any(|x| x.ends_with(".0")), "{t:?}");
    }

    #[test]
    fn stacked_bars_label_every_category_even_one() {
        for n in [1usize, 5] {
            let cats: Vec<String> = (0..n).map(|i| format!("c{i}")).collect();
            let svg = stacked_bars(
                "B",
                &cats,
                "cat",
                "val",
                &[
                    Stack {
                        name: "low".into(),
                        values: vec![1.0; n],
                    },
                    Stack {
                        name: "high".into(),
                        values: vec![2.0; n],
                    },
                ],
            )
            .unwrap();
            let t = texts(&svg);
            for c in &cats {
                assert!(t.contains(c), "{c} missing from {t:?}");
            }
            // 2 stacks × n bars plus 2 legend swatches.
            let doc = roxmltree::Document::parse(&svg).unwrap();
            let filled = doc
                .descendants()
                .filter(|e| e.has_tag_name("rect"))
                .filter(|e| {
                    e.attribute("fill")
                        .is_some_and(|f| f != "#FFFFFF" && f != "none")
                })
                .count();
            assert!(filled >= 2 * n + 2, "{filled} bars for n = {n}");
        }
    }

    #[test]
    fn tick_labels_are_plain() {
        assert_eq!(tick(&50.0), "50");
        assert_eq!(tick(&0.25), "0.25");
        assert_eq!(tick(&(0.1 + 0.2)), "0.3");
    }
}
