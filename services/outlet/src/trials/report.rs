//! What a trial run reports: one record per trial (a JSON line with `--json`),
//! the summary table with percentiles and the success rate by distance, yaw,
//! light and outlet kind, and a plot of the same.

use super::judge::{Class, Landing};
use super::park::Setup;
use crate::plot::{DrawResult, Figure, RateBar, rate_bars};
use plotters::coord::Shift;
use plotters::prelude::{DrawingArea, DrawingBackend};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write;

#[derive(Debug, Clone, Serialize)]
pub struct TrialRecord {
    pub trial: u64,
    pub seed: u64,
    pub mix: String,
    pub scenario: String,
    pub template: String,
    pub ground_up: bool,
    pub range_m: f64,
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub exposure: f64,
    pub light: &'static str,
    pub class: &'static str,
    pub success: bool,
    /// A plug pushed where it does not belong (outlet, receptacle, polarity).
    pub wrong_insertion: bool,
    /// Frames rendered and sent through the sidecar.
    pub frames: u32,
    /// The sidecar's answers per frame: ok, not_found, ambiguous, plane_mismatch, missing.
    pub statuses: BTreeMap<&'static str, u32>,
    /// The robot's time from parking to the end of the push (s): frame period,
    /// arm motion and push. `None` without a push.
    pub time_to_insert_s: Option<f64>,
    #[serde(skip)]
    pub sim_time_s: f64,
    /// Compute time of the trial (s), and its parts (ms): rendering, the
    /// detector's time, the rest of the sidecar (transport, plane, pose).
    pub wall_s: f64,
    pub render_ms: f64,
    pub detect_ms: f64,
    pub pose_ms: f64,
    /// Results with a pose whose worst hole is more than 3 mm from the truth
    /// (false poses), and the worst hole error of any result with a pose (mm).
    pub false_poses: u32,
    /// False poses whose error bars do not cover them: a hole more than 3 mm
    /// off and more than 5 sigma (`sqrt(e^T C^-1 e)`) from the truth.
    pub lying_poses: u32,
    pub worst_pose_error_mm: Option<f64>,
    /// The receptacle aimed at (template order).
    pub target: Option<usize>,
    /// Where the plug met the face (or would have).
    pub landing: Option<Landing>,
    /// The last predicted 3-sigma in-plane error over the target's holes, as a
    /// fraction of each hole's tolerance (< 1 lets the controller push).
    pub predicted_over_tolerance: Option<f64>,
}

impl TrialRecord {
    pub fn new(trial: u64, seed: u64, setup: &Setup, template: &str) -> Self {
        Self {
            trial,
            seed,
            mix: setup.mix.clone(),
            scenario: setup.scenario.clone(),
            template: template.to_string(),
            ground_up: setup.ground_up,
            range_m: setup.range_m,
            yaw_deg: setup.yaw_deg,
            pitch_deg: setup.pitch_deg,
            exposure: setup.exposure,
            light: setup.light(),
            class: "",
            success: false,
            wrong_insertion: false,
            frames: 0,
            statuses: BTreeMap::new(),
            time_to_insert_s: None,
            sim_time_s: 0.0,
            wall_s: 0.0,
            render_ms: 0.0,
            detect_ms: 0.0,
            pose_ms: 0.0,
            false_poses: 0,
            lying_poses: 0,
            worst_pose_error_mm: None,
            target: None,
            landing: None,
            predicted_over_tolerance: None,
        }
    }

    pub fn count_status(&mut self, status: &'static str) {
        *self.statuses.entry(status).or_default() += 1;
    }

    /// Holds a result with a pose against the frame's true holes (camera frame).
    pub fn check_pose(&mut self, poses: &outlet_client::HolePoses, truth: &[Option<[f64; 3]>]) {
        if !poses.is_usable() {
            return;
        }
        let worst = if poses.holes.len() == truth.len() {
            poses
                .holes
                .iter()
                .zip(truth)
                .map(|(h, t)| match t {
                    Some(t) => (0..3).map(|i| (h.position_m[i] - t[i]).powi(2)).sum::<f64>().sqrt() * 1e3,
                    None => f64::INFINITY,
                })
                .fold(0.0, f64::max)
        } else {
            f64::INFINITY // a pose where the scene has no such outlet
        };
        self.false_poses += (worst > 3.0) as u32;
        let sigmas = |h: &outlet_client::Hole, t: &[f64; 3]| {
            let e = nalgebra::Vector3::from_fn(|i, _| h.position_m[i] - t[i]);
            let c = nalgebra::Matrix3::from_fn(|i, j| h.covariance_m2[i][j]);
            c.cholesky().map_or(f64::INFINITY, |l| e.dot(&l.solve(&e)).sqrt())
        };
        let lying = poses.holes.len() != truth.len()
            || poses.holes.iter().zip(truth).any(|(h, t)| match t {
                Some(t) => {
                    let mm = (0..3).map(|i| (h.position_m[i] - t[i]).powi(2)).sum::<f64>().sqrt() * 1e3;
                    mm > 3.0 && sigmas(h, t) > 5.0
                }
                None => true,
            });
        self.lying_poses += lying as u32;
        self.worst_pose_error_mm = Some(self.worst_pose_error_mm.map_or(worst, |w| w.max(worst)));
    }

