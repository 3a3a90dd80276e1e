//! The plots of `outlet eval` on rendered scenarios: the detection rate against the
//! viewing angle and the distance (`rates`), the hole errors in pixels and per pose
//! mode in millimetres (`errors`), and where the time goes per scenario (`timing`),
//! each as PNG and SVG.

use crate::eval_cmd::Outcome;
use crate::plot::{BLUE, DrawResult, Figure, GREEN, GREY, LIGHT_GREY, ORANGE, PURPLE, RateBar, rate_bars};
use plotters::coord::Shift;
use plotters::coord::ranged1d::SegmentValue;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

const FONT: &str = crate::plot::FONT;

/// The figures `outlet eval` writes, by file stem, with a caption for the report.
pub fn figures(outcomes: &[Outcome]) -> [(&'static str, &'static str, EvalFigure<'_>); 3] {
    [
        ("rates", "Detection rate against the off-axis angle and the distance", EvalFigure::Rates(outcomes)),
        ("errors", "Hole errors: pixels, and position per pose mode", EvalFigure::Errors(outcomes)),
        ("timing", "Time per stage and scenario", EvalFigure::Timing(outcomes)),
    ]
}

/// One of `outlet eval`'s plots over its outcomes.
pub enum EvalFigure<'a> {
    Rates(&'a [Outcome]),
    Errors(&'a [Outcome]),
    Timing(&'a [Outcome]),
}

impl Figure for EvalFigure<'_> {
    fn size(&self) -> (u32, u32) {
        match self {
            Self::Rates(_) | Self::Errors(_) => (960, 400),
            Self::Timing(o) => (960, 120 + 34 * scenarios(o).len().max(1) as u32),
        }
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        match self {
            Self::Rates(o) => rates(root, o),
            Self::Errors(o) => errors(root, o),
            Self::Timing(o) => timing(root, o),
        }
    }
}

/// Rate bars of the positive images over `n` equal bins of `key` from `lo` to `hi`.
fn bins(outcomes: &[Outcome], key: impl Fn(&Outcome) -> f64, lo: f64, hi: f64, n: usize) -> Vec<RateBar> {
    let step = (hi - lo) / n as f64;
    (0..n)
        .map(|k| {
            let (a, b) = (lo + k as f64 * step, lo + (k + 1) as f64 * step);
            let inside: Vec<&Outcome> =
                outcomes.iter().filter(|o| o.positive && (a..b + 1e-9).contains(&key(o))).collect();
            let rate = inside.iter().filter(|o| o.correct).count() as f64 / inside.len().max(1) as f64;
            RateBar { label: format!("{a:.0}-{b:.0}"), rate, n: inside.len() }
        })
        .collect()
}

fn rates<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, outcomes: &[Outcome]) -> DrawResult<DB> {
    let panels = root.split_evenly((1, 2));
    rate_bars(
        &panels[0],
        "Detection rate vs off-axis angle",
        "off-axis angle (deg)",
        "correct",
        &bins(outcomes, |o| o.off_axis_deg, 0.0, 40.0, 8),
    )?;
    rate_bars(
        &panels[1],
        "Detection rate vs distance",
        "distance (cm)",
        "correct",
        &bins(outcomes, |o| o.distance_m * 100.0, 20.0, 50.0, 6),
    )
}

fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Counts of `values` in `edges.len() - 1` bins, as a share (%) of all values; values
/// outside the edges in the end bins.
fn histogram(values: &[f64], edges: &[f64]) -> Vec<f64> {
    let bins = edges.len().saturating_sub(1);
    let mut counts = vec![0usize; bins];
    for v in values.iter().filter(|v| v.is_finite()) {
        let k = edges[1..].iter().position(|e| v < e).unwrap_or(bins.saturating_sub(1));
        if let Some(c) = counts.get_mut(k) {
            *c += 1;
        }
    }
    let n = values.iter().filter(|v| v.is_finite()).count().max(1) as f64;
    counts.into_iter().map(|c| 100.0 * c as f64 / n).collect()
}

/// The pixel error histogram of every hole of a correct detection, and the hole
/// position error per pose mode (log scale: plane mode is a hundred times better
/// than mono).
fn errors<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, outcomes: &[Outcome]) -> DrawResult<DB> {
    let panels = root.split_evenly((1, 2));
    // Pixels.
    let px: Vec<f64> = outcomes.iter().filter(|o| o.correct).flat_map(|o| o.errors_px.iter().copied()).collect();
    let (step, top) = (0.05, 1.0);
    let edges: Vec<f64> = (0..=20).map(|k| k as f64 * step).collect();
    let shares = histogram(&px, &edges);
    let y_max = shares.iter().copied().fold(1.0, f64::max) * 1.15;
    let mut chart = ChartBuilder::on(&panels[0])
        .caption("Hole pixel error, correct detections", (FONT, 18))
        .margin(8)
        .x_label_area_size(44)
        .y_label_area_size(52)
        .build_cartesian_2d(0.0..top, 0.0..y_max)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_desc("distance to the true centre (px; the last bar holds the rest)")
        .y_desc("holes")
        .axis_desc_style((FONT, 14))
        .y_label_formatter(&|v| format!("{v:.0}%"))
        .light_line_style(WHITE)
        .draw()?;
    chart.draw_series(shares.iter().enumerate().map(|(k, s)| {
        let mut bar = Rectangle::new([(edges[k], 0.0), (edges[k + 1], *s)], BLUE.filled());
        bar.set_margin(0, 0, 1, 1);
        bar
    }))?;
    let beyond = px.iter().filter(|e| **e >= top).count();
    let note = format!("{} holes, median {:.3} px, {beyond} beyond {top} px", px.len(), median(px.clone()));
    let style = (FONT, 13).into_font().color(&GREY).pos(Pos::new(HPos::Right, VPos::Top));
    chart.draw_series(std::iter::once(EmptyElement::at((top, y_max)) + Text::new(note, (-6, 4), style)))?;

    // Millimetres per pose mode, log-spaced bins (8 per decade).
    let (lo, hi) = (0.005f64, 50.0f64);
    let decades = (hi / lo).log10();
    let per_decade = 8.0;
    let edges: Vec<f64> =
        (0..=(decades * per_decade).round() as usize).map(|k| lo * 10f64.powf(k as f64 / per_decade)).collect();
    let modes: [(&str, Vec<f64>, RGBColor); 4] = [
        ("plane", outcomes.iter().flat_map(|o| o.pose_mm.plane.iter().copied()).collect(), BLUE),
        ("normal (cloud)", outcomes.iter().flat_map(|o| o.pose_mm.normal_cloud.iter().copied()).collect(), GREEN),
        ("normal (1 deg)", outcomes.iter().flat_map(|o| o.pose_mm.normal.iter().copied()).collect(), ORANGE),
        ("mono", outcomes.iter().flat_map(|o| o.pose_mm.mono.iter().copied()).collect(), PURPLE),
    ];
    let shares: Vec<Vec<f64>> = modes.iter().map(|(_, v, _)| histogram(v, &edges)).collect();
    let y_max = shares.iter().flatten().copied().fold(1.0, f64::max) * 1.25;
    let mut chart = ChartBuilder::on(&panels[1])
        .caption("Hole position error per pose mode", (FONT, 18))
        .margin(8)
        .x_label_area_size(44)
        .y_label_area_size(52)
        .build_cartesian_2d((lo..hi).log_scale(), 0.0..y_max)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_desc("distance to the true hole (mm, log scale)")
        .y_desc("holes")
        .axis_desc_style((FONT, 14))
        .x_label_formatter(&|v| format!("{}", (v * 1e4).round() / 1e4))
        .y_label_formatter(&|v| format!("{v:.0}%"))
        .light_line_style(WHITE)
        .draw()?;
    for ((name, values, colour), shares) in modes.iter().zip(&shares) {
        if values.is_empty() {
            continue;
        }
        // A step line over the bins.
        let steps = shares.iter().enumerate().flat_map(|(k, s)| [(edges[k], *s), (edges[k + 1], *s)]);
        let colour = *colour;
        chart
            .draw_series(LineSeries::new(steps, colour.stroke_width(2)))?
            .label(format!("{name}: median {:.3} mm", median(values.clone())))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .label_font((FONT, 13))
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(LIGHT_GREY)
        .draw()
}

/// The scenarios of the outcomes, in their order.
fn scenarios(outcomes: &[Outcome]) -> Vec<&str> {
    let mut names: Vec<&str> = Vec::new();
    for o in outcomes {
        if !names.contains(&o.scenario.as_str()) {
            names.push(&o.scenario);
        }
    }
    names
}

/// The mean time of each stage per scenario, stacked, and the rest of `detect`.
fn timing<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, outcomes: &[Outcome]) -> DrawResult<DB> {
    let names = scenarios(outcomes);
    let n = names.len().max(1) as u32;
    // Per scenario: the mean of each stage, then the mean total.
    let means: Vec<([f64; 4], f64)> = names
        .iter()
        .map(|name| {
            let of: Vec<&Outcome> = outcomes.iter().filter(|o| o.scenario == *name).collect();
            let count = of.len().max(1) as f64;
            let mut stages = [0.0; 4];
            for o in &of {
                for (s, v) in stages.iter_mut().zip(o.stages) {
                    *s += v / count;
                }
            }
            (stages, of.iter().map(|o| o.ms).sum::<f64>() / count)
        })
        .collect();
    // Room on the right for the totals and the legend.
    let x_max = means.iter().map(|(s, t)| t.max(s.iter().sum())).fold(1.0, f64::max) * 1.45;
    let mut chart = ChartBuilder::on(root)
        .caption("Time per stage (mean ms per image, one core)", (FONT, 18))
        .margin(10)
        .x_label_area_size(44)
        .y_label_area_size(120)
        .build_cartesian_2d(0.0..x_max, (0u32..n - 1).into_segmented())?;
    // The first scenario on top.
    let row = |i: usize| n - 1 - i as u32;
    let label_of = |v: &SegmentValue<u32>| match v {
        SegmentValue::CenterOf(r) if *r < n => {
            names.get((n - 1 - r) as usize).map(|s| s.to_string()).unwrap_or_default()
        }
        _ => String::new(),
    };
    chart
        .configure_mesh()
        .disable_y_mesh()
        .y_labels(names.len() + 1)
        .y_label_formatter(&label_of)
        .y_label_style((FONT, 14))
        .x_desc("ms")
        .axis_desc_style((FONT, 14))
        .light_line_style(WHITE)
        .draw()?;
    let stages: [(&str, RGBColor); 4] =
        [("candidates", BLUE), ("classify", ORANGE), ("hash", GREEN), ("refine", PURPLE)];
    for (k, (stage, colour)) in stages.into_iter().enumerate() {
        chart
            .draw_series(means.iter().enumerate().map(|(i, (s, _))| {
                let x0: f64 = s[..k].iter().sum();
                let mut bar = Rectangle::new(
                    [(x0, SegmentValue::Exact(row(i))), (x0 + s[k], SegmentValue::Exact(row(i) + 1))],
                    colour.filled(),
                );
                bar.set_margin(5, 5, 0, 0);
                bar
            }))?
            .label(stage)
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], colour.filled()));
    }
    chart
        .draw_series(means.iter().enumerate().map(|(i, (s, total))| {
            let x0: f64 = s.iter().sum();
            let mut bar = Rectangle::new(
                [(x0, SegmentValue::Exact(row(i))), (total.max(x0), SegmentValue::Exact(row(i) + 1))],
                LIGHT_GREY.filled(),
            );
            bar.set_margin(5, 5, 0, 0);
            bar
        }))?
        .label("rest of detect")
        .legend(|(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], LIGHT_GREY.filled()));
    let style = (FONT, 13).into_font().color(&GREY).pos(Pos::new(HPos::Left, VPos::Center));
    chart.draw_series(means.iter().enumerate().map(|(i, (s, total))| {
        let end = total.max(s.iter().sum());
        EmptyElement::at((end, SegmentValue::CenterOf(row(i))))
            + Text::new(format!("{total:.2} ms"), (6, 0), style.clone())
    }))?;
    chart
        .configure_series_labels()
        .label_font((FONT, 13))
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.85))
        .border_style(LIGHT_GREY)
        .draw()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval_cmd::PoseErrors;
    use crate::plot::{
        render_png, render_svg,
        tests::{ink, share_of},
    };

    /// Two scenarios, positives at 5 and 35 degrees: all found near, half far.
    fn outcomes() -> Vec<Outcome> {
        (0..40)
            .map(|i| {
                let far = i % 2 == 1;
                let correct = !far || i % 4 == 1;
                Outcome {
                    scenario: if i < 20 { "orange2x1" } else { "white2x2" }.to_string(),
                    index: i,
                    positive: true,
                    found: correct,
                    correct,
                    errors_px: if correct { vec![0.1, 0.2, 0.15, 1.5] } else { Vec::new() },
                    ms: 4.0,
                    stages: [2.0, 0.5, 0.1, 0.4],
                    off_axis_deg: if far { 35.0 } else { 5.0 },
                    distance_m: 0.3,
                    pose_mm: PoseErrors {
                        plane: vec![0.05; 4],
                        normal: vec![0.7; 4],
                        mono: vec![0.3, 8.0],
                        ..PoseErrors::default()
                    },
                    holes_with_candidate: 4,
                    holes_classified: 4,
                }
            })
            .collect()
    }

    #[test]
    fn rate_bins_count_the_positives_of_each_angle() {
        let bars = bins(&outcomes(), |o| o.off_axis_deg, 0.0, 40.0, 8);
        assert_eq!(bars[1], RateBar { label: "5-10".into(), rate: 1.0, n: 20 });
        assert_eq!(bars[7], RateBar { label: "35-40".into(), rate: 0.5, n: 20 });
        assert_eq!(bars[3].n, 0);
    }

    #[test]
    fn a_histogram_is_the_share_per_bin_with_outliers_at_the_ends() {
        let shares = histogram(&[0.01, 0.06, 0.07, 9.0, f64::NAN], &[0.0, 0.05, 0.1]);
        assert_eq!(shares, vec![25.0, 75.0]);
    }

    #[test]
    fn every_eval_figure_draws_at_its_size_with_its_titles_and_legends() {
        let outcomes = outcomes();
        let texts: [&[&str]; 3] = [
            &["Detection rate vs off-axis angle", "Detection rate vs distance", "off-axis angle (deg)", "35-40"],
            &["Hole pixel error", "Hole position error per pose mode", "plane: median 0.050 mm", "mono: median"],
            &["Time per stage", "orange2x1", "white2x2", "candidates", "refine", "4.00 ms"],
        ];
        for ((stem, _, figure), texts) in figures(&outcomes).into_iter().zip(texts) {
            let img = render_png(&figure).expect(stem);
            assert_eq!(img.dimensions(), figure.size(), "{stem}");
            let ink = share_of(&img, WHITE, 0..img.width(), 0..img.height());
            assert!(ink < 0.97, "{stem}: {ink:.3} of it white");
            let svg = render_svg(&figure).expect(stem);
            for t in texts {
                assert!(svg.contains(t), "{stem}: {t:?} missing");
            }
        }
    }

    #[test]
    fn the_two_rate_titles_do_not_touch() {
        // The old plot's titles ran into each other: each now sits over its own half.
        let figure = EvalFigure::Rates(&[]);
        let img = render_png(&figure).expect("png");
        let (w, _) = img.dimensions();
        let gap = ink(&img, w / 2 - 20..w / 2 + 20, 0..30);
        let left = ink(&img, 0..w / 2, 0..30);
        let right = ink(&img, w / 2..w, 0..30);
        assert!(gap == 0.0 && left > 0.005 && right > 0.005, "gap {gap} left {left} right {right}");
    }
}