    pub fn finish(
        &mut self,
        class: Class,
        landing: Option<Landing>,
        target: Option<usize>,
        predicted: Option<f64>,
        wall_s: f64,
    ) {
        self.class = class.as_str();
        self.success = class.is_success();
        self.wrong_insertion = class.is_wrong_insertion();
        let pushed = matches!(
            class,
            Class::Success | Class::OffTolerance | Class::WrongOutlet | Class::WrongReceptacle | Class::WrongPolarity
        );
        self.time_to_insert_s = pushed.then_some(self.sim_time_s);
        self.landing = landing;
        self.target = target;
        self.predicted_over_tolerance = predicted;
        self.wall_s = wall_s;
    }
}

/// The `p` quantile of `values` (nearest rank); NaN when empty.
pub fn percentile(values: &[f64], p: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() as f64 * p).ceil() as usize).clamp(1, v.len()) - 1]
}

fn rate(records: &[&TrialRecord]) -> String {
    let ok = records.iter().filter(|r| r.success).count();
    format!("{ok}/{} ({:.1}%)", records.len(), 100.0 * ok as f64 / records.len().max(1) as f64)
}

/// The summary table (Markdown) of a run that took `wall_s` seconds.
pub fn summary(records: &[TrialRecord], wall_s: f64) -> String {
    let all: Vec<&TrialRecord> = records.iter().collect();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "\n## Trials: {} approaches, {:.0} s ({:.2} s per trial)\n",
        records.len(),
        wall_s,
        wall_s / records.len().max(1) as f64
    );
    let _ = writeln!(
        s,
        "Success: **{}**; wrong insertions: **{}**\n",
        rate(&all),
        records.iter().filter(|r| r.wrong_insertion).count()
    );
    let _ = writeln!(s, "| class | trials |\n|---|---:|");
    for c in Class::ALL {
        let n = records.iter().filter(|r| r.class == c.as_str()).count();
        if n > 0 {
            let _ = writeln!(s, "| {} | {n} |", c.as_str());
        }
    }
    let column = |f: &dyn Fn(&TrialRecord) -> Option<f64>| -> Vec<f64> { records.iter().filter_map(f).collect() };
    let rows: [(&str, Vec<f64>); 7] = [
        ("time to insert (robot, s)", column(&|r| r.time_to_insert_s)),
        ("frames used (pushed)", column(&|r| r.time_to_insert_s.map(|_| r.frames as f64))),
        ("frames used (all)", column(&|r| Some(r.frames as f64))),
        ("compute per trial (s)", column(&|r| Some(r.wall_s))),
        ("detector share of compute", column(&|r| Some(r.detect_ms / 1e3 / r.wall_s.max(1e-9)))),
        ("pose share of compute (transport, plane, solve)", column(&|r| Some(r.pose_ms / 1e3 / r.wall_s.max(1e-9)))),
        ("render share of compute", column(&|r| Some(r.render_ms / 1e3 / r.wall_s.max(1e-9)))),
    ];
    let _ = writeln!(s, "\n| per trial | p50 | p90 | p99 | max |\n|---|---:|---:|---:|---:|");
    for (name, v) in &rows {
        let _ = writeln!(
            s,
            "| {name} | {:.3} | {:.3} | {:.3} | {:.3} |",
            percentile(v, 0.5),
            percentile(v, 0.9),
            percentile(v, 0.99),
            percentile(v, 1.0)
        );
    }
    let tips: Vec<f64> = records
        .iter()
        .filter_map(|r| r.landing.as_ref()?.errors_mm.map(|e| e.iter().fold(0.0f64, |a, b| a.max(*b))))
        .collect();
    let _ = writeln!(
        s,
        "\nWorst prong error of each landing (pushed or would-be): p50 {:.3} mm, p90 {:.3} mm, p99 {:.3} mm, max {:.3} mm",
        percentile(&tips, 0.5),
        percentile(&tips, 0.9),
        percentile(&tips, 0.99),
        percentile(&tips, 1.0)
    );
    let mut statuses: BTreeMap<&str, u32> = BTreeMap::new();
    for r in records {
        for (k, v) in &r.statuses {
            *statuses.entry(k).or_default() += v;
        }
    }
    let _ = writeln!(s, "Frames by the sidecar's answer: {statuses:?}");
    let false_poses: u32 = records.iter().map(|r| r.false_poses).sum();
    let trials_with = records.iter().filter(|r| r.false_poses > 0).count();
    let lying: u32 = records.iter().map(|r| r.lying_poses).sum();
    let _ = writeln!(
        s,
        "False poses (a hole > 3 mm from the truth): {false_poses} in {trials_with} trials; of them beyond 5 sigma of their own covariance: {lying}\n"
    );
    for (title, key) in breakdowns() {
        let mut groups: BTreeMap<String, Vec<&TrialRecord>> = BTreeMap::new();
        for r in records {
            groups.entry(key(r)).or_default().push(r);
        }
        let _ = writeln!(s, "| {title} | success |\n|---|---:|");
        for (k, g) in groups {
            let _ = writeln!(s, "| {k} | {} |", rate(&g));
        }
        let _ = writeln!(s);
    }
    s
}

type Key = fn(&TrialRecord) -> String;

fn breakdowns() -> [(&'static str, Key); 5] {
    [
        ("distance (cm)", |r| {
            let lo = ((r.range_m * 100.0 / 10.0).floor() * 10.0).clamp(30.0, 50.0);
            format!("{lo:.0}-{:.0}", lo + 10.0)
        }),
        ("yaw (deg)", |r| {
            let lo = ((r.yaw_deg.abs() / 10.0).floor() * 10.0).min(30.0);
            format!("{lo:.0}-{:.0}", lo + 10.0)
        }),
        ("light", |r| r.light.to_string()),
        ("outlet", |r| r.scenario.clone()),
        ("mounting", |r| if r.ground_up { "ground up" } else { "ground down" }.to_string()),
    ]
}

/// Bar charts of the success rate against distance, yaw, light and outlet.
pub struct TrialsFigure<'a>(pub &'a [TrialRecord]);

impl TrialsFigure<'_> {
    /// Each panel's title and its bars.
    fn panels(&self) -> Vec<(String, Vec<RateBar>)> {
        breakdowns()
            .into_iter()
            .take(4)
            .map(|(title, key)| {
                let mut groups: BTreeMap<String, (usize, usize)> = BTreeMap::new();
                for r in self.0 {
                    let g = groups.entry(key(r)).or_default();
                    g.0 += r.success as usize;
                    g.1 += 1;
                }
                let bars = groups
                    .into_iter()
                    .map(|(label, (ok, n))| RateBar { label, rate: ok as f64 / n.max(1) as f64, n })
                    .collect();
                (title.to_string(), bars)
            })
            .collect()
    }
}

impl Figure for TrialsFigure<'_> {
    fn size(&self) -> (u32, u32) {
        (1000, 760)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        for ((title, bars), area) in self.panels().iter().zip(root.split_evenly((2, 2))) {
            rate_bars(&area, &format!("Success vs {title}"), title, "success", bars)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use outlet_protocol::CameraModel;

    #[test]
    fn the_trials_plot_has_a_panel_per_breakdown_with_each_groups_success() {
        let camera = CameraModel::default_vga();
        let records: Vec<TrialRecord> = (0..12)
            .map(|i| {
                let setup = super::super::park::draw("default", 5, i, &camera).expect("setup");
                let mut r = TrialRecord::new(i, 5, &setup, "2x1");
                r.success = i % 3 != 0;
                r
            })
            .collect();
        let figure = TrialsFigure(&records);
        let panels = figure.panels();
        let titles: Vec<&str> = panels.iter().map(|(t, _)| t.as_str()).collect();
        assert_eq!(titles, ["distance (cm)", "yaw (deg)", "light", "outlet"]);
        for (title, bars) in &panels {
            assert_eq!(bars.iter().map(|b| b.n).sum::<usize>(), 12, "{title}");
            let ok: f64 = bars.iter().map(|b| b.rate * b.n as f64).sum();
            assert!((ok - 8.0).abs() < 1e-9, "{title}: {ok}");
        }
        let img = crate::plot::render_png(&figure).expect("png");
        assert_eq!(img.dimensions(), (1000, 760));
        let svg = crate::plot::render_svg(&figure).expect("svg");
        for title in ["Success vs distance (cm)", "Success vs yaw (deg)", "Success vs light", "Success vs outlet"] {
            assert!(svg.contains(title), "{title} missing");
        }
    }
}
